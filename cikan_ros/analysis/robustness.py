"""The robustness campaign's table and figure (``make robustness``, ``cikan report DIR --robustness``).

The campaign directory holds one ``cikan montecarlo`` output per configuration (any names):
each run's JSON carries its configuration, from which the truth model, ``truth.scale``, the
Verify (``tsg.robust``) and the controller's LQ control weight R the loop flew
(:func:`cikan_ros.config.control_config`) are read. Rows: governor x Verify x R x scale. The
Delta-V reference is the
conventional TSG with nominal Verify in the nominal world (the truth at scale 0, or the nominal
truth) on the same starts: ratio = sum of Delta-V over the runs flown / sum of the reference's
Delta-V over the same seeds.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import CikanError
from ..montecarlo import between_total
from ..paths import SOURCE_ROOT


@dataclass
class Cell:
    """The runs of one governor under one configuration."""

    governor: str
    robust: bool
    r_weight: float   # the LQ control weight R (x I) the controller flew
    scale: float
    truth: str
    dock_m: float
    dock_mps: float
    #: Robust Verify's tube ("ball", "ancillary"; "-" under nominal Verify), the ancillary tube's
    #: gamma (NaN otherwise) and the truth's navigation model.
    tube: str = "-"
    gamma: float = math.nan
    nav_model: str = "realistic"
    runs: dict[int, dict[str, Any]] = field(default_factory=dict)   # seed -> metrics

    @property
    def flown(self) -> list[dict[str, Any]]:
        return [m for m in self.runs.values() if "refused" not in m]

    def docked(self, m: dict[str, Any]) -> bool:
        return (m.get("final_distance_m") is not None and m["final_distance_m"] < self.dock_m
                and m["final_speed_mps"] < self.dock_mps)


def flown_r_weight(cfg: dict[str, Any]) -> float:
    """The controller's R (first diagonal entry) a run's flat configuration flew: as
    :func:`cikan_ros.config.control_config` picks it (runs stored before control.robust_r_diag
    existed flew control.r_diag)."""
    key = "control.robust_r_diag" if cfg.get("tsg.robust") and "control.robust_r_diag" in cfg \
        else "control.r_diag"
    return float(cfg.get(key, [1.0])[0])


def load_cells(root: str | Path) -> list[Cell]:
    """Every (governor, Verify, R, scale) cell of a campaign directory (``*/<governor>/seed_*.json``)."""
    cells: dict[tuple[str, bool, float, float, str], Cell] = {}
    root = Path(root)
    for js in sorted(root.glob("*/*/seed_*.json")):
        try:
            stored = json.loads(js.read_text())
            m, cfg = stored["metrics"], stored["config"]
        except (OSError, json.JSONDecodeError, KeyError):
            continue
        robust = bool(cfg.get("tsg.robust", False))
        scale = float(cfg.get("truth.scale", 0.0))
        truth = str(cfg.get("truth.name", "nominal"))
        if truth == "nominal":
            scale = 0.0  # the nominal truth is scale 0 of every truth
        r_weight = flown_r_weight(cfg)
        # runs stored before the ancillary tube flew the ball
        tube = str(cfg.get("tsg.tube", "ball")) if robust else "-"
        gamma = float(cfg.get("tsg.ancillary_gamma", math.nan)) if tube == "ancillary" else math.nan
        nav = str(cfg.get("truth.nav_model", "realistic")) if scale > 0 else "realistic"
        key = (m["governor"], robust, r_weight, scale, truth if scale > 0 else "nominal", tube, gamma, nav)
        cell = cells.get(key)
        if cell is None:
            cell = cells[key] = Cell(m["governor"], robust, r_weight, scale, key[4],
                                     float(cfg["mission.dock_distance_km"]) * 1e3,
                                     float(cfg["mission.dock_speed_kmps"]) * 1e3, tube, gamma, nav)
        cell.runs[int(m["seed"])] = m
    if not cells:
        raise CikanError(f"no Monte Carlo runs under {root} (expected <config>/<governor>/seed_*.json)")
    return sorted(cells.values(), key=lambda c: (c.robust, c.tube, c.r_weight, c.nav_model, c.scale,
                                                 c.governor != "conventional", c.governor))


def reference(cells: list[Cell]) -> dict[int, float]:
    """seed -> Delta-V (km/s) of the nominal conventional TSG (nominal Verify, the paper's
    controller R = I, nominal world)."""
    for c in cells:
        if c.governor == "conventional" and not c.robust and c.scale == 0.0 and c.r_weight == 1.0:
            return {s: m["delta_v_kmps"] for s, m in c.runs.items() if "refused" not in m}
    return {}


def cell_row(c: Cell, ref: dict[int, float]) -> dict[str, Any]:
    """The table's figures of one cell."""
    flown = c.flown
    seeds = [s for s, m in c.runs.items() if "refused" not in m and s in ref]
    dv_ratio = (sum(c.runs[s]["delta_v_kmps"] for s in seeds) / sum(ref[s] for s in seeds)
                if seeds else math.nan)
    tz = [m["t_tau_zero_s"] for m in flown if m.get("t_tau_zero_s") is not None]
    return {
        "governor": c.governor, "verify": "robust" if c.robust else "nominal", "r_weight": c.r_weight,
        "scale": c.scale, "tube": c.tube, "gamma": c.gamma, "nav_model": c.nav_model,
        "runs": len(c.runs), "refused": len(c.runs) - len(flown),
        "violation_steps": sum(int(m["violations"]) for m in flown),
        "runs_violated": sum(1 for m in flown if m["violations"]),
        "violations_between": between_total(flown),
        "docked": sum(1 for m in flown if c.docked(m)),
        "successes": sum(1 for m in flown if m["success"]),
        "delta_v_kmps_mean": (sum(m["delta_v_kmps"] for m in flown) / len(flown)) if flown else math.nan,
        "delta_v_ratio": dv_ratio,
        "tau_zero_runs": len(tz),
        "t_tau_zero_s_mean": sum(tz) / len(tz) if tz else math.nan,
        "dock_test": f"{c.dock_m:g} m, {c.dock_mps:g} m/s",
    }


def _fmt(v: float, spec: str) -> str:
    return "-" if not math.isfinite(v) else format(v, spec)


def markdown_table(rows: list[dict[str, Any]]) -> str:
    """One row per governor, Verify, controller weight and scale."""
    lines = ["| Verify | tube | controller R | truth.scale | navigation | governor | runs | refused "
             "| violating steps (runs) | violating between samples | docked | success | ΔV mean (km/s) "
             "| ΔV / nominal conventional | τ = 0 reached | t(τ = 0) mean (s) | docking test |",
             "|" + "---|" * 17]
    for r in rows:
        tube = r["tube"] if not math.isfinite(r["gamma"]) else f"{r['tube']}, γ {r['gamma']:g}"
        lines.append(
            f"| {r['verify']} | {tube} | {r['r_weight']:g} | {r['scale']:g} | {r['nav_model']} "
            f"| {r['governor']} | {r['runs']} "
            f"| {r['refused']} "
            f"| {r['violation_steps']} ({r['runs_violated']}) "
            f"| {'-' if r['violations_between'] is None else r['violations_between']} "
            f"| {r['docked']} | {r['successes']} "
            f"| {_fmt(r['delta_v_kmps_mean'], '.3f')} | {_fmt(r['delta_v_ratio'], '.3f')} "
            f"| {r['tau_zero_runs']} | {_fmt(r['t_tau_zero_s_mean'], '.0f')} | {r['dock_test']} |")
    return "\n".join(lines) + "\n"


def figure(rows: list[dict[str, Any]], path: Path) -> None:
    """Per Verify and controller weight flown at more than one scale (columns): runs with a
    violation, runs docked and the Delta-V ratio against truth.scale, one line per governor."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def combo(r: dict[str, Any]) -> tuple[str, str, float, str]:  # a column: one Verify across scales
        return r["verify"], r["tube"], r["r_weight"], r["nav_model"]

    combos = sorted({combo(r) for r in rows}, key=lambda vr: (vr[0] == "robust", vr[1], vr[2], vr[3]))
    combos = [vr for vr in combos
              if len({r["scale"] for r in rows if combo(r) == vr}) > 1] or combos
    fig, axes = plt.subplots(3, len(combos), figsize=(5 * len(combos), 9), sharex=True,
                             sharey="row", squeeze=False)
    governors = sorted({r["governor"] for r in rows}, key=lambda g: (g != "conventional", g))
    for col, (verify, tube, r_weight, nav) in enumerate(combos):
        for g in governors:
            pts = sorted(((r["scale"], r) for r in rows if combo(r) == (verify, tube, r_weight, nav)
                          and r["governor"] == g), key=lambda p: p[0])
            if not pts:
                continue
            xs = [s for s, _ in pts]
            axes[0, col].plot(xs, [r["runs_violated"] / r["runs"] for _, r in pts], "o-", label=g)
            axes[1, col].plot(xs, [r["docked"] / r["runs"] for _, r in pts], "o-", label=g)
            axes[2, col].plot(xs, [r["delta_v_ratio"] for _, r in pts], "o-", label=g)
        axes[0, col].set_title(f"{verify} Verify{'' if tube == '-' else ', ' + tube + ' tube'}, "
                               f"R = {r_weight:g}{'' if nav == 'realistic' else ', ' + nav}", fontsize=9)
        axes[2, col].set_xlabel("truth.scale (realistic)")
    axes[0, 0].set_ylabel("runs with a violation")
    axes[1, 0].set_ylabel("runs docked (refused: not)")
    axes[2, 0].set_ylabel("ΔV / nominal conventional")
    axes[0, -1].legend(fontsize=8)
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_robustness(source: str | Path, out_dir: str | Path, notes: str | None = None,
                     title: str | None = None, name: str = "robustness") -> Path:
    """<name>.md and <name>.png of a campaign directory; returns the page's path."""
    cells = load_cells(source)
    ref = reference(cells)
    rows = [cell_row(c, ref) for c in cells]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figure(rows, out / f"{name}.png")
    page = out / f"{name}.md"
    derivation = os.path.relpath(SOURCE_ROOT / "docs" / "robustness.md", out.resolve())  # the page links it from where it lies
    text = [f"# {title or 'Robustness: nominal and robust Verify in the realistic world'}", "",
            f"Generated by `cikan report {source} --robustness --out {out_dir}"
            f"{'' if name == 'robustness' else ' --name ' + name}` from the campaign "
            "its make target flies (`make robustness`, `make controller-sweep`, `make "
            "scenario-controller-sweep`); the models and the derivation are in "
            f"[robustness.md]({derivation}). Violations, docking and ΔV are judged on the "
            "truth; ΔV / nominal conventional is the sum of ΔV over the runs flown divided by the "
            "nominal conventional TSG's (nominal Verify, the paper's controller, nominal world) on "
            "the same starts. Controller R: the FTRE controller's LQ control weight the loop flew "
            "(R = 1: the paper's; robust Verify flies `control.robust_r_diag`). "
            "Refused: runs for which robust Verify found no feasible shift at the start, or whose "
            "declared thruster errors exceed the controller's stability margin (no run flown).", "",
            markdown_table(rows), f"![{name}]({name}.png)", ""]
    if notes:
        text += [notes.strip(), ""]
    page.write_text("\n".join(text))
    return page
