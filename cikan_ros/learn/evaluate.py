"""Closed-loop evaluation of a governor (SPEC §9): Monte Carlo missions with the governor in the
loop; RMSE of its shifts against π* solved at the states it visited (same τ_{k-1}), success,
violations, ΔV, update times and the network's acceptance rate.

``python -m cikan_ros.learn.evaluate cikan relu --runs 5`` prints one JSON line per governor.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..config import Config, load_config
from ..governor import Governor, make_governor
from ..mission import errors_against_optimal, nominal_start, rmse, run_mission, sample_start
from ..tsg import Predictor
from .governor import nn_accept_rate


def closed_loop(governor: Governor, seeds: list[int | None]) -> dict[str, Any]:
    """Missions from the nominal start (seed None) or Monte Carlo seeds; aggregated metrics."""
    pred = governor.predictor
    errors: list[NDArray] = []
    runs = []
    records = []
    start = time.perf_counter()
    for seed in seeds:
        x0 = nominal_start(pred) if seed is None else sample_start(pred, seed)
        res = run_mission(governor, x0)
        runs.append(res.metrics())
        records += res.updates
        errors.append(errors_against_optimal(pred, res.update_states()))
    active = [r.wall_s for r in records if r.active]
    return {
        "governor": governor.name,
        "runs": len(runs),
        "success": sum(r["success"] for r in runs),
        "violations": sum(r["violations"] for r in runs),
        "rmse_tau_s": rmse(np.concatenate(errors)),
        "delta_v_kmps_mean": float(np.mean([r["delta_v_kmps"] for r in runs])),
        "t_tau_zero_s_mean": float(np.nanmean([np.nan if r["t_tau_zero_s"] is None
                                               else r["t_tau_zero_s"] for r in runs])),
        "update_ms_mean": float(np.mean([r.wall_s for r in records]) * 1e3),
        "update_ms_max": float(np.max([r.wall_s for r in records]) * 1e3),
        "active_update_ms_mean": float(np.mean(active) * 1e3) if active else 0.0,
        "active_updates": len(active),
        "verify_calls_mean_active": float(np.mean([r.verify_calls for r in records
                                                   if r.active])) if active else 0.0,
        "nn_accept_rate": None if governor.name == "conventional" else nn_accept_rate(records),
        "wall_s": time.perf_counter() - start,
    }


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("governors", nargs="+", help="conventional, cikan, grbf, rswaf, relu, gelu or a path")
    p.add_argument("--runs", type=int, default=5, help="nominal start + Monte Carlo seeds 1..runs-1")
    args = p.parse_args(argv)
    cfg: Config = load_config()
    pred = Predictor.from_config(cfg)
    seeds: list[int | None] = [None] + list(range(1, args.runs))
    for name in args.governors:
        print(json.dumps(closed_loop(make_governor(name, cfg, pred), seeds)), flush=True)


if __name__ == "__main__":
    main()
