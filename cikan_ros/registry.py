"""The governors by name: the conventional TSG, the learned model families of ``models/`` and model
paths, each optionally with its update rule (``NAME@keep``, ``NAME@paper``).

Above both :mod:`cikan_ros.governor` (the protocol and the conventional TSG) and the learned
governor (:mod:`cikan_ros.learn.governor`): the core modules never import ``learn/``, and whatever
turns a name into a governor (``cikan`` commands, Monte Carlo, the dataset generator, the governor
node) imports this module.
"""

from __future__ import annotations

from .config import LEARNED_ALGORITHMS, Config
from .governor import ConventionalGovernor, Governor
from .learn.governor import load_learned_governor
from .learn.modelfile import CARD, MODELS_DIR, scenario_model_dir
from .tsg import Predictor

#: Names of the learned model families shipped in ``models/`` (see ``cikan_ros.learn``).
LEARNED_NAMES = ("cikan", "grbf", "rswaf", "relu", "gelu")
GOVERNOR_NAMES = ("conventional",) + LEARNED_NAMES


def campaign_names() -> list[str]:
    """Every governor of the results campaign (``cikan montecarlo --governor all``): the
    conventional TSG; each family's default model under the keep rule and under the paper's
    Algorithm 1; and, where ``models/<family>-prev`` ships (τ_{k-1} as an input), that model
    under the keep rule."""
    names = list(GOVERNOR_NAMES) + [f"{n}@paper" for n in LEARNED_NAMES]
    return names + [f"{n}-prev" for n in LEARNED_NAMES if (MODELS_DIR / f"{n}-prev").is_dir()]


def shipped_names(cfg: Config) -> list[str]:
    """The conventional TSG and every learned family with a model for the configuration's
    scenario, approach side and Verify mode (``scenario.models_dir``)."""
    return ["conventional"] + [n for n in LEARNED_NAMES if (scenario_model_dir(
        cfg.scenario.models_dir, n, cfg.mission.approach, cfg.tsg.robust) / CARD).is_file()]


def split_rule(name: str) -> tuple[str, str | None]:
    """``"cikan@paper"`` -> ("cikan", "paper"): a learned governor with its update rule named
    (``learned.algorithm``); a name without a known rule suffix -> (name, None)."""
    base, sep, rule = name.rpartition("@")
    return (base, rule) if sep and rule in LEARNED_ALGORITHMS else (name, None)


def make_governor(name: str, cfg: Config, predictor: Predictor | None = None) -> Governor:
    """The governor called ``name``: "conventional", a shipped model family, or a model path,
    optionally with its update rule as ``NAME@keep`` / ``NAME@paper`` (else ``learned.algorithm``).

    Learned governors come from ``cikan_ros.learn``; their files are checked on load and a bad
    file raises a CikanError naming the problem.
    """
    base, rule = split_rule(name)
    if rule is not None and base != "conventional" and rule != cfg.learned.algorithm:
        cfg = cfg.replace(**{"learned.algorithm": rule})
        predictor = None
    predictor = predictor or Predictor.from_config(cfg)
    if base == "conventional":
        return ConventionalGovernor(predictor)
    gov = load_learned_governor(base, predictor)
    if rule is not None:
        gov.name = f"{gov.name}@{rule}"
    return gov
