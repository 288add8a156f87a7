"""`cikan compare`: paired closed-loop figures against the conventional TSG (contracts and golden)."""

from __future__ import annotations

import pytest

from cikan_ros.cli import main
from cikan_ros.compare import compare, relative_figures
from cikan_ros.config import load_config


def _run(dv: float, t0: float | None, cpu: float, n: int, calls: int, ok: bool = True) -> dict:
    return {"delta_v_kmps": dv, "t_tau_zero_s": t0, "success": ok, "violations": 0,
            "active_cpu_s": cpu, "active_updates": n, "active_verify_calls": calls}


def test_relative_figures_are_ratios_of_sums_on_paired_starts() -> None:
    """ΔV ratio = Σ mine / Σ conv; t(τ=0) only over runs where both reached 0; speed-up = conv CPU
    per active update / mine; calls per active update."""
    conv = [_run(1.0, 1000.0, 0.10, 100, 1800), _run(3.0, None, 0.30, 200, 3600)]
    mine = [_run(1.5, 1100.0, 0.01, 50, 100), _run(2.5, 2000.0, 0.02, 150, 350, ok=False)]
    f = relative_figures(mine, conv)
    assert f["delta_v_ratio"] == pytest.approx(4.0 / 4.0)
    # R = 1, e = (0.5, -0.5): SE = sqrt(2 · 0.5) / 4
    assert f["delta_v_ratio_se"] == pytest.approx(0.25)
    assert f["t_tau_zero_ratio"] == pytest.approx(1100.0 / 1000.0)
    assert f["verify_calls_mean"] == pytest.approx(450 / 200)
    assert f["active_speedup"] == pytest.approx((0.40 / 300) / (0.03 / 200))
    assert (f["success"], f["violations"]) == (1, 0)


def test_the_conventional_against_itself_is_exactly_one() -> None:
    """Same starts, same deterministic governor: every ratio is 1 (the pairing is by seed)."""
    cfg = load_config()
    rows = compare({"default": cfg, "other rule": cfg.replace(**{"learned.algorithm": "paper"})},
                   ["conventional"], [3])
    assert [r["variant"] for r in rows] == ["default", "other rule"]
    for r in rows:
        assert r["delta_v_ratio"] == 1.0 and r["t_tau_zero_ratio"] == 1.0
        assert (r["success"], r["violations"], r["runs"]) == (1, 0, 1)


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
