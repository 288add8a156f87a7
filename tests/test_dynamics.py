"""Dynamics: linearisation vs finite differences, RK4 (single and batch) vs DOP853 with the same ZOH."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cikan_ros.dynamics import Plant, linearisation, rk4_step, two_body_rhs
from cikan_ros.errors import ConfigError

MU = 398600.4418


def test_linearisation_matches_finite_differences(predictor):
    """A(r) = d f / d x of the unforced two-body field (central differences, h = 1e-3 km)."""
    x = predictor.orbit.state(1000.0)
    a = linearisation(x[:3], MU)
    num = np.empty((6, 6))
    for j in range(6):
        h = np.zeros(6)
        h[j] = 1e-3 if j < 3 else 1e-6
        num[:, j] = (two_body_rhs(x + h, np.zeros(3), MU) - two_body_rhs(x - h, np.zeros(3), MU)) / (2 * h[j])
    np.testing.assert_allclose(a, num, rtol=1e-6, atol=1e-15)


def _reference(x0, u_seq, dt):
    """DOP853 (rtol 1e-12) over consecutive ZOH periods."""
    x = np.array(x0)
    out = [x]
    for u in u_seq:
        sol = solve_ivp(lambda _t, y: two_body_rhs(y, u, MU), (0.0, dt), x, method="DOP853",
                        rtol=1e-12, atol=1e-12)
        x = sol.y[:, -1]
        out.append(x)
    return np.array(out)


def test_rk4_batch_matches_dop853_with_same_zoh(predictor):
    """A batch of 4 trajectories near periapsis, 60 ZOH steps of 10 s with random saturated thrust."""
    rng = np.random.default_rng(0)
    x0 = predictor.orbit.state(np.array([-20.0, -10.0, 0.0, 500.0]))
    x0[:, :3] += rng.normal(0, 5, (4, 3))
    u = rng.uniform(-3e-4, 3e-4, (60, 4, 3))
    x = x0.copy()
    for k in range(60):
        x = rk4_step(x, u[k], 10.0, MU, substeps=2)
    for b in range(4):
        ref = _reference(x0[b], u[:, b], 10.0)[-1]
        assert np.linalg.norm(x[b, :3] - ref[:3]) < 1e-6  # km: well under a millimetre in 10 min
        assert np.linalg.norm(x[b, 3:] - ref[3:]) < 1e-9


def test_rk4_batch_equals_single(predictor):
    rng = np.random.default_rng(1)
    x0 = predictor.orbit.state(np.linspace(0, 3000, 5))
    u = rng.uniform(-5e-4, 5e-4, (5, 3))
    batch = rk4_step(x0, u, 10.0, MU, substeps=3)
    for b in range(5):
        np.testing.assert_array_equal(batch[b], rk4_step(x0[b], u[b], 10.0, MU, substeps=3))


def test_rk4_converges_at_fourth_order(predictor):
    """Halving the step divides the error by ~16 (classical RK4)."""
    x0 = predictor.orbit.state(0.0)
    u = np.array([1e-4, -2e-4, 3e-4])
    ref = _reference(x0, [u], 600.0)[-1]
    e1 = np.linalg.norm(rk4_step(x0, u, 600.0, MU, substeps=10)[:3] - ref[:3])
    e2 = np.linalg.norm(rk4_step(x0, u, 600.0, MU, substeps=20)[:3] - ref[:3])
    assert 12.0 < e1 / e2 < 20.0


def test_plant_methods_agree(predictor):
    x = predictor.orbit.state(-10.0)
    fine, adaptive = Plant(MU, 10, "rk4"), Plant(MU, method="dop853")
    xa, xb = x.copy(), x.copy()
    for k in range(30):
        u = np.array([2e-4, -1e-4, 5e-5]) * np.cos(k)
        xa, xb = fine.step(xa, u, 10.0), adaptive.step(xb, u, 10.0)
    assert np.linalg.norm(xa[:3] - xb[:3]) < 1e-7


def test_unknown_plant_method_is_rejected():
    with pytest.raises(ConfigError, match="euler"):
        Plant(MU, method="euler")
