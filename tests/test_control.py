"""FTRE controller: ZOH discretisation, DARE gains vs scipy, periodic interpolation, saturation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad_vec
from scipy.linalg import expm, solve_discrete_are

from cikan_ros.config import control_config, load_config
from cikan_ros.control import (B_INPUT, dlqr_gain, ftre_control, gain_at, interpolate_gain, saturate,
                               zoh_discretise)
from cikan_ros.dynamics import linearisation
from cikan_ros.orbit import KeplerOrbit, elements_to_state

U_MAX = 5e-4


def test_zoh_discretisation_matches_integral(predictor):
    """A_d = e^{A T}, B_d = ∫_0^T e^{A s} ds B (integrated numerically)."""
    a = linearisation(predictor.orbit.state(0.0)[:3], predictor.orbit.mu)
    a_d, b_d = zoh_discretise(a, B_INPUT, 10.0)
    np.testing.assert_allclose(a_d, expm(a * 10.0), rtol=1e-12, atol=1e-15)
    integral, _ = quad_vec(lambda s: expm(a * s) @ B_INPUT, 0.0, 10.0, epsabs=1e-14)
    np.testing.assert_allclose(b_d, integral, rtol=1e-9, atol=1e-14)


def test_gain_table_rows_are_dare_gains(cfg, predictor):
    """Row j equals K from scipy.linalg.solve_discrete_are at nu_j, and A_d - B_d K is stable."""
    table = predictor.gains
    assert table.shape == (721, 3, 6)
    np.testing.assert_array_equal(table[0], table[-1])
    orbit = predictor.orbit
    q, r = np.diag(cfg.control.q_diag), np.diag(cfg.control.r_diag)
    for j in (0, 1, 180, 359, 500, 720):
        nu = math.radians(0.5 * j)
        x = elements_to_state(orbit.a, orbit.e, orbit.i, orbit.raan, orbit.argp, nu, orbit.mu)
        a = linearisation(x[:3], orbit.mu)
        blk = expm(np.block([[a, B_INPUT], [np.zeros((3, 9))]]) * cfg.control.period_s)
        a_d, b_d = blk[:6, :6], blk[:6, 6:]
        s = solve_discrete_are(a_d, b_d, q, r)
        k = np.linalg.inv(b_d.T @ s @ b_d + r) @ b_d.T @ s @ a_d
        np.testing.assert_allclose(table[j], k, rtol=1e-8, atol=1e-12)
        assert max(abs(np.linalg.eigvals(a_d - b_d @ k))) < 1.0


def test_interpolation_is_linear_and_periodic(cfg, predictor):
    table = predictor.gains
    step = math.radians(cfg.control.grid_deg)
    np.testing.assert_allclose(interpolate_gain(table, 10 * step), table[10], atol=1e-15)
    np.testing.assert_allclose(interpolate_gain(table, 10.5 * step), 0.5 * (table[10] + table[11]), atol=1e-15)
    np.testing.assert_allclose(interpolate_gain(table, 2 * math.pi + 3 * step), table[3], atol=1e-14)
    np.testing.assert_allclose(interpolate_gain(table, -step), table[719], atol=1e-14)
    # Wrap: just below 2 pi approaches K(0).
    np.testing.assert_allclose(interpolate_gain(table, 2 * math.pi - 1e-12), table[0], atol=1e-9)


def test_interpolated_gain_is_close_to_exact_between_nodes(cfg, predictor):
    """Between grid nodes the interpolant stays within 1 % of the exact DARE gain."""
    step = math.radians(cfg.control.grid_deg)
    for nu in (0.25 * step, 77.5 * step, 400.3 * step):
        exact = gain_at(predictor.orbit, nu, cfg.control)
        err = np.abs(interpolate_gain(predictor.gains, nu) - exact).max()
        assert err < 0.01 * np.abs(exact).max()


def test_saturation_caps_and_keeps_direction():
    u = np.array([3e-3, -4e-3, 0.0])
    s = saturate(u, U_MAX)
    assert np.linalg.norm(s) == pytest.approx(U_MAX, rel=1e-15)
    np.testing.assert_allclose(s / np.linalg.norm(s), u / np.linalg.norm(u), rtol=1e-15)
    small = np.array([1e-4, 2e-4, -1e-4])
    np.testing.assert_array_equal(saturate(small, U_MAX), small)
    np.testing.assert_array_equal(saturate(np.zeros(3), U_MAX), np.zeros(3))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3))
def test_saturation_properties(v):
    u = np.array(v)
    s = saturate(u, U_MAX)
    assert np.linalg.norm(s) <= U_MAX * (1 + 1e-15)
    if np.linalg.norm(u) > 0:
        # Same direction: the cross product vanishes and the dot product is positive.
        assert np.linalg.norm(np.cross(s, u)) <= 1e-12 * np.linalg.norm(u) * max(np.linalg.norm(s), 1e-300)
        assert s @ u >= 0


def test_control_drives_toward_the_target(predictor):
    """A deputy 10 m behind the target gets a forward push; at the target u = 0."""
    x_v, nu = predictor.orbit.state_and_anomaly(100.0)
    assert np.all(ftre_control(predictor.gains, nu, x_v, x_v, U_MAX) == 0.0)
    x_d = x_v.copy()
    x_d[:3] -= 0.01 * x_v[3:] / np.linalg.norm(x_v[3:])
    u = ftre_control(predictor.gains, nu, x_d, x_v, U_MAX)
    assert u @ x_v[3:] > 0


@settings(max_examples=300, deadline=None)
@given(nu=st.one_of(st.floats(-20.0, 20.0), st.sampled_from([0.0, -0.0, 2 * math.pi, math.nextafter(2 * math.pi, 0),
                                                               math.pi, 1e-300])),
       dx=st.lists(st.floats(-50.0, 50.0), min_size=6, max_size=6),
       u_max=st.sampled_from([U_MAX, 1e-9, 1.0]))
def test_control_is_the_interpolated_gain_times_the_error_to_the_bit(predictor, nu, dx, u_max):
    """ftre_control interpolates K inside the product (no scratch gain): the same bits as
    interpolate_gain (the periodic modulo included) followed by u_r = -sum_c K_rc dx_c in column
    order and the saturation, at any anomaly (negative, past 2 pi, signed zeros)."""
    x_v = predictor.orbit.state(300.0)
    x_d = x_v + np.array(dx) * np.array([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3])
    k = interpolate_gain(predictor.gains, nu)
    d = [float(a - b) for a, b in zip(x_d, x_v)]
    ref = np.empty(3)
    for r in range(3):
        acc = 0.0
        for c in range(6):
            acc -= float(k[r, c]) * d[c]
        ref[r] = acc
    u = ftre_control(predictor.gains, nu, x_d, x_v, u_max)
    np.testing.assert_array_equal(u.view(np.int64), saturate(ref, u_max).view(np.int64))


def test_gain_table_disk_cache_is_bit_exact_and_recovers(cfg, tmp_path, monkeypatch):
    """A cached table equals the computed one bit for bit; a corrupt cache file is recomputed."""
    from cikan_ros import control
    from cikan_ros.orbit import KeplerOrbit

    monkeypatch.setenv("CIKAN_CACHE_DIR", str(tmp_path))
    orbit = KeplerOrbit.from_config(cfg.orbit)
    ctl = type(cfg.control)(grid_deg=10.0)  # a small table: 37 rows
    control.gain_table.cache_clear()
    first = control.gain_table(orbit, ctl)
    files = list(tmp_path.glob("gains-*.npy"))
    assert len(files) == 1
    control.gain_table.cache_clear()
    np.testing.assert_array_equal(control.gain_table(orbit, ctl), first)  # read back from disk
    np.testing.assert_array_equal(first, control.compute_gain_table(orbit, ctl))
    files[0].write_bytes(b"not a numpy file")
    control.gain_table.cache_clear()
    np.testing.assert_array_equal(control.gain_table(orbit, ctl), first)
    control.gain_table.cache_clear()


def dare_by_doubling(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Independent DARE reference: the structure-preserving doubling algorithm (Chu, Fan, Lin,
    Wang 2004), A' = A W^-1 A, G' = G + A W^-1 G A^T, H' = H + A^T H W^-1 A with W = I + G H,
    from A, G = B R^-1 B^T, H = Q; H converges quadratically to the stabilising S."""
    n = a.shape[0]
    g, h = b @ np.linalg.solve(r, b.T), q.copy()
    for _ in range(60):
        w = np.eye(n) + g @ h
        a_w = np.linalg.solve(w.T, a.T).T                      # A W^-1
        h_next = h + a.T @ h @ np.linalg.solve(w, a)
        g, a = g + a_w @ g @ a.T, a_w @ a
        if np.max(np.abs(h_next - h)) <= 1e-14 * np.max(np.abs(h_next)):
            return h_next
        h = h_next
    raise AssertionError("the doubling iteration did not converge")


#: Anomalies (rad) to check gains at: every 15 deg, and 0.3 rad, where plain scipy's DARE
#: failed with R = 1e8 I on one processor (3 to 6 of the 720 grid anomalies fail on others).
ANOMALIES = [math.radians(d) for d in range(0, 360, 15)] + [0.3]


@pytest.mark.parametrize("r_diag", [[1e8] * 3, [1e8, 1.0, 1e4], [1.0] * 3])
def test_dlqr_gain_is_the_dare_gain(cfg, r_diag):
    """dlqr_gain (the input scaled by R^-1/2, so that scipy solves with R' = I) gives the DARE's
    stabilising S and K = (B^T S B + R)^-1 B^T S A of the unscaled problem: against the doubling
    algorithm, the DARE residual and a stable loop at every anomaly, and against plain
    solve_discrete_are wherever that one succeeds (with R = 1e8 I it fails at some anomalies on
    some processors: its QZ reordering, the reason for the scaling; which, is not asserted).
    R = diag(1e8, 1, 1e4) exercises the scaling with unequal weights on every processor; with
    R = I it is the plain solve, bit for bit."""
    orbit = KeplerOrbit.from_config(cfg.orbit)
    q, r = np.diag(cfg.control.q_diag), np.diag(r_diag)
    for nu in ANOMALIES:
        x = elements_to_state(orbit.a, orbit.e, orbit.i, orbit.raan, orbit.argp, nu, orbit.mu)
        a_d, b_d = zoh_discretise(linearisation(x[:3], orbit.mu), B_INPUT, cfg.control.period_s)
        k, s = dlqr_gain(a_d, b_d, q, r)
        s_ref = dare_by_doubling(a_d, b_d, q, r)
        np.testing.assert_allclose(s, s_ref, rtol=1e-9, atol=1e-9 * np.max(np.abs(s_ref)))
        k_ref = np.linalg.solve(b_d.T @ s_ref @ b_d + r, b_d.T @ s_ref @ a_d)
        np.testing.assert_allclose(k, k_ref, rtol=1e-8, atol=1e-9 * np.max(np.abs(k_ref)))
        residual = a_d.T @ s @ a_d - a_d.T @ s @ b_d @ k + q - s
        assert np.max(np.abs(residual)) <= 1e-9 * np.max(np.abs(s))
        assert max(abs(np.linalg.eigvals(a_d - b_d @ k))) < 1.0
        try:
            s_plain = solve_discrete_are(a_d, b_d, q, r)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if r_diag == [1.0] * 3:
            np.testing.assert_array_equal(s, s_plain)
        np.testing.assert_allclose(s, s_plain, rtol=1e-8, atol=1e-9 * np.max(np.abs(s_plain)))


def test_robust_verify_flies_the_robust_weight():
    """control_config: the paper's R under nominal Verify, control.robust_r_diag under robust
    Verify, and the paper's again when robust_r_diag is set to it."""
    nominal = load_config()
    robust = load_config(**{"tsg.robust": True})
    assert control_config(nominal) is nominal.control
    assert control_config(robust).r_diag == robust.control.robust_r_diag != robust.control.r_diag
    same = load_config(**{"tsg.robust": True, "control.robust_r_diag": list(robust.control.r_diag)})
    assert control_config(same).r_diag == same.control.r_diag
