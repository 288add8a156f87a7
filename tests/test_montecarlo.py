"""Monte Carlo campaigns: same starts for every executor, stored results reused, summary figures."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from cikan_ros.montecarlo import load_run_arrays, run_campaign, run_paths, summarise
from cikan_ros.parallel import ordered_map


def _square(x: int) -> int:
    return x * x


def test_ordered_map_keeps_order_and_stops_early():
    assert list(ordered_map(_square, range(7), workers=2)) == [x * x for x in range(7)]
    gen = ordered_map(_square, iter(range(10**9)), workers=2, in_flight=3)  # unbounded task stream
    assert [next(gen) for _ in range(5)] == [0, 1, 4, 9, 16]
    gen.close()


def test_campaign_results_files_and_reuse(cfg, tmp_path):
    res = run_campaign(cfg, ["conventional"], runs=2, seed=11, out_dir=tmp_path, progress=False)
    runs = res["conventional"]
    assert [r["seed"] for r in runs] == [11, 12] and all(r["success"] for r in runs)
    json_path, npz_path = run_paths(tmp_path, "conventional", 11)
    stored = json.loads(json_path.read_text())
    assert stored["metrics"] == runs[0] and stored["config"] == cfg.flat()
    arrays = load_run_arrays(npz_path)
    assert arrays["x_d"].shape == (1441, 6) and arrays["update_path"].dtype.kind == "U"
    dv = cfg.control.period_s * np.linalg.norm(arrays["u"], axis=1).sum()
    assert dv == pytest.approx(runs[0]["delta_v_kmps"], rel=1e-12)
    # A second campaign reuses the stored runs (same numbers, files untouched).
    mtime = json_path.stat().st_mtime_ns
    again = run_campaign(cfg, ["conventional"], runs=2, seed=11, out_dir=tmp_path, progress=False)
    assert again == res and json_path.stat().st_mtime_ns == mtime
    # A changed configuration flies the runs again.
    other = cfg.replace(**{"tsg.update_period_s": 120.0})
    changed = run_campaign(other, ["conventional"], runs=1, seed=11, out_dir=tmp_path, progress=False)
    assert changed["conventional"][0]["updates"] == 14400 // 120 - 1


def test_dask_cluster_gives_the_same_runs(cfg, tmp_path):
    """A real distributed.LocalCluster on loopback, its worker a separate process, flies the same
    runs as the local executor: every run, in seed order, with the same metrics."""
    from distributed import Client, LocalCluster

    local = run_campaign(cfg, ["conventional"], runs=2, seed=21, out_dir=tmp_path / "a", progress=False)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, protocol="tcp", host="127.0.0.1",
                      dashboard_address=None) as cluster:
        with Client(cluster) as client:
            pids = client.run(os.getpid)
        assert len(pids) == 1 and os.getpid() not in pids.values()
        remote = run_campaign(cfg, ["conventional"], runs=2, seed=21, out_dir=tmp_path / "b",
                              dask_address=cluster.scheduler_address, progress=False)
    a_runs, b_runs = local["conventional"], remote["conventional"]
    assert [r["seed"] for r in a_runs] == [r["seed"] for r in b_runs] == [21, 22]
    for a, b in zip(a_runs, b_runs, strict=True):
        timing = {k for k in a if k.endswith("_ms") or "_ms_" in k}
        assert {k: v for k, v in a.items() if k not in timing} == {k: v for k, v in b.items() if k not in timing}


def test_summary_figures():
    runs = [
        {"success": True, "violations": 0, "delta_v_kmps": 1.0, "min_h1_margin": 1e-3, "max_h3": -1e-3,
         "tau0_s": -7.0, "t_tau_zero_s": 1800.0, "final_distance_m": 1e-8, "updates": 10, "update_ms_mean": 1.0,
         "update_ms_max": 5.0, "active_updates": 2, "active_update_ms_mean": 4.0, "active_update_ms_max": 5.0,
         "initial_ms": 10.0},
        {"success": False, "violations": 3, "delta_v_kmps": 3.0, "min_h1_margin": -1e-4, "max_h3": None,
         "tau0_s": -9.0, "t_tau_zero_s": None, "final_distance_m": 2.0, "updates": 30, "update_ms_mean": 2.0,
         "update_ms_max": 9.0, "active_updates": 6, "active_update_ms_mean": 8.0, "active_update_ms_max": 9.0,
         "initial_ms": 20.0},
    ]
    s = summarise(runs)
    assert s["successes"] == 1 and s["violations"] == 3
    assert s["delta_v_kmps_mean"] == 2.0 and s["min_h1_margin"] == -1e-4 and s["max_h3"] == -1e-3
    assert s["update_ms_mean"] == pytest.approx((10 * 1.0 + 30 * 2.0) / 40)  # over all updates
    assert s["active_update_ms_mean"] == pytest.approx((2 * 4.0 + 6 * 8.0) / 8)
    assert s["t_tau_zero_s_max"] == 1800.0


def test_governor_labels_are_distinct_directories():
    """A model path's stem names its runs' directory; a stem that is a governor's name takes its
    parent's in front, so another scenario's model flown beside the shipped one keeps its own."""
    from cikan_ros.montecarlo import governor_label

    assert governor_label("cikan") == "cikan"
    assert governor_label("cikan@paper") == "cikan@paper"
    assert governor_label("runs/bad/random-cikan") == "random-cikan"
    assert governor_label("models/leo/cikan") == "leo-cikan"
    assert governor_label("models/leo/cikan-ahead") == "cikan-ahead"
    assert governor_label("m/relu.safetensors") == "m-relu"
    assert governor_label("relu.safetensors") == "relu"
