"""Tables of the shipped models from their cards, and the loss breakdown on a dataset.

``cikan models`` prints them (``--out models/README.md`` rewrites that page): every figure of
``models/README.md`` comes from here, none is typed by hand.

- :func:`card_table`: size, parameter counts, the paper's complexity, losses (the paper's
  definition, L = mean((y - ŷ)²) + θ_c mean(ReLU(y - ŷ)²), y = ln|τ*|), training budget and
  TPE study of each model directory under ``models/``, next to the paper's L_val.
- :func:`loss_breakdown`: the same loss (θ_c = 1) of each model on one split of a dataset,
  by band of |τ*| and by kind of update: "hold" (π* within 1e-4 s of τ_{k-1}: the deputy rides
  the line-of-sight cone) or "move".
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ModelFileError
from .modelfile import MODELS_DIR, LoadedModel, card_scenario, label_config, load_model, model_scenario

#: The paper's validation losses (Table 2, ×1e-3 there).
PAPER_VAL = {"cikan": 1.2615e-3, "grbf": 1.1540e-3, "rswaf": 1.2610e-3, "relu": 1.6458e-3,
             "gelu": 1.8538e-3}
#: Bands of |τ*| (s) of the breakdown.
BANDS = ((0.0, 0.05), (0.05, 1.0), (1.0, 5.0), (5.0, np.inf))
#: π* within this of τ_{k-1} (s) is a "hold" update.
HOLD_S = 1e-4


def shipped_models(root: Path = MODELS_DIR) -> list[LoadedModel | tuple[str, str]]:
    """Every model directory under ``root``, the scenarios' subdirectories included (sorted),
    loaded and checked, or (name relative to ``root``, error)."""
    out: list[LoadedModel | tuple[str, str]] = []
    for d in sorted(p.parent for p in root.rglob("card.json")):
        try:
            out.append(load_model(d))
        except ModelFileError as exc:
            out.append((d.relative_to(root).as_posix(), str(exc)))
    return out


def _name(path: Path) -> str:
    """A model directory's name under ``models/`` (``cikan``, ``leo/cikan-ahead``)."""
    try:
        return Path(path).resolve().relative_to(MODELS_DIR.resolve()).as_posix()
    except ValueError:
        return Path(path).name


def card_table(models: list[LoadedModel | tuple[str, str]]) -> str:
    """Markdown: one row per model directory, from its card."""
    rows = ["| model | scenario, side, Verify | inputs | (n, l, G) | params | n²l(G+3) | θ_c | L_train | L_val | L_test "
            "| L_val (θ_c=1) | L_val paper | RMSE τ test (s) | train labels | epochs | CPU wall (s) "
            "| TPE trials (complete/pruned) |",
            "|" + "---|" * 17]
    for m in models:
        if isinstance(m, tuple):
            rows.append(f"| {m[0]} | unreadable: {m[1]} |" + " |" * 15)
            continue
        a, c = m.arch, m.card
        L, tr, tun = c["losses"], c["training"], c.get("tuning", {})
        size = f"({a.width}, {a.layers}, {a.grid})" if a.is_kan else f"({a.width}, {a.layers}, -)"
        labels = c.get("dataset", {}).get("split_labels", {}).get("train", "-")
        sc = model_scenario(c)
        inputs = f"{a.features}, {a.target}" if a.relative else a.features
        rows.append(
            f"| {_name(m.path)} | {sc['name']}, {sc['approach']}, {_verify(c.get('config') or {})} | {inputs} | {size} | {a.n_params():,} | {a.complexity():,} "
            f"| {L['theta_c']:.2f} | {L['train']['loss']:.3e} | {L['val']['loss']:.3e} "
            f"| {L['test']['loss']:.3e} | {L['val']['loss_theta1']:.3e} | {PAPER_VAL[a.family]:.3e} "
            f"| {L['test']['rmse_tau_s']:.3f} | {labels:,} | {tr['epochs_run']}/{tr['epochs']} "
            f"| {tr['cpu_budget']['wall_s']:.0f} | {tun.get('trials', 0)} "
            f"({tun.get('complete', 0)}/{tun.get('pruned', 0)}) |")
    return "\n".join(rows) + "\n"


def _verify(flat: dict[str, Any]) -> str:
    """The Verify whose labels a configuration (a card's, a dataset's) made: "nominal" or "robust"."""
    return "robust" if label_config(flat)["tsg.robust"] else "nominal"


def loss_breakdown(models: list[LoadedModel | tuple[str, str]], data_path: str | Path,
                   split: str = "val") -> str:
    """Markdown: loss (θ_c = 1) of each model on ``split`` of a dataset, by |τ*| band and by
    hold/move update, with the share of labels in each group."""
    from .arch import NumpyNet
    from .dataset import XC_COLS, XD_COLS, read_parquet
    from .features import features
    from .loss import cinn_log_loss_np

    df, meta = read_parquet(data_path)
    part = df[df["split"] == split]
    tau = part["tau_star_s"].to_numpy(dtype=float)
    prev = part["tau_prev_s"].to_numpy(dtype=float)
    y = np.log(np.abs(tau))
    mag = np.abs(tau)
    groups: list[tuple[str, np.ndarray]] = [("all", np.ones(len(y), bool))]
    groups += [(f"\\|τ*\\| in [{lo:g}, {hi:g}) s", (mag >= lo) & (mag < hi)) for lo, hi in BANDS]
    hold = np.abs(tau - prev) <= HOLD_S
    groups += [("hold (\\|π* - τ_{k-1}\\| <= 1e-4 s)", hold), ("move", ~hold)]
    # The models of the dataset's scenario, side and Verify only (the others learned other labels).
    made = label_config(meta.get("config") or {})
    ok = [m for m in models if not isinstance(m, tuple) and model_scenario(m.card) == card_scenario(meta)
          and label_config(m.card.get("config") or {}) == made]
    head = "| labels | share of split | " + " | ".join(_name(m.path) for m in ok) + " |"
    sc = card_scenario(meta)
    lines = [f"Split `{split}` of `{Path(data_path).name}` (scenario {sc['name']}, approach "
             f"{sc['approach']}, {_verify(meta.get('config') or {})} Verify; {len(y):,} labels); loss = the "
             "paper's definition at θ_c = 1.", "",
             head, "|" + "---|" * (2 + len(ok))]
    preds = {}
    x_d = part[list(XD_COLS)].to_numpy()
    x_c = part[list(XC_COLS)].to_numpy()
    for m in ok:
        net = NumpyNet(m.arch, m.tensors)
        preds[m.path.name] = net.log_shift(features(x_d, x_c, m.arch.features, prev))
    for name, mask in groups:
        cells = [f"{cinn_log_loss_np(preds[m.path.name][mask], y[mask]):.3e}" if mask.any() else "-"
                 for m in ok]
        lines.append(f"| {name} | {mask.mean():.1%} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


#: A loss breakdown's first line names the labels it was computed on (:func:`loss_breakdown`).
_BREAKDOWN_KEY = re.compile(r"^Split `[^`]*` of `[^`]*` \(scenario (\S+), approach (\S+), (\S+) Verify;")


def _breakdown_sections(page: str) -> dict[tuple[str, str, str], str]:
    """The loss breakdowns of a models page, by (scenario, approach, Verify) of their labels."""
    out: dict[tuple[str, str, str], str] = {}
    key, lines = None, []
    for line in page.splitlines() + ["*"]:
        m = _BREAKDOWN_KEY.match(line)
        if m or line.startswith("*"):
            if key is not None:
                out[key] = "\n".join(lines).rstrip() + "\n"
            key, lines = (m.groups() if m else None), []
        if key is not None:
            lines.append(line)
    return out


def _breakdown_order(key: tuple[str, str, str]) -> tuple[str, str, int]:
    """The page's order: scenario, side, robust Verify before nominal (the datasets' path order)."""
    return key[0], key[1], 0 if key[2] == "robust" else 1


def models_page(intro: str, data_path: str | Path | list[str | Path] | None, split: str = "val",
                root: Path = MODELS_DIR, out: str | Path | None = "models/README.md"
                ) -> tuple[str, dict[str, Any]]:
    """The whole ``models/README.md``: a fixed introduction, then the generated tables (a loss
    breakdown per dataset, for the models of its scenario and side); the footer names the
    command that wrote it (``out``: its --out, None for standard output). A breakdown already on
    the page at ``out`` whose labels (scenario, side, Verify) no dataset given covers is kept as
    it was (its dataset need not be on this machine), and the footer says which."""
    models = shipped_models(root)
    parts = [intro.rstrip() + "\n", "## Models (from the cards)\n", card_table(models)]
    paths = [] if data_path is None else [data_path] if isinstance(data_path, (str, Path)) else list(data_path)
    sections: dict[tuple[str, str, str], str] = {}
    for p in paths:
        text = loss_breakdown(models, p, split)
        m = _BREAKDOWN_KEY.match(text)
        sections[m.groups() if m else (str(p), "", "")] = text
    kept = []
    if out is not None and Path(out).is_file():
        for key, text in _breakdown_sections(Path(out).read_text()).items():
            if key not in sections:
                sections[key] = text
                kept.append(key)
    if sections:
        parts.append("\n## Loss by |τ*| band and by hold/move update\n")
    parts += [sections[k] for k in sorted(sections, key=_breakdown_order)]
    said = ""
    if kept:
        names = ", ".join(f"{sc} {side} {v}" for sc, side, v in sorted(kept, key=_breakdown_order))
        said = f"; the breakdowns of {names} kept from the page before (their datasets were not given)"
    parts.append("\n*Generated by `cikan models" + (f" --data {' '.join(map(str, paths))}" if paths else "")
                 + (f" --out {out}" if out else "") + f"`{said}; do not edit the tables by hand.*\n")
    return "\n".join(parts), {"models": len(models)}
