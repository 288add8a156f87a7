"""Offline missions: the nominal rendezvous, a 10-run Monte Carlo, metrics vs independent formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cikan_ros.constraints import margins
from cikan_ros.governor import ConventionalGovernor
from cikan_ros.mission import nominal_start, run_mission, sample_start


@pytest.fixture(scope="module")
def nominal(predictor):
    return run_mission(ConventionalGovernor(predictor), nominal_start(predictor))


def test_nominal_mission_docks_safely(nominal):
    """tau_0 in [-15, -5] s, tau reaches 0, docked (< 1 m, < 1 mm/s) within 4 h, no violation."""
    m = nominal.metrics()
    assert -15.0 <= m["tau0_s"] <= -5.0
    assert m["t_tau_zero_s"] is not None and m["t_tau_zero_s"] <= 4 * 3600
    assert m["final_distance_m"] < 1.0 and m["final_speed_mps"] < 1e-3
    assert m["violations"] == 0 and m["success"]
    assert m["duration_s"] == 4 * 3600


def test_plant_constraints_hold_at_every_step(cfg, nominal):
    """Recompute h1 and h3 from the recorded states with the formulas of SPEC §4."""
    rel = nominal.x_d - nominal.x_c
    p, v = rel[:, :3], rel[:, 3:]
    pn, vc = np.linalg.norm(p, axis=1), np.linalg.norm(nominal.x_c[:, 3:], axis=1)
    h1 = np.einsum("ij,ij->i", nominal.x_c[:, 3:], p) + math.cos(math.radians(20)) * vc * pn
    outside_apex = pn > 1e-3
    assert np.all(h1[outside_apex] / (vc * pn)[outside_apex] <= 1e-9)
    near = pn <= 5.0
    assert np.all(np.linalg.norm(v, axis=1)[near] - 20 * pn[near] - 1e-3 <= 1e-9)
    assert np.all(np.linalg.norm(nominal.u, axis=1) <= 5e-4 * (1 + 1e-12))


def test_metrics_match_independent_formulas(cfg, nominal):
    m = nominal.metrics()
    dv = 10.0 * np.linalg.norm(nominal.u, axis=1).sum()  # dV = T_c sum |u_k|
    assert m["delta_v_kmps"] == pytest.approx(dv, rel=1e-12)
    rel = nominal.x_d[-1] - nominal.x_c[-1]
    assert m["final_distance_m"] == pytest.approx(1e3 * np.linalg.norm(rel[:3]), rel=1e-12)
    assert m["tau0_s"] == nominal.tau[0]
    first_zero = nominal.t[np.argmax(nominal.tau == 0.0)]
    assert m["t_tau_zero_s"] == first_zero
    mm = margins(nominal.x_d, nominal.x_c, nominal.u, cfg.constraints, 5e-4, cfg.side)
    assert m["min_h1_margin"] == pytest.approx(-np.nanmax(mm.h1_normalised), rel=1e-12)
    assert m["updates"] == 14400 // 60 - 1
    assert m["update_ms_max"] >= m["update_ms_mean"] > 0


def test_ten_run_monte_carlo_all_succeed(predictor):
    """Seeds 1..10 of the Monte Carlo distribution (SPEC §6): every run docks with zero violations."""
    gov = ConventionalGovernor(predictor)
    dvs = []
    for seed in range(1, 11):
        m = run_mission(gov, sample_start(predictor, seed)).metrics()
        assert m["success"], (seed, m)
        assert m["violations"] == 0
        dvs.append(m["delta_v_kmps"])
    assert 0.3 < np.mean(dvs) < 6.0  # SPEC §10 saw 1-4 km/s on Monte Carlo starts


def test_sampler_is_deterministic_and_admissible(cfg, predictor):
    a, b = sample_start(predictor, 7), sample_start(predictor, 7)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, sample_start(predictor, 8))
    x_c = predictor.orbit.state(0.0)
    assert margins(a, x_c, np.zeros(3), cfg.constraints, 5e-4, cfg.side).h1[0] <= 0
    np.testing.assert_array_equal(a[3:], nominal_start(predictor)[3:])  # velocity as nominal


def test_schedule_of_the_default_mission(cfg):
    """SPEC §6: T_c = 10 s, P_upd = 60 s, T_sim = 4 h: K = 1440 steps at t_k = 10 k s exactly, a
    decision at k = 0 and every 6th step after it, 240 in all (k = K needs none)."""
    from cikan_ros.mission import Schedule

    s = Schedule(cfg)
    assert s.n_steps == 1440 and s.every == 6
    np.testing.assert_array_equal(s.times(), 10.0 * np.arange(1441))
    due = [k for k in range(s.n_steps) if k == 0 or s.update_due(k)]
    assert due[:3] == [0, 6, 12] and due[-1] == 1434 and len(due) == 240
    assert not s.finished(1439, np.zeros(6), np.ones(6)) and s.finished(1440, np.zeros(6), np.ones(6))


def test_docking_test_is_strict_and_per_row(cfg):
    """Docked iff |p_rel| < 1 m and |v_rel| < 1 mm/s (SPEC §6); on the boundary it is not."""
    from cikan_ros.mission import Schedule, docked

    x_c = np.array([7000.0, 0.0, 0.0, 0.0, 7.5, 0.0])
    rows = np.array([x_c + [0.0009, 0, 0, 0, 0, 9e-7], x_c + [0.001, 0, 0, 0, 0, 0],
                     x_c + [0, 0, 0, 0, 1e-6, 0], x_c])
    np.testing.assert_array_equal(docked(rows, x_c, cfg), [True, False, False, True])
    assert Schedule(cfg).finished(3, rows[0], x_c, stop_on_dock=True)
    assert not Schedule(cfg).finished(3, rows[1], x_c, stop_on_dock=True)


def test_shift_audit_of_a_governed_and_of_tampered_histories(predictor, nominal):
    """The conventional run keeps the contract; tau = 0 from the start and a shift changed
    between updates are found. References: Verify called directly, the schedule of SPEC §6."""
    from cikan_ros.mission import audit_shifts
    from cikan_ros.units import through_si

    x_seen = through_si(nominal.x_d)      # the states the governor saw
    audit = audit_shifts(predictor, x_seen, nominal.tau)
    assert (audit.unverified, audit.off_schedule, audit.decisions) == (0, 0, 240)
    zero = audit_shifts(predictor, x_seen, np.zeros_like(nominal.tau))
    assert not predictor.verify(x_seen[0], 0.0, 0.0)   # tau = 0 is not admissible at the start
    assert zero.off_schedule == 0 and 1 <= zero.unverified <= 240
    tampered = nominal.tau.copy()
    tampered[3] = nominal.tau[3] / 2                      # changed at k = 3, back at k = 4
    assert audit_shifts(predictor, x_seen, tampered).off_schedule == 2
    late = nominal.tau.copy()
    late[:2] = np.nan                                     # no shift before k = 2: the first comes then
    assert audit_shifts(predictor, x_seen, late).decisions == 240
