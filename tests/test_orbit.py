"""Orbit: Kepler propagation against scipy's DOP853, element round trips, VNB frame."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from cikan_ros.config import load_config
from cikan_ros.dynamics import two_body_rhs
from cikan_ros.errors import StateError
from cikan_ros.orbit import (P_E, P_M0, P_N, ROTATE_MAX, KeplerOrbit, _rotated, eccentric_anomaly_kernel,
                             elements_to_state, state_from_anomaly_kernel, state_to_elements, state_warm_kernel,
                             vnb_frame, wrap_anomaly_kernel)

MU = 398600.4418


def test_period_and_periapsis_golden(predictor):
    """T = 2 pi sqrt(a^3/mu) = 43288.81 s; r_p = a(1-e) = 6928.137 km; v_p = sqrt(mu(1+e)/r_p)."""
    orbit = predictor.orbit
    assert orbit.period == pytest.approx(43288.81, abs=0.01)
    x0 = orbit.state(0.0)
    assert np.linalg.norm(x0[:3]) == pytest.approx(6928.137, abs=1e-3)
    assert np.linalg.norm(x0[3:]) == pytest.approx(10.00542, abs=1e-5)
    assert float(x0[:3] @ x0[3:]) == pytest.approx(0.0, abs=1e-9)  # periapsis: r ⟂ v


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_kepler_matches_dop853_over_one_period(predictor, direction):
    """Analytic propagation vs DOP853 (rtol 1e-12) forward and backward over one period: < 1 m."""
    orbit = predictor.orbit
    t_end = direction * orbit.period
    times = np.linspace(0.0, t_end, 201)
    sol = solve_ivp(lambda _t, y: two_body_rhs(y, np.zeros(3), MU), (0.0, t_end), orbit.state(0.0),
                    method="DOP853", rtol=1e-12, atol=1e-12, t_eval=times)
    kepler = orbit.state(times)
    pos_err = np.linalg.norm(kepler[:, :3] - sol.y[:3].T, axis=1)
    vel_err = np.linalg.norm(kepler[:, 3:] - sol.y[3:].T, axis=1)
    assert pos_err.max() < 1e-3  # km
    assert vel_err.max() < 1e-6  # km/s


def test_state_shapes_and_anomaly_range(predictor):
    t = np.linspace(-5e4, 5e4, 12).reshape(3, 4)
    x, nu = predictor.orbit.state_and_anomaly(t)
    assert x.shape == (3, 4, 6) and nu.shape == (3, 4)
    assert np.all((nu >= 0) & (nu < 2 * np.pi))
    assert predictor.orbit.state(0.0).shape == (6,)
    # one float time (Python or numpy) takes a shorter path to the same kernel: the same bits
    for k, tk in enumerate(t.ravel()):
        for one in (float(tk), np.float64(tk)):
            x1, nu1 = predictor.orbit.state_and_anomaly(one)
            assert x1.shape == (6,) and np.array_equal(x1, x.reshape(-1, 6)[k]) and nu1 == nu.ravel()[k]
    for bad in (float("nan"), np.inf, np.array([0.0, np.nan])):
        with pytest.raises(StateError, match="finite"):
            predictor.orbit.state_and_anomaly(bad)


def test_chief_elements_recovered(cfg, predictor):
    """Cartesian -> elements of the chief at any time gives the configured elements."""
    x = predictor.orbit.state(np.array([0.0, 1234.5, -20000.0]))
    el = state_to_elements(x, MU)
    np.testing.assert_allclose(el["a"], cfg.orbit.a_km, rtol=1e-12)
    np.testing.assert_allclose(el["e"], cfg.orbit.e, rtol=1e-11)
    np.testing.assert_allclose(el["i"], math.radians(cfg.orbit.i_deg), atol=1e-12)
    np.testing.assert_allclose(el["argp"], math.radians(cfg.orbit.argp_deg), atol=1e-10)
    assert el["nu"][0] == pytest.approx(0.0, abs=1e-10) or el["nu"][0] == pytest.approx(2 * np.pi, abs=1e-10)


elements = st.tuples(
    st.floats(7000.0, 60000.0),          # a
    st.floats(0.01, 0.9),                # e
    st.floats(0.05, math.pi - 0.05),     # i
    st.floats(0.0, 2 * math.pi - 1e-6),  # raan
    st.floats(0.0, 2 * math.pi - 1e-6),  # argp
    st.floats(0.0, 2 * math.pi - 1e-6),  # nu
)


@settings(max_examples=200, deadline=None)
@given(elements)
def test_elements_round_trip(el):
    a, e, i, raan, argp, nu = el
    x = elements_to_state(a, e, i, raan, argp, nu, MU)
    back = state_to_elements(x, MU)
    x2 = elements_to_state(back["a"], back["e"], back["i"], back["raan"], back["argp"], back["nu"], MU)
    np.testing.assert_allclose(x2, x, rtol=0, atol=1e-8 * max(1.0, float(np.abs(x).max())))
    assert back["a"] == pytest.approx(a, rel=1e-10)
    assert back["e"] == pytest.approx(e, abs=1e-10)


@settings(max_examples=300, deadline=None)
@given(st.floats(-100.0, 100.0), st.floats(0.0, 0.99))
def test_kepler_equation_residual(m, e):
    """E - e sin E = M (mod 2 pi) for every M and e < 1."""
    big_e = eccentric_anomaly_kernel(m, e)
    resid = (big_e - e * math.sin(big_e) - m + math.pi) % (2 * math.pi) - math.pi
    assert abs(resid) < 1e-12


@settings(max_examples=200, deadline=None)
@given(t=st.floats(-1e5, 1e5), dt=st.sampled_from([1.0, 10.0, 60.0, 600.0]))
def test_warm_started_state_is_the_cold_one_and_returns_its_sine_and_cosine(predictor, t, dt):
    """state_warm_kernel from the previous sample's anomaly (the rollout's virtual target) solves
    Kepler's equation at t (the cold solver's E to 1e-14 rad), returns sin E and cos E within
    1e-15 of the library's (turned, not computed; 600 s is beyond the turning range: computed)
    and the state of that E to 1e-14 of |r| and |v|."""
    orb = predictor.orbit.params
    prev = eccentric_anomaly_kernel(orb[P_M0] + orb[P_N] * (t - dt), orb[P_E])
    advance = orb[P_N] * dt / (1.0 - orb[P_E] * math.cos(prev))
    warm, cold = np.empty(6), np.empty(6)
    nu, big_e, sin_e, cos_e = state_warm_kernel(orb, t, prev, math.sin(prev), math.cos(prev), advance, warm)
    e_cold = eccentric_anomaly_kernel(orb[P_M0] + orb[P_N] * t, orb[P_E])
    assert abs((big_e - e_cold + math.pi) % (2 * math.pi) - math.pi) < 1e-14
    assert abs(sin_e - math.sin(big_e)) < 1e-15 and abs(cos_e - math.cos(big_e)) < 1e-15
    assert nu == pytest.approx(state_from_anomaly_kernel(orb, big_e, cold), abs=1e-13)
    assert _relative_error(warm, cold) < 1e-14
    assert _relative_error(warm, predictor.orbit.state(t)) < 1e-12


def _relative_error(x: np.ndarray, ref: np.ndarray) -> float:
    """Largest of |dr| / |r| and |dv| / |v|."""
    return max(float(np.linalg.norm(x[:3] - ref[:3]) / np.linalg.norm(ref[:3])),
               float(np.linalg.norm(x[3:] - ref[3:]) / np.linalg.norm(ref[3:])))


@pytest.mark.parametrize("e", [0.0, 0.5, 0.74])
def test_a_chain_of_warm_samples_stays_on_kepler_motion(e):
    """10,000 samples of 10 s chained as the rollout chains them (each sample's E, sin E and cos E
    start the next): the turned sine and cosine drift by rounding alone (at most 5.7e-13 here,
    on the circular orbit), so after 28 hours of samples, longer than any horizon, the state
    still matches Kepler's equation solved afresh to 1e-12 of |r| and |v| (measured: 1.3e-13)."""
    orbit = KeplerOrbit.from_config(load_config(**{"orbit.e": e}).orbit)
    orb = orbit.params
    ts = 10.0
    big_e = eccentric_anomaly_kernel(orb[P_M0], orb[P_E])
    s, c = math.sin(big_e), math.cos(big_e)
    x = np.empty(6)
    worst_sc = worst_x = 0.0
    for j in range(1, 10_001):
        _, big_e, s, c = state_warm_kernel(orb, j * ts, big_e, s, c, orb[P_N] * ts / (1.0 - orb[P_E] * c), x)
        worst_sc = max(worst_sc, abs(s - math.sin(big_e)), abs(c - math.cos(big_e)))
        if j % 97 == 0:
            ref = orbit.state(j * ts)
            worst_x = max(worst_x, _relative_error(x, ref))
    assert worst_sc < 2e-12 and worst_x < 1e-12


_TWO_PI = 2.0 * math.pi


@settings(max_examples=500, deadline=None)
@given(a=st.one_of(st.floats(-math.pi, 3.0 * math.pi), st.floats(allow_nan=True, allow_infinity=True),
                   st.sampled_from([-math.pi, 0.0, -0.0, math.pi, 3.0 * math.pi, math.pi - 1e-16,
                                    3.0 * math.pi - 4e-16, math.nextafter(-math.pi, 0.0),
                                    math.nextafter(3.0 * math.pi, 0.0), -4.0, 1e6, -1e6])))
def test_wrapping_an_anomaly_is_the_python_remainder_bit_for_bit(a):
    """wrap_anomaly_kernel(a) is (a + pi) % (2 pi) - pi to the bit (Python's float remainder, a
    reference independent of the kernel's fast paths), on the paths' edges, far outside and NaN."""
    ref = (a + math.pi) % _TWO_PI - math.pi
    got = wrap_anomaly_kernel(a)
    assert (math.isnan(got) and math.isnan(ref)) or got.hex() == ref.hex()


@settings(max_examples=300, deadline=None)
@given(x=st.floats(-10.0, 10.0), d=st.floats(-ROTATE_MAX, ROTATE_MAX))
def test_turning_sine_and_cosine_by_a_small_angle_is_the_library_to_rounding(x, d):
    """sin(x + d) = sin x cos d + cos x sin d, cos(x + d) = cos x cos d - sin x sin d, with the
    series of sin d and cos d: within 4e-16 of math.sin and math.cos for |d| <= ROTATE_MAX."""
    s, c = _rotated(math.sin(x), math.cos(x), d)
    assert abs(s - math.sin(x + d)) < 4e-16 + 2e-16 * abs(x) and abs(c - math.cos(x + d)) < 4e-16 + 2e-16 * abs(x)


def test_vnb_frame_is_orthonormal_and_along_velocity(predictor):
    x = predictor.orbit.state(np.linspace(0, 40000, 7))
    rot = vnb_frame(x)
    for r, xc in zip(rot, x):
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-13)
        assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(r[0], xc[3:] / np.linalg.norm(xc[3:]), atol=1e-14)
        assert abs(r[1] @ xc[:3]) < 1e-9  # ŷ is normal to the orbit plane


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_time_is_rejected(predictor, bad):
    with pytest.raises(StateError, match="finite"):
        predictor.orbit.state(bad)


def test_degenerate_states_are_rejected():
    with pytest.raises(StateError, match="non-finite"):
        state_to_elements([7000.0, 0, 0, np.nan, 7.5, 0], MU)
    with pytest.raises(StateError, match="parallel"):
        state_to_elements([7000.0, 0, 0, 1.0, 0, 0], MU)
    with pytest.raises(StateError, match="elliptic"):
        state_to_elements([7000.0, 0, 0, 0, 20.0, 0], MU)
    with pytest.raises(StateError, match="centre"):
        state_to_elements([0.0, 0, 0, 0, 7.5, 0], MU)


def test_orbit_from_config_true_anomaly(cfg):
    """nu0 = 90 deg gives a state at true anomaly 90 deg at t = 0."""
    orbit = KeplerOrbit.from_config(type(cfg.orbit)(nu0_deg=90.0))
    _, nu = orbit.state_and_anomaly(0.0)
    assert float(nu) == pytest.approx(math.pi / 2, abs=1e-12)
