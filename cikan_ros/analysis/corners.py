"""The corner campaign's table (``cikan montecarlo --corners``, ``make corners``, ``cikan report
DIR --corners``): per corner of the truth's declared bounds and governor, the runs flown, the
violating control steps and the violating states between samples (on the truth), the runs docked
(by the mission's test, and within the ball robust Verify certified for the final step, under
the ancillary tube) and the largest final distance; one row per governor over all corners below
them.

The campaign directory is ``<corner>/<governor>/seed_*.json`` (what ``cikan montecarlo
--corners`` writes); each run's metrics name their ``corner``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from ..errors import CikanError
from ..montecarlo import between_total

#: Row label of a governor's runs over every corner.
ALL_CORNERS = "all corners"


def ends_docked(m: dict[str, Any]) -> bool:
    """Did a flown run end within its docking test (distance and speed, as its metrics say)?"""
    return (m.get("final_distance_m") is not None and m["final_distance_m"] < m["dock_distance_m"]
            and m["final_speed_mps"] < m["dock_speed_mps"])


def _row(corner: str, governor: str, runs: list[dict[str, Any]]) -> dict[str, Any]:
    flown = [m for m in runs if "refused" not in m]
    between = between_total(flown)
    return {
        "corner": corner, "governor": governor, "runs": len(runs), "refused": len(runs) - len(flown),
        "violation_steps": sum(int(m["violations"]) for m in flown),
        "runs_violated": sum(1 for m in flown if m["violations"]),
        "violations_between": between,
        "runs_violated_between": None if between is None else
        sum(1 for m in flown if m["violations_between"]),
        "docked": sum(1 for m in flown if ends_docked(m)),
        # the docking test robust Verify certified (the ancillary tube, tau = 0: None elsewhere)
        "certified": sum(1 for m in flown if "dock_certified_m" in m),
        "docked_certified": sum(1 for m in flown if m.get("docked_certified")),
        "certified_ball_max": (max((m["dock_certified_m"] for m in flown if "dock_certified_m" in m), default=math.nan),
                               max((m["dock_certified_mps"] for m in flown if "dock_certified_mps" in m),
                                   default=math.nan)),
        "successes": sum(1 for m in flown if m["success"]),
        "final_distance_m_max": max((m["final_distance_m"] for m in flown), default=math.nan),
        "delta_v_kmps_mean": (sum(m["delta_v_kmps"] for m in flown) / len(flown)) if flown else math.nan,
    }


def corner_rows(results: dict[str, list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """Rows of the table from {governor: [metrics of its runs, each with its ``corner``]}: per
    governor, its runs over every corner, then one row per corner (in the order flown)."""
    rows = []
    for governor, runs in results.items():
        rows.append(_row(ALL_CORNERS, governor, runs))
        names = list(dict.fromkeys(m.get("corner", "-") for m in runs))
        rows += [_row(c, governor, [m for m in runs if m.get("corner", "-") == c]) for c in names]
    return rows


def _fmt(v: float | None, spec: str) -> str:
    return "-" if v is None or not math.isfinite(v) else format(v, spec)


def markdown_corner_table(rows: list[dict[str, Any]]) -> str:
    """The table: one row per governor over all corners, then per corner."""
    lines = ["| governor | corner | runs | refused | violating steps (runs) | violating between samples "
             "(runs) | docked | success | docked in the certified ball (of certified), largest ball (m, mm/s) "
             "| final distance max (m) | ΔV mean (km/s) |", "|" + "---|" * 11]
    for r in rows:
        ball_p, ball_v = r["certified_ball_max"]
        certified = "-" if not r["certified"] else \
            f"{r['docked_certified']} ({r['certified']}), {ball_p:.3f}, {ball_v * 1e3:.2f}"  # m/s -> mm/s
        between = "-" if r["violations_between"] is None else \
            f"{r['violations_between']} ({r['runs_violated_between']})"
        corner = f"**{r['corner']}**" if r["corner"] == ALL_CORNERS else f"`{r['corner']}`"
        lines.append(
            f"| {r['governor']} | {corner} | {r['runs']} | {r['refused']} "
            f"| {r['violation_steps']} ({r['runs_violated']}) | {between} | {r['docked']} "
            f"| {r['successes']} | {certified} | {_fmt(r['final_distance_m_max'], '.4f')} "
            f"| {_fmt(r['delta_v_kmps_mean'], '.3f')} |")
    return "\n".join(lines) + "\n"


def load_corner_runs(root: str | Path) -> tuple[dict[str, list[dict[str, Any]]], dict[str, Any]]:
    """({governor: [metrics]}, the flat configuration of one run) of a corner campaign directory."""
    out: dict[str, list[dict[str, Any]]] = {}
    cfg: dict[str, Any] = {}
    for js in sorted(Path(root).glob("*/*/seed_*.json")):
        try:
            stored = json.loads(js.read_text())
            m, cfg = stored["metrics"], stored["config"]
        except (OSError, json.JSONDecodeError, KeyError):
            continue
        if "corner" in m:
            out.setdefault(m["governor"], []).append(m)
    if not out:
        raise CikanError(f"no corner runs under {root} (expected <corner>/<governor>/seed_*.json "
                         "from `cikan montecarlo --corners`)")
    return out, cfg


def write_corners(source: str | Path, out_dir: str | Path, notes: str | None = None,
                  title: str | None = None, name: str = "corners") -> Path:
    """<name>.md of a corner campaign directory; returns the page's path."""
    results, cfg = load_corner_runs(source)
    seeds = sorted({int(m["seed"]) for runs in results.values() for m in runs})
    verify = "robust" if cfg.get("tsg.robust") else "nominal"
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    page = out / f"{name}.md"
    text = [f"# {title or 'Corners: the truth pinned to every corner of its declared bounds'}", "",
            f"Generated by `cikan report {source} --corners --out {out_dir}"
            f"{'' if name == 'corners' else ' --name ' + name}` from the campaign `make corners` "
            f"flies: truth `{cfg.get('truth.name')}` x {cfg.get('truth.scale')}, {verify} Verify, "
            f"navigation model `{cfg.get('truth.nav_model', 'realistic')}`, seeds "
            f"{seeds[0]}-{seeds[-1]} ({len(seeds)} start{'s' if len(seeds) > 1 else ''}) at every corner. A corner `bB.AXISR.dD.nN` "
            "pins the thrust bias to B b_max, the pointing error to a rotation by R theta_max about "
            "the chief's VNB axis AXIS at the epoch, the disturbance to D d_max along the chief's "
            "velocity and the navigation error to N (b_p, b_v) along the line of sight "
            "([../robustness.md](../robustness.md), \"Corners, the filter navigation model and "
            "between-sample checks\"). Violations are judged on the truth at the control samples "
            "and, between them, at the plant's integration substeps; docked: the final state "
            "within the run's docking test.", "", markdown_corner_table(corner_rows(results))]
    if notes:
        text += [notes.strip(), ""]
    page.write_text("\n".join(text))
    return page
