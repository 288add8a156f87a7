"""Closed-loop comparison of governors and configuration variants against the conventional TSG
on the same Monte Carlo starts (how the keep rule's settings were chosen, docs/learned_update_rule.md).

Each (variant, governor, seed) flies one mission from ``mission.sample_start(seed)``; the
conventional TSG flies the same seeds under each variant's configuration. Per governor and
variant: ΔV and time to τ = 0 as ratios of their sums over the runs to the conventional's
(paired: same starts), success and violations, Verify calls per active update, the active
speed-up (conventional CPU time per active update / the governor's, both summed over the runs;
CPU time of the deciding thread) and the mission speed-up (the conventional missions' CPU of
their active updates / the governor's: whole missions, which count a governor that lags π* and
flies more updates for it). Missions are chaotic (SPEC §10): compare over many seeds, and
choose settings on seeds other than the ones a table reports (Table 2 flies seeds 1-100).

The same figures by the size of the shift the update started from (|τ_prev| in the bands of
:data:`SHIFT_BANDS`, ``cikan compare --by-shift``): where a mission's active updates and their CPU
time are, per band the share of updates the governor answered by searching and with its
network's proposal, and the band's speed-up. The mission's speed-up is the CPU-weighted mix of
the bands', so this says which phase of the approach a governor has to be fast in.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any, Iterable

from .config import Config
from .errors import CikanError, NoFeasibleShiftError
from .governor import PATH_NN, SEARCHING_PATHS, UpdateRecord
from .mission import run_mission, sample_start
from .montecarlo import process_governor
from .paired import paired_ratio
from .parallel import ordered_map

#: Bands of |τ_prev| (s), (low, high]: the approach's first phase, its middle, its last part.
SHIFT_BANDS: tuple[tuple[float, float], ...] = ((1.0, math.inf), (0.1, 1.0), (0.0, 0.1))
#: What :func:`shift_bands` counts in each band.
SHIFT_BAND_KEYS = ("updates", "cpu_s", "verify_calls", "searched", "nn")


def shift_bands(active: Iterable[UpdateRecord]) -> list[dict[str, float]]:
    """Per band of :data:`SHIFT_BANDS` (|τ_prev| in (low, high]): the active updates, their CPU
    time (s), Verify calls, and how many searched (:data:`cikan_ros.governor.SEARCHING_PATHS`)
    or answered with the network's proposal ("nn")."""
    out = [{k: 0.0 if k == "cpu_s" else 0 for k in SHIFT_BAND_KEYS} for _ in SHIFT_BANDS]
    for r in active:
        m = abs(r.tau_prev)
        band = next(b for (lo, hi), b in zip(SHIFT_BANDS, out) if lo < m <= hi)
        band["updates"] += 1
        band["cpu_s"] += r.cpu_s
        band["verify_calls"] += r.verify_calls
        band["searched"] += r.path in SEARCHING_PATHS
        band["nn"] += r.path == PATH_NN
    return out


@dataclass(frozen=True)
class Flight:
    """One mission of a comparison: configuration (flat JSON), governor name, Monte Carlo seed."""

    config_json: str
    governor: str
    seed: int


def fly(task: Flight) -> dict[str, Any]:
    """Fly one mission (governors cached and warmed up per process); its paired figures, or
    ``{"refused": why}`` when Verify finds no feasible shift at its start (robust Verify)."""
    gov = process_governor(task.config_json, task.governor)
    try:
        res = run_mission(gov, sample_start(gov.predictor, task.seed), task.seed)
    except NoFeasibleShiftError as exc:
        return {"refused": str(exc)}
    m = res.metrics()
    active = [r for r in res.updates if r.active]
    return {"delta_v_kmps": m["delta_v_kmps"], "t_tau_zero_s": m["t_tau_zero_s"],
            "success": bool(m["success"]), "violations": int(m["violations"]),
            "active_cpu_s": sum(r.cpu_s for r in active), "active_updates": len(active),
            "active_verify_calls": sum(r.verify_calls for r in active), "by_shift": shift_bands(active)}


def _conventional_key(cfg: Config) -> str:
    """The configuration the conventional TSG flies (the learned.* settings do not change it)."""
    return json.dumps({k: v for k, v in cfg.flat().items() if not k.startswith("learned.")},
                      sort_keys=True)


def compare(variants: dict[str, Config], governors: list[str], seeds: list[int], workers: int = 1,
            dask_address: str | None = None) -> list[dict[str, Any]]:
    """One row per (variant, governor): figures relative to the conventional TSG on ``seeds``."""
    if not seeds:
        raise CikanError("no seeds to fly")
    cfg_json = {label: json.dumps(c.flat(), sort_keys=True) for label, c in variants.items()}
    # The conventional flies once per distinct non-learned configuration, under its first variant's.
    conv_json: dict[str, str] = {}
    for label, c in variants.items():
        conv_json.setdefault(_conventional_key(c), cfg_json[label])
    tasks = [Flight(j, "conventional", s) for j in conv_json.values() for s in seeds]
    tasks += [Flight(cfg_json[label], g, s) for label in variants for g in governors for s in seeds]
    runs = dict(zip(tasks, ordered_map(fly, tasks, workers, dask_address)))
    rows = []
    for label, c in variants.items():
        conv = [runs[Flight(conv_json[_conventional_key(c)], "conventional", s)] for s in seeds]
        for g in governors:
            mine = [runs[Flight(cfg_json[label], g, s)] for s in seeds]
            # Starts Verify refused (robust Verify; the initial search is the same for every
            # governor) are counted, not flown: the figures pair the starts both flew.
            both = [(a, b) for a, b in zip(mine, conv) if "refused" not in a and "refused" not in b]
            flown, paired = [a for a, _ in both], [b for _, b in both]
            rows.append({"variant": label, "governor": g, "runs": len(both), "refused": len(seeds) - len(both),
                         **relative_figures(flown, paired), "by_shift": band_figures(flown, paired)})
    if all(r["runs"] == 0 for r in rows):
        raise NoFeasibleShiftError(f"Verify refused all {len(seeds)} starts: nothing to compare")
    return rows


def _total(runs: Iterable[dict[str, Any]], key: str) -> float:
    return float(sum(r[key] for r in runs))


def relative_figures(mine: list[dict[str, Any]], conv: list[dict[str, Any]]) -> dict[str, Any]:
    """Paired figures of a governor's runs against the conventional TSG's on the same starts."""
    both_zero = [(a, b) for a, b in zip(mine, conv)
                 if a["t_tau_zero_s"] is not None and b["t_tau_zero_s"] is not None]
    n_mine, n_conv = _total(mine, "active_updates"), _total(conv, "active_updates")
    cpu_mine, cpu_conv = _total(mine, "active_cpu_s"), _total(conv, "active_cpu_s")
    if not mine:
        return {"success": 0, "violations": 0, "delta_v_ratio": None, "delta_v_ratio_se": None,
                "t_tau_zero_ratio": None, "verify_calls_mean": None, "active_speedup": None,
                "mission_speedup": None}
    dv = paired_ratio([a["delta_v_kmps"] for a in mine], [b["delta_v_kmps"] for b in conv])
    return {
        "success": sum(r["success"] for r in mine),
        "violations": sum(r["violations"] for r in mine),
        "delta_v_ratio": dv.ratio,
        "delta_v_ratio_se": dv.se,
        "t_tau_zero_ratio": (sum(a["t_tau_zero_s"] for a, _ in both_zero)
                             / sum(b["t_tau_zero_s"] for _, b in both_zero)) if both_zero else None,
        "verify_calls_mean": _total(mine, "active_verify_calls") / n_mine if n_mine else None,
        "active_speedup": (cpu_conv / n_conv) / (cpu_mine / n_mine) if n_mine and n_conv else None,
        # Whole missions: the CPU of all their active updates. Not the same as per update when
        # the governors fly different numbers of updates: one that lags π* flies more of the
        # cheap updates near τ = 0, which lowers its mean and flatters a per-update ratio.
        "mission_speedup": cpu_conv / cpu_mine if cpu_mine > 0 else None,
    }


def band_figures(mine: list[dict[str, Any]], conv: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per band of :data:`SHIFT_BANDS`, over paired runs: the governor's and the conventional
    TSG's active updates, their shares of all active updates and of the active CPU time, CPU
    per update (ms), the governor's shares searching and answered by its network, and the band's
    speed-up (the conventional's CPU per update over the governor's)."""
    def summed(runs: list[dict[str, Any]]) -> list[dict[str, float]]:
        return [{k: sum(r["by_shift"][i][k] for r in runs) for k in SHIFT_BAND_KEYS} for i in range(len(SHIFT_BANDS))]

    def share(x: float, total: float) -> float | None:
        return x / total if total else None

    m, c = summed(mine), summed(conv)
    m_upd, c_upd = sum(b["updates"] for b in m), sum(b["updates"] for b in c)
    m_cpu, c_cpu = sum(b["cpu_s"] for b in m), sum(b["cpu_s"] for b in c)
    out = []
    for (lo, hi), a, b in zip(SHIFT_BANDS, m, c):
        a_ms = 1e3 * a["cpu_s"] / a["updates"] if a["updates"] else None
        b_ms = 1e3 * b["cpu_s"] / b["updates"] if b["updates"] else None
        out.append({"low_s": lo, "high_s": hi, "updates": a["updates"], "conventional_updates": b["updates"],
                    "update_share": share(a["updates"], m_upd), "conventional_update_share": share(b["updates"], c_upd),
                    "cpu_share": share(a["cpu_s"], m_cpu), "conventional_cpu_share": share(b["cpu_s"], c_cpu),
                    "ms_per_update": a_ms, "conventional_ms_per_update": b_ms,
                    "search_share": share(a["searched"], a["updates"]), "nn_share": share(a["nn"], a["updates"]),
                    "speedup": b_ms / a_ms if a_ms and b_ms else None})
    return out


def markdown_by_shift(rows: list[dict[str, Any]]) -> str:
    """The bands of each row of :func:`compare` (``by_shift``) as a Markdown table."""
    def num(x: float | None, fmt: str) -> str:
        return "-" if x is None else format(x, fmt)

    out = [r"| variant | governor | \|τ_prev\| (s) |"
           " updates (conv.) | share of updates (conv.) | "
           "share of CPU (conv.) | ms / update (conv.) | searching | network accepted | speed-up |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for b in r["by_shift"]:
            band = f"> {b['low_s']:g}" if math.isinf(b["high_s"]) else f"{b['low_s']:g} - {b['high_s']:g}"
            out.append(f"| {r['variant']} | {r['governor']} | {band} | {b['updates']} ({b['conventional_updates']}) | "
                       f"{num(b['update_share'], '.2f')} ({num(b['conventional_update_share'], '.2f')}) | "
                       f"{num(b['cpu_share'], '.2f')} ({num(b['conventional_cpu_share'], '.2f')}) | "
                       f"{num(b['ms_per_update'], '.3f')} ({num(b['conventional_ms_per_update'], '.3f')}) | "
                       f"{num(b['search_share'], '.2f')} | {num(b['nn_share'], '.2f')} | {num(b['speedup'], '.2f')} |")
    return "\n".join(out)


def markdown(rows: list[dict[str, Any]]) -> str:
    """The rows of :func:`compare` as a Markdown table."""
    def pct(r: float | None) -> str:
        return "-" if r is None else f"{100 * (r - 1):+.1f} %"

    def pct_se(r: float | None, e: float | None) -> str:
        return pct(r) if e is None else f"{100 * (r - 1):+.1f} ± {100 * e:.1f} %"

    out = ["| variant | governor | runs | ΔV vs conventional (± SE) | t(τ=0) vs conventional | success | "
           "violations | Verify calls / active update | active speed-up (CPU) | mission speed-up (CPU) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        calls = "-" if r["verify_calls_mean"] is None else f"{r['verify_calls_mean']:.2f}"
        speed = "-" if r["active_speedup"] is None else f"{r['active_speedup']:.2f}"
        mission = "-" if r.get("mission_speedup") is None else f"{r['mission_speedup']:.2f}"
        runs = f"{r['runs']} ({r['refused']} refused)" if r.get("refused") else f"{r['runs']}"
        out.append(f"| {r['variant']} | {r['governor']} | {runs} | "
                   f"{pct_se(r['delta_v_ratio'], r['delta_v_ratio_se'])} | "
                   f"{pct(r['t_tau_zero_ratio'])} | {r['success']}/{r['runs']} | {r['violations']} | "
                   f"{calls} | {speed} | {mission} |")
    return "\n".join(out)
