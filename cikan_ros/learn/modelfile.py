"""Model files: ``model.safetensors`` (weights and normalisation, no pickle) + ``card.json``.

The card states the architecture, feature normalisation, dataset (size, seed, recipe), losses,
parameter counts, library versions and the CPU training budget, plus the SHA-256 of the weights
file. :func:`load_model` checks everything and raises :class:`ModelFileError` naming the problem
on a missing, truncated, corrupt or mismatched file. Loading needs numpy and safetensors only
(no torch), so a governor starts fast.
"""

from __future__ import annotations

import hashlib
import json
import math
import platform
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np
from numpy.typing import NDArray

from ..paths import shipped
from .arch import FAMILIES, NORM_TENSORS, Arch, norm_tensor_shapes
from .errors import ModelFileError

if TYPE_CHECKING:
    from ..config import Config

FORMAT = "cikan-model/1"
WEIGHTS = "model.safetensors"
CARD = "card.json"
#: Shipped models: ``models/<family>/`` at the repository root, or in an install's share/cikan_ros.
MODELS_DIR = shipped("models")


@dataclass(frozen=True)
class LoadedModel:
    """A checked model: architecture, tensors (float64 numpy), card and directory."""

    arch: Arch
    tensors: dict[str, NDArray]
    card: dict[str, Any]
    path: Path


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def library_versions() -> dict[str, str]:
    """Versions of the libraries that produced a model."""
    import numpy
    import safetensors

    from .. import __version__

    out = {"python": platform.python_version(), "numpy": numpy.__version__,
           "safetensors": safetensors.__version__, "cikan_ros": __version__}
    try:
        import torch

        out["torch"] = torch.__version__
    except ImportError:  # pragma: no cover - training always has torch
        pass
    return out


def save_model(directory: str | Path, arch: Arch, tensors: Mapping[str, Any],
               card: Mapping[str, Any]) -> Path:
    """Write weights and card into ``directory``. ``tensors``: name -> torch tensor or array
    (trainable tensors as float32, normalisation buffers as float64)."""
    from safetensors.numpy import save_file

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, NDArray] = {}
    for name, t in tensors.items():
        a = t.detach().cpu().numpy() if hasattr(t, "detach") else np.asarray(t)
        arrays[name] = np.ascontiguousarray(a.astype(np.float64 if name in NORM_TENSORS else np.float32))
    _check_tensors(arch, arrays, d / WEIGHTS)
    tmp = d / (WEIGHTS + ".tmp")
    save_file(arrays, str(tmp), metadata={"format": FORMAT, "family": arch.family})
    tmp.replace(d / WEIGHTS)
    full = {
        "format": FORMAT,
        **dict(card),
        "architecture": arch.to_dict(),
        "normalisation": {
            "features": arch.features,
            "feature_mean": arrays["feature_mean"].tolist(),
            "feature_std": arrays["feature_std"].tolist(),
            "target": "ln|tau*| with tau* in s",
            "target_mean": float(arrays["target_mean"][0]),
            "target_std": float(arrays["target_std"][0]),
        },
        "parameters": {"trainable": arch.n_params(), "complexity_n2l_G3": arch.complexity(),
                       "tensors": {k: list(v) for k, v in arch.tensor_shapes().items()}},
        "weights_file": WEIGHTS,
        "weights_sha256": sha256_file(d / WEIGHTS),
    }
    full.setdefault("versions", library_versions())
    (d / (CARD + ".tmp")).write_text(json.dumps(full, indent=2) + "\n")
    (d / (CARD + ".tmp")).replace(d / CARD)
    return d


def card_scenario(meta: Mapping[str, Any]) -> dict[str, str]:
    """The scenario and approach side a model was trained for, from its dataset's metadata
    (datasets written before scenarios existed are the paper's, from behind)."""
    flat = meta.get("config") or {}
    return {"name": str(meta.get("scenario", flat.get("scenario.name", "paper"))),
            "approach": str(meta.get("approach", flat.get("mission.approach", "behind")))}


def check_dataset_scenario(meta: Mapping[str, Any], path: str, scenario: str, approach: str) -> None:
    """DatasetError unless the dataset (metadata ``meta``) is of ``scenario`` and ``approach``."""
    want = {"name": scenario, "approach": approach}
    if card_scenario(meta) != want:
        from .errors import DatasetError

        raise DatasetError(f"dataset {path} is of scenario {card_scenario(meta)}, not {want}: give "
                           "the dataset's --scenario and --set mission.approach")


def check_dataset_labels(meta: Mapping[str, Any], path: str, flat: Mapping[str, Any]) -> None:
    """DatasetError unless the dataset (metadata ``meta``) holds labels of the Verify a flight of
    configuration ``flat`` runs (:func:`label_config`): a model is trained for the Verify it flies."""
    made, wanted = label_config(meta.get("config") or {}), label_config(flat)
    if made != wanted:
        from .errors import DatasetError

        raise DatasetError(f"dataset {path} holds labels of {describe_labels(made)}, not of "
                           f"{describe_labels(wanted)}: give the dataset's --truth, --robust and --set "
                           "options")


#: Beyond the scenario and side, what decides a label tau* under robust Verify (flat configuration
#: keys): the zeta interval and the truth's declared bounds, which size the tube and choose the
#: prediction's gravity. The truth a dataset's missions flew under nominal Verify moves its
#: states, not its labels.
ROBUST_LABEL_KEYS = ("tsg.robust_zeta_s", "truth.name", "truth.scale", "truth.gravity",
                     "truth.thrust_bias_max", "truth.thrust_pointing_max_deg", "truth.disturbance_max_kmps2",
                     "truth.nav_pos_floor_km", "truth.nav_pos_range_fraction", "truth.nav_vel_floor_kmps",
                     "truth.nav_vel_range_fraction_per_s", "truth.nav_rate_per_s", "truth.nav_model",
                     "truth.nav_update_s")


def label_config(flat: Mapping[str, Any]) -> dict[str, Any]:
    """What a label tau* was computed with, from a flat configuration (a dataset's, a card's, a
    mission's; keys absent from an older one take the defaults it was made with: nominal Verify):
    the Verify mode (``tsg.robust``), the LQ weights of the controller that Verify predicts
    (``control.q_diag`` and ``control.r_diag``, or ``control.robust_r_diag`` under robust Verify:
    ``config.control_config``) and, under robust Verify, :data:`ROBUST_LABEL_KEYS`."""
    robust = bool(flat.get("tsg.robust", False))
    r_key = "control.robust_r_diag" if robust else "control.r_diag"
    out: dict[str, Any] = {"tsg.robust": robust, "control.q_diag": flat.get("control.q_diag"),
                           r_key: flat.get(r_key)}
    if robust:
        out.update({k: flat.get(k) for k in ROBUST_LABEL_KEYS})
        # The tube sets which shifts robust Verify accepts (configurations before it: the ball's).
        out["tsg.tube"] = flat.get("tsg.tube", "ball")
        if out["tsg.tube"] == "ancillary":
            out.update({k: flat.get(k) for k in ("tsg.ancillary_gamma", "tsg.ancillary_r_diag")})
            # the between-samples bound (configurations before it: the samples only)
            out["tsg.ancillary_between"] = flat.get("tsg.ancillary_between", False)
            # the FTRE law of the terminal handoff (before it: the robust controller's)
            out["tsg.ancillary_handoff_r_diag"] = flat.get("tsg.ancillary_handoff_r_diag",
                                                           flat.get("control.robust_r_diag"))
            # the gain schedule by range (named only when set: configurations before it had one gain)
            if flat.get("tsg.ancillary_bands_km"):
                out.update({k: flat.get(k) for k in ("tsg.ancillary_bands_km", "tsg.ancillary_bands_r")})
            # the l1 bound (named only when set: configurations before it had the geometric one)
            if flat.get("tsg.ancillary_bound", "geometric") != "geometric":
                out["tsg.ancillary_bound"] = flat["tsg.ancillary_bound"]
    return out


def describe_labels(labels: Mapping[str, Any]) -> str:
    """One phrase for :func:`label_config`: "nominal Verify (controller R = 1)" or "robust Verify
    (truth realistic at scale 1.0, controller R = 1e+07)"."""
    robust = labels["tsg.robust"]
    r = labels.get("control.robust_r_diag" if robust else "control.r_diag") or [math.nan]
    if not robust:
        return f"nominal Verify (controller R = {float(r[0]):g})"
    tube = "" if labels.get("tsg.tube", "ball") == "ball" else f", {labels['tsg.tube']} tube"
    if tube and labels.get("tsg.ancillary_bound", "geometric") != "geometric":
        tube += f" ({labels['tsg.ancillary_bound']} bound)"
    return (f"robust Verify (truth {labels.get('truth.name')} at scale {labels.get('truth.scale')}, "
            f"controller R = {float(r[0]):g}{tube})")


def label_mismatch(card: Mapping[str, Any], flat: Mapping[str, Any]) -> str | None:
    """None when the model of ``card`` was trained on labels of the Verify a flight of configuration
    ``flat`` runs, else what differs, in words (the keys that differ named)."""
    made, flown = label_config(card.get("config") or {}), label_config(flat)
    if made == flown:
        return None
    text = f"trained on labels of {describe_labels(made)}, not of {describe_labels(flown)}"
    if made["tsg.robust"] != flown["tsg.robust"]:
        return text
    # a key one side has and the other not (the ancillary tube's settings under the ball tube) differs
    return text + f" (differs: {', '.join(sorted(k for k in made.keys() | flown.keys() if made.get(k) != flown.get(k)))})"


def model_scenario(card: Mapping[str, Any]) -> dict[str, str]:
    """``{"name": scenario, "approach": side}`` a model card declares (cards written before
    scenarios existed: the paper's, from behind; their dataset says so)."""
    sc = card.get("scenario")
    if isinstance(sc, Mapping) and "name" in sc and "approach" in sc:
        return {"name": str(sc["name"]), "approach": str(sc["approach"])}
    return card_scenario({**(card.get("dataset") or {}), "config": card.get("config") or {}})


def scenario_model_dir(models_dir: str, family: str, approach: str, robust: bool = False) -> Path:
    """Where a scenario keeps family ``family``'s model for ``approach`` and the Verify it learned:
    ``<models_dir>/<family>`` behind, ``<models_dir>/<family>-ahead`` ahead, with ``-robust``
    appended for labels of robust Verify (``tsg.robust``); ``models_dir`` relative to the project
    root (or an install's share/cikan_ros) unless absolute."""
    root = Path(models_dir)
    if not root.is_absolute():
        root = MODELS_DIR.parent / root
    return root / (family + ("" if approach == "behind" else "-ahead") + ("-robust" if robust else ""))


def flown_model_dir(cfg: Config, family: str) -> Path:
    """The directory of the model family ``family`` flies in configuration ``cfg``: the scenario's,
    for its approach side and Verify mode (:func:`scenario_model_dir`); under robust Verify with
    ``learned.foreign_model`` and no model of robust labels, the nominal one (flown as foreign)."""
    models_dir, approach = cfg.scenario.models_dir, cfg.mission.approach
    where = scenario_model_dir(models_dir, family, approach, cfg.tsg.robust)
    nominal = scenario_model_dir(models_dir, family, approach)
    if not (where / CARD).is_file() and cfg.learned.foreign_model and (nominal / CARD).is_file():
        return nominal
    return where


def resolve(name_or_path: str | Path) -> Path:
    """A family name (``models/<family>/``), a model directory, or a file inside one."""
    s = str(name_or_path)
    if (s in FAMILIES or (MODELS_DIR / s / CARD).exists()) and not Path(s).exists():
        d = MODELS_DIR / s  # a shipped model: models/<family>/ or another directory there
    else:
        p = Path(s)
        d = p.parent if p.is_file() or p.name in (WEIGHTS, CARD) else p
    if not d.is_dir():
        raise ModelFileError(f"model directory not found: {d}")
    return d


def _check_tensors(arch: Arch, arrays: Mapping[str, NDArray], where: Path) -> None:
    expected = {**arch.tensor_shapes(), **norm_tensor_shapes(arch.n_in)}
    missing = sorted(set(expected) - set(arrays))
    extra = sorted(set(arrays) - set(expected))
    if missing or extra:
        raise ModelFileError(f"{where}: tensors do not match the {arch.family} architecture "
                             f"(missing {missing[:4]}{'...' if len(missing) > 4 else ''}, "
                             f"unexpected {extra[:4]}{'...' if len(extra) > 4 else ''})")
    for name, shape in expected.items():
        a = arrays[name]
        if tuple(a.shape) != tuple(shape):
            raise ModelFileError(f"{where}: tensor {name} has shape {tuple(a.shape)}, the card's "
                                 f"architecture needs {tuple(shape)}")
        if not np.all(np.isfinite(a)):
            raise ModelFileError(f"{where}: tensor {name} has non-finite values")
    for name in ("feature_std", "target_std"):
        if not np.all(arrays[name] > 0):
            raise ModelFileError(f"{where}: normalisation {name} must be > 0")


def load_model(name_or_path: str | Path) -> LoadedModel:
    """Load and check a model directory; every failure is a :class:`ModelFileError`."""
    from safetensors import SafetensorError
    from safetensors.numpy import load_file

    d = resolve(name_or_path)
    card_path, weights_path = d / CARD, d / WEIGHTS
    for p, what in ((card_path, "card"), (weights_path, "weights file")):
        if not p.is_file():
            raise ModelFileError(f"model {what} missing: {p}")
    try:
        card = json.loads(card_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ModelFileError(f"model card {card_path} is not valid JSON ({exc})") from None
    if not isinstance(card, dict) or card.get("format") != FORMAT:
        raise ModelFileError(f"model card {card_path} is not a {FORMAT} card "
                             f"(format = {card.get('format') if isinstance(card, dict) else None!r})")
    for key in ("architecture", "normalisation", "weights_sha256", "parameters"):
        if key not in card:
            raise ModelFileError(f"model card {card_path} lacks {key!r}")
    arch = Arch.from_dict(card["architecture"])
    digest = sha256_file(weights_path)
    if digest != card["weights_sha256"]:
        raise ModelFileError(f"weights file {weights_path} does not match its card (SHA-256 "
                             f"{digest[:12]}... != {str(card['weights_sha256'])[:12]}...): "
                             "truncated, corrupt or replaced")
    try:
        raw = load_file(str(weights_path))
    except (SafetensorError, OSError, ValueError) as exc:
        raise ModelFileError(f"weights file {weights_path} is not a readable safetensors file "
                             f"({exc})") from None
    for name, a in raw.items():
        want = np.float64 if name in NORM_TENSORS else np.float32
        if a.dtype != want:
            raise ModelFileError(f"{weights_path}: tensor {name} is {a.dtype}, expected {np.dtype(want)}")
    _check_tensors(arch, raw, weights_path)
    norm = card["normalisation"]
    if norm.get("features") != arch.features:
        raise ModelFileError(f"{card_path}: normalisation is for feature set "
                             f"{norm.get('features')!r}, architecture uses {arch.features!r}")
    for name in ("feature_mean", "feature_std", "target_mean", "target_std"):
        card_v = np.atleast_1d(np.asarray(norm.get(name), dtype=np.float64))
        if card_v.shape != raw[name].shape or not np.array_equal(card_v, raw[name]):
            raise ModelFileError(f"{card_path}: normalisation {name} differs from the weights file")
    if card["parameters"].get("trainable") != arch.n_params():
        raise ModelFileError(f"{card_path}: parameter count {card['parameters'].get('trainable')} "
                             f"!= {arch.n_params()} of the architecture")
    tensors = {k: v.astype(np.float64) for k, v in raw.items()}
    if not math.isfinite(float(tensors["target_mean"][0])):  # pragma: no cover - checked above
        raise ModelFileError(f"{weights_path}: non-finite target normalisation")
    return LoadedModel(arch, tensors, card, d)
