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
        {"success": True, "violations": 0, "violations_between": 2, "delta_v_kmps": 1.0, "min_h1_margin": 1e-3, "max_h3": -1e-3,
         "tau0_s": -7.0, "t_tau_zero_s": 1800.0, "final_distance_m": 1e-8, "updates": 10, "update_ms_mean": 1.0,
         "update_ms_max": 5.0, "active_updates": 2, "active_update_ms_mean": 4.0, "active_update_ms_max": 5.0,
         "initial_ms": 10.0},
        {"success": False, "violations": 3, "violations_between": 5, "delta_v_kmps": 3.0, "min_h1_margin": -1e-4, "max_h3": None,
         "tau0_s": -9.0, "t_tau_zero_s": None, "final_distance_m": 2.0, "updates": 30, "update_ms_mean": 2.0,
         "update_ms_max": 9.0, "active_updates": 6, "active_update_ms_mean": 8.0, "active_update_ms_max": 9.0,
         "initial_ms": 20.0},
    ]
    s = summarise(runs)
    assert s["successes"] == 1 and s["violations"] == 3 and s["violations_between"] == 7
    # a run stored before the truth was judged between samples: the total is unknown
    assert summarise([runs[0], {**runs[1], "violations_between": None}])["violations_between"] is None
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


def test_corner_campaign_flies_every_corner_on_the_same_starts(tmp_path):
    """`cikan montecarlo --corners` as a user runs it: one run per corner of the bounds (pointing
    and disturbance bounds 0 leave bias x navigation signs: 4), labelled, and `cikan report
    --corners` tabulates them per corner."""
    import subprocess
    import sys

    cikan = [sys.executable, "-m", "cikan_ros.cli"]
    truth = ["--truth", "realistic", "--set", "truth.thrust_pointing_max_deg=0", "--set",
             "truth.disturbance_max_kmps2=0", "--set", "mission.duration_s=300"]
    out = subprocess.run([*cikan, "montecarlo", "--corners", "--runs", "1", "--seed", "3", *truth,
                          "--out", str(tmp_path / "mc"), "--json"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    names = {"b+.along+.d+.n+", "b+.along+.d+.n-", "b-.along+.d+.n+", "b-.along+.d+.n-"}
    assert {p.name for p in (tmp_path / "mc").iterdir() if p.is_dir()} == names
    runs = {n: json.loads((tmp_path / "mc" / n / "conventional" / "seed_00003.json").read_text())
            for n in names}
    assert all(r["metrics"]["corner"] == n and r["config"]["truth.corner"] == n for n, r in runs.items())
    # the same start, four different truths
    assert len({r["metrics"]["final_distance_m"] for r in runs.values()}) == 4
    summary = json.loads(out.stdout)["conventional"]
    assert summary["runs"] == 4 and set(summary["corners"]) == names | {"all corners"}
    rep = subprocess.run([*cikan, "report", str(tmp_path / "mc"), "--corners", "--out", str(tmp_path / "doc")],
                         capture_output=True, text=True, timeout=120)
    assert rep.returncode == 0, rep.stderr
    page = (tmp_path / "doc" / "corners.md").read_text()
    assert all(f"| conventional | `{n}` | 1 | 0 |" in page for n in names)
    bad = subprocess.run([*cikan, "montecarlo", "--corners", "--runs", "1", *truth, "--set", "truth.draw=corner",
                          "--set", "truth.corner=b+.normal+.d+.n+", "--out", str(tmp_path / "bad")],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "leave truth.draw random" in bad.stderr


def test_a_refused_run_replaces_the_arrays_of_an_older_run(tmp_path):
    """A start flown once (JSON and arrays) and refused when the campaign is flown again under
    another configuration: the refusal is recorded and the old arrays go, so no table reads the
    old run's arrays as this run's (a scenario table once failed on such a pair)."""
    from cikan_ros.montecarlo import RunTask, save_refused

    task = RunTask(json.dumps({"tsg.robust": True}), "conventional", 13, str(tmp_path))
    json_path, npz_path = run_paths(str(tmp_path), "conventional", 13)
    npz_path.parent.mkdir(parents=True)
    np.savez(npz_path, t=np.zeros(3))
    json_path.write_text(json.dumps({"metrics": {"seed": 13, "delta_v_kmps": 0.5}, "config": {}}))
    metrics = save_refused(task, "no feasible time shift", json_path, npz_path)
    assert metrics["refused"] == "no feasible time shift" and not npz_path.exists()
    assert json.loads(json_path.read_text())["metrics"]["refused"] == "no feasible time shift"


def test_the_corner_table_counts_the_runs_inside_the_certified_ball():
    """The corner table's certified column: runs that ended inside the ball robust Verify
    certified, of those that have one, and the largest ball (m, mm/s); "-" when none has one."""
    from cikan_ros.analysis.corners import corner_rows, markdown_corner_table

    base = {"violations": 0, "violations_between": 0, "success": True, "final_distance_m": 0.01,
            "final_speed_mps": 1e-4, "dock_distance_m": 0.1, "dock_speed_mps": 0.01, "delta_v_kmps": 0.4,
            "corner": "b+.along+.d+.n+"}
    runs = [{**base, "dock_certified_m": 0.044, "dock_certified_mps": 0.00135, "docked_certified": True},
            {**base, "dock_certified_m": 0.05, "dock_certified_mps": 0.0012, "docked_certified": False},
            base]
    row = corner_rows({"conventional": runs})[0]
    assert (row["certified"], row["docked_certified"]) == (2, 1)
    assert row["certified_ball_max"] == (0.05, 0.00135)
    assert "| 1 (2), 0.050, 1.35 |" in markdown_corner_table([row])
    assert "| 1 | 1 | - |" in markdown_corner_table(corner_rows({"conventional": [base]})[:1])
