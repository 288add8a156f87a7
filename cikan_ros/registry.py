"""The governors by name: the conventional TSG, the learned model families of ``models/`` and model
paths, each optionally with its update rule (``NAME@keep``, ``NAME@paper``).

Above both :mod:`cikan_ros.governor` (the protocol and the conventional TSG) and the learned
governor (:mod:`cikan_ros.learn.governor`): the core modules never import ``learn/``, and whatever
turns a name into a governor (``cikan`` commands, Monte Carlo, the dataset generator, the governor
node) imports this module.
"""

from __future__ import annotations

import json

from .config import LEARNED_ALGORITHMS, Config
from .governor import ConventionalGovernor, Governor
from .learn.governor import foreign_reason, load_learned_governor
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


def shipped_models(cfg: Config) -> dict[str, str | None]:
    """Every learned family with a model in the place of the configuration's scenario, approach
    side and Verify mode (``scenario.models_dir``), and why that model was made for another
    configuration (:func:`~cikan_ros.learn.governor.foreign_reason`; None: made for this one)."""
    out: dict[str, str | None] = {}
    for n in LEARNED_NAMES:
        card = scenario_model_dir(cfg.scenario.models_dir, n, cfg.mission.approach, cfg.tsg.robust) / CARD
        if card.is_file():
            try:
                out[n] = foreign_reason(json.loads(card.read_text()), cfg)
            except (OSError, ValueError, KeyError, TypeError) as exc:   # flown, it is refused naming the file
                out[n] = f"unreadable card {card}: {exc}"
    return out


def shipped_names(cfg: Config) -> list[str]:
    """The conventional TSG and every learned family whose model in the configuration's place
    (:func:`shipped_models`) was made for it, or any there with ``learned.foreign_model``."""
    return ["conventional"] + [n for n, why in shipped_models(cfg).items()
                               if why is None or cfg.learned.foreign_model]


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
