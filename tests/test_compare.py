"""`cikan compare`: paired closed-loop figures against the conventional TSG (contracts and golden)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cikan_ros.cli import main
from cikan_ros.compare import SHIFT_BANDS, band_figures, compare, relative_figures, shift_bands
from cikan_ros.governor import UpdateRecord
from cikan_ros.config import load_config
from cikan_ros.registry import make_governor
from cikan_ros.mission import run_mission, sample_start


def _run(dv: float, t0: float | None, cpu: float, n: int, calls: int, ok: bool = True) -> dict:
    return {"delta_v_kmps": dv, "t_tau_zero_s": t0, "success": ok, "violations": 0,
            "active_cpu_s": cpu, "active_updates": n, "active_verify_calls": calls}


def test_relative_figures_are_ratios_of_sums_on_paired_starts() -> None:
    """ΔV ratio = Σ mine / Σ conv; t(τ=0) only over runs where both reached 0; active speed-up =
    conv CPU per active update / mine, mission speed-up = conv CPU of the missions' active updates /
    mine; calls per active update."""
    conv = [_run(1.0, 1000.0, 0.10, 100, 1800), _run(3.0, None, 0.30, 200, 3600)]
    mine = [_run(1.5, 1100.0, 0.01, 50, 100), _run(2.5, 2000.0, 0.02, 150, 350, ok=False)]
    f = relative_figures(mine, conv)
    assert f["delta_v_ratio"] == pytest.approx(4.0 / 4.0)
    # R = 1, e = (0.5, -0.5): SE = sqrt(2 · 0.5) / 4
    assert f["delta_v_ratio_se"] == pytest.approx(0.25)
    assert f["t_tau_zero_ratio"] == pytest.approx(1100.0 / 1000.0)
    assert f["verify_calls_mean"] == pytest.approx(450 / 200)
    assert f["active_speedup"] == pytest.approx((0.40 / 300) / (0.03 / 200))
    assert f["mission_speedup"] == pytest.approx(0.40 / 0.03)   # whole missions: CPU over CPU
    assert (f["success"], f["violations"]) == (1, 0)


def test_updates_fall_in_the_band_of_the_shift_they_started_from() -> None:
    """shift_bands: |τ_prev| in (1, inf), (0.1, 1], (0, 0.1] s, edges in the lower band; either
    side of the chief; CPU, calls, searching ("search", "stall") and network ("nn") counted."""
    assert SHIFT_BANDS == ((1.0, math.inf), (0.1, 1.0), (0.0, 0.1))
    recs = [UpdateRecord(-4.0, "search", 20, 0.0, 1, -5.0, 2e-3),
            UpdateRecord(-0.9, "nn", 2, 0.0, 2, -1.0, 1e-4),       # 1.0: the middle band
            UpdateRecord(0.4, "stall", 15, 0.0, 3, 0.5, 5e-4),      # ahead of the chief
            UpdateRecord(-0.09, "keep", 0, 0.0, 4, -0.1, 1e-5),     # 0.1: the last band
            UpdateRecord(-0.01, "audit", 3, 0.0, 5, -0.02, 3e-5)]
    b = shift_bands(recs)
    assert [x["updates"] for x in b] == [1, 2, 2]
    assert [x["verify_calls"] for x in b] == [20, 17, 3]
    assert [x["searched"] for x in b] == [1, 1, 0] and [x["nn"] for x in b] == [0, 1, 0]
    assert [x["cpu_s"] for x in b] == pytest.approx([2e-3, 6e-4, 4e-5])


def test_band_figures_are_shares_and_ratios_of_sums() -> None:
    """band_figures over two paired runs: shares of the updates and of the CPU time among the
    bands, ms per update, the searching and network shares, speed-up = conventional ms / mine."""
    def run(bands):
        return {"by_shift": [dict(zip(("updates", "cpu_s", "verify_calls", "searched", "nn"), x)) for x in bands]}

    mine = [run([(2, 2e-3, 10, 1, 0), (1, 1e-4, 1, 0, 1), (5, 5e-5, 5, 5, 0)]),
            run([(2, 2e-3, 10, 2, 0), (0, 0.0, 0, 0, 0), (3, 3e-5, 3, 3, 0)])]
    conv = [run([(3, 6e-3, 60, 0, 0), (1, 3e-4, 15, 0, 0), (4, 4e-5, 20, 0, 0)]),
            run([(1, 2e-3, 20, 0, 0), (1, 3e-4, 15, 0, 0), (4, 4e-5, 20, 0, 0)])]
    f = band_figures(mine, conv)
    assert [b["updates"] for b in f] == [4, 1, 8] and [b["conventional_updates"] for b in f] == [4, 2, 8]
    assert [b["update_share"] for b in f] == pytest.approx([4 / 13, 1 / 13, 8 / 13])
    assert [b["cpu_share"] for b in f] == pytest.approx([4e-3 / 4.18e-3, 1e-4 / 4.18e-3, 8e-5 / 4.18e-3])
    assert [b["ms_per_update"] for b in f] == pytest.approx([1.0, 0.1, 0.01])
    assert [b["conventional_ms_per_update"] for b in f] == pytest.approx([2.0, 0.3, 0.01])
    assert [b["speedup"] for b in f] == pytest.approx([2.0, 3.0, 1.0])
    assert [b["search_share"] for b in f] == pytest.approx([3 / 4, 0.0, 1.0])
    assert [b["nn_share"] for b in f] == pytest.approx([0.0, 1.0, 0.0])


def test_a_learned_governor_against_the_conventional_on_the_same_starts() -> None:
    """`compare` for the shipped CIKAN under two rules against the conventional TSG (flown once:
    the learned.* settings do not change it) equals the figures written out here from missions
    flown directly, each governor fresh, on the same Monte Carlo starts: sums of ΔV and of t(τ=0),
    successes, violations, Verify calls per active update, which are fewer than the conventional
    TSG's. 90-min missions (the conventional's τ reaches 0 in them)."""
    cfg = load_config(**{"mission.duration_s": 5400.0})
    variants = {"keep": cfg, "paper": cfg.replace(**{"learned.algorithm": "paper"})}
    seeds = [3, 4]
    rows = compare(variants, ["cikan"], seeds)
    assert [(r["variant"], r["governor"], r["runs"]) for r in rows] == [("keep", "cikan", 2),
                                                                         ("paper", "cikan", 2)]

    def flown(name: str, c) -> list:
        gov = make_governor(name, c)
        return [run_mission(gov if name == "conventional" else make_governor(name, c),
                            sample_start(gov.predictor, s), s) for s in seeds]

    conv_runs = flown("conventional", cfg)
    conv = [r.metrics() for r in conv_runs]
    assert all(m["t_tau_zero_s"] is not None for m in conv)
    conv_active = [u for r in conv_runs for u in r.updates if u.active]
    conv_calls = sum(u.verify_calls for u in conv_active) / len(conv_active)
    for row, c in zip(rows, variants.values()):
        runs = flown("cikan", c)
        mine = [r.metrics() for r in runs]
        active = [u for r in runs for u in r.updates if u.active]
        a = np.array([m["delta_v_kmps"] for m in mine])
        b = np.array([m["delta_v_kmps"] for m in conv])
        ratio = a.sum() / b.sum()
        assert row["delta_v_ratio"] == pytest.approx(ratio, rel=1e-12)
        se = math.sqrt(2 / 1 * np.sum((a - ratio * b) ** 2)) / b.sum()    # n / (n - 1) = 2
        assert row["delta_v_ratio_se"] == pytest.approx(se, rel=1e-9)
        both = [(x["t_tau_zero_s"], y["t_tau_zero_s"]) for x, y in zip(mine, conv)
                if x["t_tau_zero_s"] is not None]
        t_ratio = sum(x for x, _ in both) / sum(y for _, y in both)
        assert row["t_tau_zero_ratio"] == pytest.approx(t_ratio, rel=1e-12)
        assert row["success"] == sum(m["success"] for m in mine) and row["violations"] == 0
        calls = sum(u.verify_calls for u in active) / len(active)
        assert row["verify_calls_mean"] == pytest.approx(calls, rel=1e-12)
        # by the shift they started from: every active update in one band, of the governor and
        # of the conventional TSG; the CPU shares of all bands sum to 1
        assert sum(b["updates"] for b in row["by_shift"]) == len(active)
        assert sum(b["conventional_updates"] for b in row["by_shift"]) == len(conv_active)
        assert sum(b["cpu_share"] for b in row["by_shift"]) == pytest.approx(1.0)
        assert sum(b["conventional_cpu_share"] for b in row["by_shift"]) == pytest.approx(1.0)
        # what a learned governor is for: fewer predictions per decision than the bisection's
        # ~log2(|tau_prev| / 1e-5 s) (measured 8.1 keep, 10.5 paper against 18.6)
        assert row["verify_calls_mean"] < conv_calls
        assert row["active_speedup"] > 0.0


def test_starts_verify_refuses_are_counted_not_flown() -> None:
    """Robust Verify in LEO's realistic truth (the ancillary tube, missions of 3000 s) refuses Monte
    Carlo start 13 and accepts start 2 (measured): the row pairs the start both flew, counts the
    refused one, and says so; every start refused is an error naming it."""
    from cikan_ros.compare import markdown
    from cikan_ros.config import scenario_overrides, truth_overrides
    from cikan_ros.errors import NoFeasibleShiftError

    cfg = load_config(**{**scenario_overrides("leo"), **truth_overrides("realistic"),
                         "tsg.robust": True, "mission.duration_s": 3000.0})
    rows = compare({"default": cfg}, ["cikan"], [2, 13])
    assert [(r["runs"], r["refused"]) for r in rows] == [(1, 1)]
    conv = run_mission(make_governor("conventional", cfg), sample_start(make_governor("conventional", cfg).predictor, 2), 2)
    mine = run_mission(make_governor("cikan", cfg), sample_start(make_governor("cikan", cfg).predictor, 2), 2)
    assert rows[0]["delta_v_ratio"] == pytest.approx(mine.metrics()["delta_v_kmps"] / conv.metrics()["delta_v_kmps"],
                                                     rel=1e-12)
    assert "| default | cikan | 1 (1 refused) |" in markdown(rows)
    with pytest.raises(NoFeasibleShiftError, match="refused all 1 starts"):
        compare({"default": cfg}, ["cikan"], [13])


def test_variants_keep_the_commands_scenario_truth_and_verify() -> None:
    """A --variant is the command's configuration (here LEO from ahead, robust Verify in the
    realistic truth) with its own overrides added: only the variant's keys differ."""
    from cikan_ros.cli import build_parser
    from cikan_ros.commands.compare import variant_configs

    args = build_parser().parse_args(["compare", "--scenario", "leo", "--set", "mission.approach=ahead",
                                      "--truth", "realistic", "--robust",
                                      "--variant", "learned.ladder=[0.1, 0.0];learned.audit_step=0.2"])
    variants = variant_configs(args)
    base, var = variants["default"].flat(), variants["learned.ladder=[0.1, 0.0];learned.audit_step=0.2"].flat()
    assert (base["scenario.name"], base["mission.approach"], base["truth.name"], base["tsg.robust"]) == \
        ("leo", "ahead", "realistic", True)
    assert {k for k in base if base[k] != var[k]} == {"learned.ladder", "learned.audit_step"}
    assert var["learned.ladder"] == [0.1, 0.0] and var["learned.audit_step"] == 0.2


@pytest.mark.parametrize("args, problem", [
    (["--seeds", "9-3"], "--seeds range is empty"),
    (["--seeds", "x"], "--seeds expects A-B"),
    (["--variant", "learned.ladder=[0.0, 0.1]"], "strictly decreasing"),
    (["--variant", "learned.no_such=1"], "unknown configuration parameter"),
])
def test_bad_arguments_are_one_line_and_exit_2(args, problem, capsys) -> None:
    assert main(["compare", *args]) == 2
    err = capsys.readouterr().err
    assert problem in err and len(err.strip().splitlines()) == 1
