"""``cikan bench`` under a non-nominal truth and robust Verify, on a tiny state set (no timing
thresholds: the figures are only checked to exist and be finite)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cikan_ros.bench import conventional_section, nominal_section
from cikan_ros.config import load_config, truth_overrides
from cikan_ros.errors import CikanError
from cikan_ros import timing
from cikan_ros.timing import collect_states, is_nominal, median_thread_time, nominal_config
from cikan_ros.tsg import Predictor

#: The conventional section's keys before the truth model: a nominal run reports exactly these,
#: and a non-nominal one reports them again as ``nominal_<key>``.
NOMINAL_KEYS = {
    "n_missions", "n_update_states", "conventional_update_ms_mean", "conventional_update_ms_p50",
    "conventional_update_ms_p99",
    "conventional_update_ms_max", "conventional_update_max_t_s", "conventional_update_max_tau_prev_s",
    "conventional_update_max_verify_calls", "conventional_verify_calls_mean", "verify_ms_mean",
    "conventional_initial_ms_mean", "conventional_initial_ms_max", "offline_mission_s_mean",
    "oracle_mission_speedup_mean", "oracle_mission_speedup_worst", "oracle_cpu_speedup",
    "oracle_update_ms_mean", "oracle_hold_rate",
}
#: Figures a non-nominal run adds: the ratio to the nominal configuration and the anchoring cost.
NEW_KEYS = {
    "conventional_update_ms_ratio_to_nominal", "conventional_update_ms_max_ratio_to_nominal",
    "conventional_re_anchor_rate", "mission_re_anchors_mean", "mission_anchor_calls_mean",
    "anchor_ms_mean", "anchor_check_ms_mean", "verify_cold_ms_mean",
    "conventional_update_anchored_ms_mean", "conventional_update_anchored_ms_max",
    "re_anchor_cost_ms_mean", "conventional_verify_calls_max", "n_missions_infeasible",
}
N_STATES = 4


def tiny(states):
    states.updates, states.priors = states.updates[:N_STATES], states.priors[:N_STATES]
    return states


@pytest.fixture(scope="module")
def realistic():
    cfg = load_config(None, **truth_overrides("realistic"), **{"tsg.robust": True})
    return cfg, tiny(collect_states(cfg, 1))


def test_median_thread_time_times_each_call_after_its_setup(monkeypatch):
    """On a fake thread clock, calls of 3, 1 and 2 ticks give the median 2; setup runs before each
    call and outside the timed span; the first call's result comes back."""
    ticks = iter([0.0, 3.0, 10.0, 11.0, 20.0, 22.0])   # (start, end) of each call
    monkeypatch.setattr(timing.time, "thread_time", lambda: next(ticks))
    events: list[str] = []

    def call(x: int) -> int:
        events.append("call")
        return x + events.count("call")

    cpu, first = median_thread_time(call, 10, repeats=3, setup=lambda: events.append("setup"))
    assert (cpu, first) == (2.0, 11)
    assert events == ["setup", "call"] * 3


def test_nominal_run_keeps_its_keys():
    cfg = load_config()
    assert is_nominal(cfg) and nominal_config(cfg) == cfg
    states = tiny(collect_states(cfg, 1))
    assert states.priors == [None] * N_STATES  # the configured chief: never re-anchored
    out = conventional_section(cfg, states, 1)
    assert set(out) == NOMINAL_KEYS
    assert nominal_section(cfg, states, 1) == {}
    # the slowest update is one of the states, and its Verify calls are the bisection's own
    worst = next(s for s in states.updates if s.t == out["conventional_update_max_t_s"]
                 and s.tau_prev == out["conventional_update_max_tau_prev_s"])
    assert out["conventional_update_max_verify_calls"] == Predictor.from_config(cfg).optimal_shift(
        worst.x_d, worst.t, worst.tau_prev)[1]


def test_ceiling_figures_golden():
    """ceiling_figures on hand-made CPU times: mission 0 has conventional updates of 4 and 2 ms and
    an oracle that paid 1 ms and held once (0); mission 1 has 3 and 3 ms against 1 and 2 ms. Per
    mission (4 + 2) / (1 + 0) = 6 and (3 + 3) / (1 + 2) = 2: mean 4, worst 2; pooled 12 / 4 = 3;
    the oracle's mean 1 ms a state; it held on 1 of 4 states."""
    from cikan_ros.bench import ceiling_figures

    out = ceiling_figures(np.array([4.0, 2.0, 3.0, 3.0]) * 1e-3, np.array([1.0, 0.0, 1.0, 2.0]) * 1e-3, [0, 0, 1, 1])
    assert out == pytest.approx({"oracle_mission_speedup_mean": 4.0, "oracle_mission_speedup_worst": 2.0,
                                 "oracle_cpu_speedup": 3.0, "oracle_update_ms_mean": 1.0, "oracle_hold_rate": 0.25})
    # a mission where the oracle held on every state costs it nothing: no ratio, not infinity
    held = ceiling_figures(np.array([1.0, 1.0]), np.zeros(2), [0, 0])
    assert math.isnan(held["oracle_mission_speedup_mean"]) and held["oracle_hold_rate"] == 1.0


def test_the_oracle_verifies_pi_star_once_and_holds_for_free():
    """oracle_time at a benchmark state: 0 where pi* is tau_prev; elsewhere the CPU of one Verify
    of pi*, which passes (its own bisection verified it); a tau that Verify refuses (0, whose
    zero test failed where pi* is not 0) is an error, not a ceiling."""
    from cikan_ros.bench import oracle_time
    from cikan_ros.governor import ConventionalGovernor

    cfg = load_config()
    states = collect_states(cfg, 1)
    gov = ConventionalGovernor.from_config(cfg)
    moved = next(i for i, s in enumerate(states.updates) if s.tau_prev != s.tau != 0.0)
    s = states.updates[moved]
    assert oracle_time(gov, states, moved, s.tau_prev, 1) == 0.0
    assert 0.0 < oracle_time(gov, states, moved, s.tau, 1)
    assert not gov.predictor.verify(s.x_d, s.t, 0.0)
    with pytest.raises(CikanError, match="failed its own Verify"):
        oracle_time(gov, states, moved, 0.0, 1)


def test_bench_sections_by_name():
    """--section picks sections by name, in the report's order; the learned section brings the
    conventional one it reads; an unknown name is refused naming the known ones."""
    from cikan_ros.bench import conventional_section, nominal_section
    from cikan_ros.commands.bench import sections
    from cikan_ros.errors import ConfigError
    from cikan_ros.learn.bench import learned_section

    assert sections(("nominal", "conventional")) == [conventional_section, nominal_section]
    assert sections(("learned",)) == [conventional_section, learned_section]
    assert len(sections()) == 4
    with pytest.raises(ConfigError, match="unknown bench section.*bogus.*known: conventional, nominal, learned, ros"):
        sections(("bogus",))


def test_realistic_robust_bench_reports_ratio_and_anchoring(realistic):
    cfg, states = realistic
    assert not is_nominal(cfg) and is_nominal(nominal_config(cfg))
    assert len(states.updates) == N_STATES
    # The states are what the governor saw under the J2 truth: the first instant anchors on the
    # configured chief (the truth starts on it), every later update had re-anchored before.
    assert states.priors[0] is None and all(p is not None for p in states.priors[1:])
    out = conventional_section(cfg, states, 1)
    out.update(nominal_section(cfg, states, 1))
    assert NEW_KEYS <= set(out)
    assert {k.removeprefix("nominal_") for k in out if k.startswith("nominal_")} == NOMINAL_KEYS
    for k in NEW_KEYS | {f"nominal_{k}" for k in NOMINAL_KEYS} | NOMINAL_KEYS:
        assert math.isfinite(out[k]), k
    assert out["truth"] == "realistic" and out["robust"] is True
    assert out["conventional_re_anchor_rate"] > 0.0  # each timed update paid its re-anchoring
    assert out["mission_re_anchors_mean"] >= 1
    assert out["nominal_n_missions"] == out["n_missions"] == 1


def test_realistic_robust_learned_section(realistic, tmp_path):
    pytest.importorskip("safetensors")
    from cikan_ros.analysis.table import bench_index
    from cikan_ros.registry import LEARNED_NAMES
    from cikan_ros.learn.bench import learned_section
    from cikan_ros.learn.modelfile import MODELS_DIR

    cfg, states = realistic
    # under robust Verify each family flies its model of robust Verify's labels (models/F-robust,
    # shipped for CIKAN and ReLU); the others, with nominal labels only, are not flown ...
    robust = [n for n in LEARNED_NAMES if (MODELS_DIR / f"{n}-robust" / "card.json").is_file()]
    assert {"cikan", "relu"} <= set(robust)
    own = learned_section(cfg, states, 1)
    assert len(own["learned_models_missing"]) == len(LEARNED_NAMES) - len(robust)
    assert all("no " in m and "model of robust Verify" in m for m in own["learned_models_missing"])
    # ... naming the place looked in relative to the project (the files go into docs/results)
    assert all("(looked in models/" in m and str(MODELS_DIR.parent) not in m for m in own["learned_models_missing"])
    assert "learned_foreign_models" not in own
    assert all(math.isfinite(own[f"{n}_mission_speedup_mean"]) for n in robust)
    # ... unless explicitly allowed: then they fly their nominal models, each named foreign
    cfg = cfg.replace(**{"learned.foreign_model": True})
    out = conventional_section(cfg, states, 1)
    out.update(learned_section(cfg, states, 1))
    assert "learned_models_missing" not in out
    assert sorted(out["learned_foreign_models"]) == sorted(set(LEARNED_NAMES) - set(robust))
    for name in LEARNED_NAMES:
        for k in ("speedup_mean", "speedup_worst", "verify_calls_mean", "nn_accept_rate",
                  "rmse_tau_s", "mission_speedup_mean", "mission_speedup_worst", "mission_cpu_speedup",
                  "flown_update_speedup", "mission_verify_calls_mean",
                  "search_rate", "mission_nn_accept_rate"):
            assert math.isfinite(out[f"{name}_{k}"]), (name, k)
        # one start here: its mission is the worst and the mean alike
        assert out[f"{name}_mission_speedup_worst"] == pytest.approx(out[f"{name}_mission_speedup_mean"])
        assert out[f"{name}_mission_cpu_speedup"] == pytest.approx(out[f"{name}_mission_speedup_mean"])
        assert 0.0 <= out[f"{name}_mission_nn_accept_rate"] <= 1.0 - out[f"{name}_search_rate"] + 1e-12
    # the scenario index's speed table: one row per model, as flown first, the Verify mode read
    # from the file
    (tmp_path / "paper-behind-robust.json").write_text(json.dumps(out))
    rows = bench_index(tmp_path).splitlines()[2:]
    assert [r.split(" | ")[3] for r in rows] == [m if m in robust else f"{m} (foreign)" for m in LEARNED_NAMES]
    cikan = rows[0].strip("| ").split(" | ")
    assert cikan[:3] == ["paper", "behind", "robust (realistic)"]
    assert cikan[4] == f"{out['cikan_mission_speedup_mean']:.2f} / {out['cikan_mission_speedup_worst']:.2f}"
    assert cikan[6] == f"{out['cikan_search_rate']:.1%}"
    assert cikan[8] == f"{out['cikan_speedup_mean']:.2f} / {out['cikan_speedup_worst']:.2f}"
    from cikan_ros.commands.bench import report_tables
    from rich.console import Console

    console = Console(record=True, width=250)
    for table in report_tables(out):
        console.print(table)
    text = console.export_text()
    assert text.index("Whole missions as flown") < text.index("Per update") < text.index("every other figure")
    assert "cikan_mission_speedup_mean" not in text and "conventional_update_ms_p99" in text
    assert "cikan_flown_update_speedup" not in text and "per update as flown" in text
    (tmp_path / "leo-ahead.json").write_text("{not json")
    with pytest.raises(CikanError, match="leo-ahead.json"):
        bench_index(tmp_path)


def test_a_bench_whose_models_were_all_refused_is_a_row_of_the_index(tmp_path):
    """A `cikan bench --json` file where every shipped model was refused (GEO under the ancillary
    tube: its robust models are of the ball tube's labels): the speed table says so in one row,
    with the conventional TSG's calls and update time, instead of leaving the world out."""
    from cikan_ros.analysis.table import bench_index

    (tmp_path / "geo-behind-robust.json").write_text(json.dumps({
        "robust": True, "truth": "realistic", "conventional_verify_calls_mean": 14.25,
        "conventional_update_ms_mean": 16.6354,
        "learned_models_missing": ["cikan: model models/geo/cikan-robust was trained on labels of ...",
                                   "relu: model models/geo/relu-robust was trained on labels of ..."]}))
    (row,) = bench_index(tmp_path).splitlines()[2:]
    assert row == ("| geo | behind | robust (realistic) | - | no model flown (refused: cikan, relu) | - (14.25) "
                   "| - | - | - | 16.635 |")


def test_a_configuration_that_refuses_every_start_is_reported_not_failed(tmp_path):
    """Robust Verify flying the paper orbit's controller weight (R = 1e7) refuses LEO's starts from
    behind in the realistic truth (docs/results/scenarios/leo-behind/controller_sweep.md: 38 of 40):
    `cikan bench --json` says so as its result (exit code 0), and the scenario index shows the row."""
    import subprocess
    import sys

    from cikan_ros.analysis.table import bench_index

    out = subprocess.run([sys.executable, "-m", "cikan_ros.cli", "bench", "--scenario", "leo", "--truth", "realistic",
                          "--robust", "--set", "control.robust_r_diag=[1.0e+7, 1.0e+7, 1.0e+7]", "--missions", "2",
                          "--json"], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    b = json.loads(out.stdout)
    assert b["refused"].startswith("Verify refuses all 2 starts") and b["n_missions_infeasible"] == 2
    assert (b["scenario"], b["approach"], b["truth"], b["robust"]) == ("leo", "behind", "realistic", True)
    (tmp_path / "leo-behind-robust.json").write_text(out.stdout)
    row = bench_index(tmp_path).splitlines()[2]
    assert row.startswith("| leo | behind | robust (realistic) | - | every start refused: Verify refuses all 2")


def test_mission_speedups_per_update_and_of_whole_missions_golden(monkeypatch) -> None:
    """mission_figures on hand-made missions (run_mission replaced): of whole missions, each
    start's CPU ratio (their mean and the worst) and the ratio of the pooled CPU; per update, the
    ratio of the pooled mean CPU per active update. Conventional: start A 4 updates of 1 ms,
    start B 2 of 3 ms; the learned governor lags on A (8 updates of 0.25 ms) and not on B (1 of
    1 ms). Missions: A 4 / 2 = 2, B 6 / 1 = 6: mean 4, worst 2; pooled 10 / 3 = 3.33; per
    update (10 / 6) / (3 / 9) = 5."""
    from types import SimpleNamespace

    import cikan_ros.mission
    from cikan_ros.governor import PATH_BISECT, PATH_NN, UpdateRecord
    from cikan_ros.learn.bench import mission_figures

    def rec(ms: float, path: str) -> UpdateRecord:
        return UpdateRecord(tau_s=-1.0, path=path, verify_calls=2, wall_s=ms / 1e3, k=1, tau_prev=-2.0,
                            cpu_s=ms / 1e3)

    flights = {("conventional", "A"): [rec(1.0, PATH_BISECT)] * 4, ("conventional", "B"): [rec(3.0, PATH_BISECT)] * 2,
               ("learned", "A"): [rec(0.25, PATH_NN)] * 8, ("learned", "B"): [rec(1.0, PATH_NN)]}

    def fake_run(gov, x0, seed):
        return SimpleNamespace(updates=flights[(gov.name, seed)])

    monkeypatch.setattr(cikan_ros.mission, "run_mission", fake_run)
    anchor = SimpleNamespace(base=None, current=None, re_anchors=0)
    conv, learned = SimpleNamespace(name="conventional", anchor=anchor), SimpleNamespace(name="learned", anchor=anchor)
    states = SimpleNamespace(seeds=["A", "B"], starts=[None, None])
    out = mission_figures(conv, [learned], states)
    assert out["learned_mission_speedup_mean"] == pytest.approx((4 / 2 + 6 / 1) / 2)
    assert out["learned_mission_speedup_worst"] == pytest.approx(4 / 2)
    assert out["learned_mission_cpu_speedup"] == pytest.approx(10 / 3)
    assert out["learned_flown_update_speedup"] == pytest.approx((10 / 6) / (3 / 9))


def test_process_cpu_of_a_running_process_is_what_it_used():
    """cikan_ros.ros.bench.process_cpu_s (from /proc/PID/stat) of this process against its own
    rusage, after 0.1 s of work: equal to the clock tick (1/SC_CLK_TCK) and the time between."""
    import os
    import resource
    import time

    from cikan_ros.ros.bench import process_cpu_s

    t = time.process_time() + 0.1
    while time.process_time() < t:
        sum(range(1000))
    r = resource.getrusage(resource.RUSAGE_SELF)
    tick = 1.0 / os.sysconf("SC_CLK_TCK")
    assert process_cpu_s(os.getpid()) == pytest.approx(r.ru_utime + r.ru_stime, abs=3 * tick)
    assert math.isnan(process_cpu_s(2 ** 22 + 7))  # no such process


def test_ros_section_reports_the_median_lockstep_and_cpu_per_node(monkeypatch):
    """The ROS section's arithmetic on the figures of its missions (the missions themselves fly in
    `cikan bench`; tests/test_ros_graph.py flies the graph): the run with the median rtf is
    reported with the spread beside it, and each node's CPU per step is its spin's less the short
    mission's over the difference in steps (golden: (1.2 - 0.2) s / (1440 - 10) steps = 0.699 ms)."""
    import types

    from cikan_ros.ros import bench as ros_bench
    from cikan_ros.ros import graph_spec

    flown = iter([9000.0, 7000.0, 8000.0])
    calls = []

    def fake(cfg, executor, follow=None, seed=None, layout=graph_spec.DEFAULT_LAYOUT):
        short = cfg.mission.duration_s == ros_bench.SHORT_STEPS * cfg.control.period_s
        calls.append((executor, short, layout))
        steps = ros_bench.SHORT_STEPS if short else 1440
        if layout == "separate":   # one process per node
            cpu = {"sim_node": 0.3, "recorder_node": 0.2} if short else {"sim_node": 2.3, "recorder_node": 1.2}
            return {"rtf": 2.0, "step_ms_p99": 2.0, "mission_success": True, "cpu_s": cpu, "steps": steps}
        rtf = 1.0 if short or executor == "single" else next(flown)
        cpu = ({"recorder+sim": 0.2, "governor+controller": 0.1} if short else
               {"recorder+sim": 1.2, "governor+controller": 0.1 + rtf / 1e4})
        return {"rtf": rtf, "step_ms_p99": rtf / 1e4, "mission_success": True, "cpu_s": cpu, "steps": steps}

    monkeypatch.setattr(ros_bench, "lockstep_figures", fake)
    out = ros_bench.ros_section(load_config(), types.SimpleNamespace(seeds=[None]), 1)
    default = graph_spec.DEFAULT_LAYOUT
    assert calls == [("events", False, default)] * 3 + [("events", True, default), ("single", False, default),
                                                        ("events", False, "separate"), ("events", True, "separate")]
    assert (out["ros_rtf"], out["ros_rtf_min"], out["ros_rtf_max"]) == (8000.0, 7000.0, 9000.0)
    assert out["ros_step_ms_p99"] == 0.8 and out["ros_lockstep_runs"] == 3 and out["ros_layout"] == default
    assert out["ros_cpu_per_step_ms_recorder+sim"] == pytest.approx(1.0 / 1430 * 1e3)
    assert out["ros_cpu_per_step_ms_governor+controller"] == pytest.approx(0.8 / 1430 * 1e3)
    assert out["ros_cpu_per_step_ms"] == pytest.approx(1.8 / 1430 * 1e3)
    assert "ros_single_cpu_per_step_ms_recorder+sim" not in out and out["ros_single_rtf"] == 1.0
    # the separate layout's fixed cost is its own short mission's: (2.3 - 0.3 + 1.2 - 0.2) s / 1430
    assert out["ros_separate_rtf"] == 2.0 and out["ros_separate_cpu_per_step_ms"] == pytest.approx(3.0 / 1430 * 1e3)
    assert out["ros_separate_cpu_per_step_ms_sim"] == pytest.approx(2.0 / 1430 * 1e3)


def test_the_ceiling_page_from_bench_files(tmp_path, capsys):
    """`cikan report DIR --ceiling`: one row per `cikan bench --section conventional --json` file,
    the Verify mode read from the file, figures as the file holds them; a refused configuration is
    a row that says so; a file made before the ceiling is refused naming it."""
    from cikan_ros.analysis.table import ceiling_index
    from cikan_ros.cli import main

    figures = {"n_missions": 4, "n_missions_infeasible": 1, "n_update_states": 812, "conventional_update_ms_mean": 1.23456,
               "conventional_verify_calls_mean": 14.04, "oracle_update_ms_mean": 0.2468, "oracle_hold_rate": 0.125,
               "oracle_mission_speedup_mean": 4.256, "oracle_mission_speedup_worst": 3.01, "oracle_cpu_speedup": 4.5,
               "truth": "realistic", "robust": True}
    (tmp_path / "leo-ahead-robust.json").write_text(json.dumps(figures))
    (tmp_path / "leo-behind-robust.json").write_text(json.dumps({"refused": "Verify refuses all 5 starts", "robust": True,
                                                                 "truth": "realistic"}))
    rows = ceiling_index(tmp_path).splitlines()[2:]
    assert rows == ["| leo | ahead | robust (realistic) | 4 (+1 refused) | 812 | 1.235 (14.0) | 0.247 | 12% | 4.26 / 3.01 | 4.50 |",
                    "| leo | behind | robust (realistic) | - | every start refused: Verify refuses all 5 starts "
                    "| - | - | - | - | - |"]
    out = tmp_path / "page"
    assert main(["report", str(tmp_path), "--ceiling", "--out", str(out)]) == 0
    page = (out / "README.md").read_text()
    assert rows[0] in page and f"cikan report {tmp_path} --ceiling --out {out}" in page
    del figures["oracle_cpu_speedup"], figures["oracle_mission_speedup_mean"]
    (tmp_path / "paper-behind.json").write_text(json.dumps(figures))
    assert main(["report", str(tmp_path), "--ceiling", "--out", str(out)]) == 2
    assert "paper-behind.json has no ceiling" in capsys.readouterr().err
