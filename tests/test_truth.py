"""The truth model: J2 gravity against the potential's gradient and scipy, the drawn errors
within their declared bounds, seeding, and the chief anchored on its measured state."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cikan_ros.config import load_config, truth_overrides
from cikan_ros.dynamics import J2_EARTH, R_EARTH_KM, j2_acceleration, rk4_step
from cikan_ros.errors import ConfigError, StateError
from cikan_ros.orbit import KeplerOrbit
from cikan_ros.mission import nominal_start
from cikan_ros.truth import Truth, gauss_markov
from cikan_ros.tsg import ChiefAnchor, Predictor

MU = 398600.4418


def j2_potential(r: np.ndarray) -> float:
    """U_J2 = -mu J2 R^2 / (2 r^3) (3 z^2 / r^2 - 1): the J2 term of the geopotential (a = grad U)."""
    rn = float(np.linalg.norm(r))
    return -MU * J2_EARTH * R_EARTH_KM**2 / (2 * rn**3) * (3 * r[2] ** 2 / rn**2 - 1)


@pytest.mark.parametrize("r", [[7000.0, 0.0, 0.0], [0.0, 0.0, 6900.0], [4000.0, -3000.0, 5000.0],
                               [1104.7, -3126.6, -6083.5]])
def test_j2_acceleration_is_the_gradient_of_the_j2_potential(r):
    r = np.array(r)
    h = 1e-3
    grad = np.array([(j2_potential(r + h * e) - j2_potential(r - h * e)) / (2 * h) for e in np.eye(3)])
    np.testing.assert_allclose(j2_acceleration(r, MU), grad, rtol=1e-7, atol=1e-16)


def test_rk4_with_j2_matches_dop853_with_the_potential_gradient():
    x0 = KeplerOrbit.from_config(load_config().orbit).state(0.0)

    def rhs(_t, y):
        r = y[:3]
        return np.concatenate([y[3:], -MU * r / np.linalg.norm(r) ** 3 + j2_acceleration(r, MU)])

    ref = solve_ivp(rhs, (0, 600.0), x0, method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]
    x = x0.copy()
    for _ in range(60):
        x = rk4_step(x, np.zeros(3), 10.0, MU, 10, 1.5 * J2_EARTH * R_EARTH_KM**2)
    assert np.linalg.norm(x[:3] - ref[:3]) < 1e-6  # km: under a millimetre after 10 minutes
    # and J2 matters at this resolution: two-body lands hundreds of metres away
    two_body = x0.copy()
    for _ in range(60):
        two_body = rk4_step(two_body, np.zeros(3), 10.0, MU, 10)
    assert np.linalg.norm(two_body[:3] - ref[:3]) > 0.1


def realistic(**extra) -> object:
    return load_config(**{**truth_overrides("realistic"), **extra})


def test_truth_errors_stay_within_their_declared_bounds():
    cfg = realistic(**{"truth.scale": 2.0})
    tc = cfg.truth
    truth = Truth(cfg, seed=7, n_steps=400)
    x_d = truth.chief_state(0) + np.array([3.0, -1.0, 2.0, 1e-3, 0.0, -1e-3])
    for k in range(0, 400, 7):
        meas, cov = truth.measure_deputy(k, x_d)
        rng = np.linalg.norm(x_d[:3] - truth.chief_state(k)[:3])
        bp = 2 * (tc.nav_pos_floor_km + tc.nav_pos_range_fraction * rng)
        bv = 2 * (tc.nav_vel_floor_kmps + tc.nav_vel_range_fraction_per_s * rng)
        assert np.linalg.norm(meas[:3] - x_d[:3]) <= bp * (1 + 1e-12)
        assert np.linalg.norm(meas[3:] - x_d[3:]) <= bv * (1 + 1e-12)
        np.testing.assert_allclose(np.diag(cov), [(bp / 3) ** 2] * 3 + [(bv / 3) ** 2] * 3)
    assert np.all(np.linalg.norm(truth.disturbance, axis=1) <= 2 * tc.disturbance_max_kmps2 * (1 + 1e-12))
    steps = np.linalg.norm(np.diff(truth.nav_pos, axis=0), axis=1)
    assert steps.max() <= tc.nav_rate_per_s * cfg.control.period_s * (1 + 1e-12)
    rng = np.random.default_rng(0)
    b, theta = 2 * tc.thrust_bias_max, math.radians(2 * tc.thrust_pointing_max_deg)
    eps = b + (1 + b) * 2 * math.sin(theta / 2)
    for u in rng.normal(size=(50, 3)) * 1e-4:
        applied = truth.applied_thrust(u)
        assert np.linalg.norm(applied - u) <= eps * np.linalg.norm(u) * (1 + 1e-12)
        assert np.linalg.norm(applied) <= (1 + b) * np.linalg.norm(u) * (1 + 1e-12)


def test_truth_is_seeded_and_the_nominal_truth_is_the_model():
    cfg = realistic()
    a, b, c = Truth(cfg, 3, 50), Truth(cfg, 3, 50), Truth(cfg, 4, 50)
    np.testing.assert_array_equal(a.nav_pos, b.nav_pos)
    assert a.bias == b.bias and a.bias != c.bias
    assert not np.array_equal(a.nav_pos, c.nav_pos)
    nominal = Truth(load_config(), 3, 50)
    x = nominal.chief_state(0) + 1.0
    u = np.array([1e-4, -2e-4, 3e-5])
    assert nominal.nominal and nominal.measure_deputy(5, x)[0] is x and nominal.applied_thrust(u) is u
    # the nominal chief is the configured Kepler orbit, bit for bit
    orbit = KeplerOrbit.from_config(load_config().orbit)
    np.testing.assert_array_equal(nominal.chief, orbit.state(np.arange(51) * 10.0))
    # scale 0 of the realistic truth is the nominal model, J2 included
    assert Truth(realistic(**{"truth.scale": 0.0}), 3, 5).nominal


def test_gauss_markov_is_stationary_and_bounded():
    out = gauss_markov(np.random.default_rng(1), 20000, 10.0, 300.0, 0.2)
    assert np.all(np.linalg.norm(out, axis=1) <= 1.0 + 1e-12)
    assert 0.25 < out.std(axis=0).mean() < 0.4  # a third of the bound per axis, a little clipped
    lag = 30  # 300 s: correlation exp(-1)
    corr = np.mean([np.corrcoef(out[:-lag, i], out[lag:, i])[0, 1] for i in range(3)])
    assert 0.2 < corr < 0.5


def test_chief_anchor_follows_the_measured_chief():
    pred = Predictor.from_config(load_config())
    anchor = ChiefAnchor(pred)
    x_c = pred.orbit.state(600.0)
    assert anchor(x_c, 600.0) is pred and anchor.re_anchors == 0
    moved = x_c + np.array([0.05, -0.02, 0.01, 1e-5, 0.0, 0.0])  # 50 m off the configured chief
    new = anchor(moved, 600.0)
    assert new is not pred and anchor.re_anchors == 1
    np.testing.assert_allclose(new.orbit.state(600.0), moved, rtol=0, atol=1e-9)
    # propagated like scipy integrates two-body motion from the measured state
    ref = solve_ivp(lambda _t, y: np.concatenate([y[3:], -MU * y[:3] / np.linalg.norm(y[:3]) ** 3]),
                    (600.0, 900.0), moved, method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]
    np.testing.assert_allclose(new.orbit.state(900.0)[:3], ref[:3], atol=1e-7)
    assert anchor(new.orbit.state(610.0), 610.0) is new  # within tolerance: no new chief table


def test_chief_anchor_tolerance_is_per_component_and_bad_states_are_named():
    cfg = load_config()
    pred = Predictor.from_config(cfg)
    anchor = ChiefAnchor(pred)
    tol = cfg.tsg.chief_anchor_tolerance_km
    x_c = pred.orbit.state(600.0)
    # the largest component counts, position (km) and velocity (km/s per sample period) apart
    assert anchor(x_c + np.array([0, 0, 0.9 * tol, 0, 0, 0]), 600.0) is pred
    assert anchor(x_c + np.array([0, 0, 0, 0, -0.9 * tol / cfg.tsg.sample_period_s, 0]), 600.0) is pred
    assert anchor.re_anchors == 0
    assert anchor(x_c + np.array([0, 0, 0, 0, -1.1 * tol / cfg.tsg.sample_period_s, 0]), 600.0) is not pred
    assert anchor.re_anchors == 1
    for bad in (np.where(np.arange(6) == 4, np.nan, x_c), np.where(np.arange(6) == 0, np.inf, x_c)):
        with pytest.raises(StateError, match="chief state x_c"):
            anchor(bad, 600.0)
    with pytest.raises(StateError, match="shape"):
        anchor(x_c[:5], 600.0)
    assert anchor.re_anchors == 1


#: A measured chief 50 m and 1 cm/s off the configured one (the anchor makes a new chief).
ANCHOR_OFFSET = np.array([0.05, -0.02, 0.01, 1e-5, 0.0, 0.0])


def test_j2_chief_rows_are_integrated_from_the_anchored_chief_whichever_buffer_holds_them():
    """Under the J2 prediction model the chief rows of an update are RK4 with J2 from the chief
    anchored at t (row j from row j - 1); the caches of a predictor and its re-anchored copies
    reuse one buffer once the cache before is gone. Rows left by an earlier update (a longer
    rollout, another chief) must not leak into the next: the rows equal a fresh predictor's, and
    scipy's integration of the anchored chief."""
    cfg = realistic(**{"tsg.robust": True})
    pred = Predictor.from_config(cfg)
    x_d = nominal_start(pred)
    tau0, _ = pred.initial_shift(x_d, 0.0)

    def filled(cache) -> np.ndarray:
        done = ~np.isnan(cache.rows[:, 6])
        assert done[0] and not np.any(done[int(np.argmin(done)):])  # a prefix
        return cache.rows[done]

    first = pred.cache(0.0)
    assert pred.verify(x_d, 0.0, tau0, first)   # a passing rollout: rows to its terminal sample
    n_first = len(filled(first))
    first_rows = first.rows
    del first
    moved = pred.orbit.state(0.0) + ANCHOR_OFFSET
    anchored = ChiefAnchor(pred)(moved, 0.0)
    second = anchored.cache(0.0)
    assert second.rows is first_rows   # the buffer came back: nothing held it
    fresh = Predictor.from_config(cfg).with_orbit(anchored.orbit).cache(0.0)
    assert fresh.rows is not first_rows
    for tau in (0.0, tau0 / 2):   # rollouts shorter than the first's
        assert anchored.verify(x_d, 0.0, tau, second) == anchored.verify(x_d, 0.0, tau, fresh)
    a, b = filled(second), filled(fresh)
    assert 1 < len(a) < n_first and len(a) == len(b)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(a[0, :6], moved, rtol=0, atol=1e-9)
    # row j is the anchored chief integrated over j samples (scipy, the J2 potential's gradient)
    j = len(a) - 1
    ref = solve_ivp(lambda _t, y: np.concatenate([y[3:], -MU * y[:3] / np.linalg.norm(y[:3]) ** 3
                                                  + j2_acceleration(y[:3], MU)]),
                    (0.0, j * cfg.tsg.sample_period_s), a[0, :6], method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]
    np.testing.assert_allclose(a[j, :3], ref[:3], rtol=0, atol=1e-6)
    # a cache still in use is never overwritten: the next one gets a buffer of its own
    held = anchored.cache(0.0)
    other = anchored.cache(10.0)
    assert other.rows is not held.rows
    np.testing.assert_array_equal(held.rows[0], a[0])


@pytest.mark.parametrize("key,value", [("truth.nav_pos_floor_km", -1.0),
                                       ("truth.thrust_bias_max", float("nan")),
                                       ("truth.gravity", "j4"), ("truth.scale", float("inf"))])
def test_bad_truth_values_are_named(key, value):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        realistic(**{key: value})


def test_truth_files_are_checked(tmp_path):
    with pytest.raises(ConfigError, match="unknown truth model 'nosuch'"):
        truth_overrides("nosuch")
    bad = tmp_path / "t.yaml"
    bad.write_text("/**:\n  ros__parameters:\n    tsg:\n      robust: true\n")
    with pytest.raises(ConfigError, match="sets 'tsg.robust'"):
        truth_overrides(str(bad))
