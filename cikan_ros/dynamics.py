"""Two-body dynamics with a thrust acceleration, its linearisation, and the integrators.

State x = [r; v] (km, km/s, ECI); u is an acceleration (km/s^2, ECI) held constant over a step
(zero-order hold). ``rk4_kernel`` is the one integrator of predictions and of the plant; the
plant may instead use scipy's adaptive DOP853 (:class:`Plant`, method ``"dop853"``).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import solve_ivp

from .errors import ConfigError


def two_body_rhs(x: NDArray, u: NDArray, mu: float) -> NDArray:
    """dx/dt = [v; -mu r/|r|^3 + u] for state(s) (..., 6) and acceleration(s) (..., 3)."""
    r = x[..., :3]
    rn = np.linalg.norm(r, axis=-1, keepdims=True)
    return np.concatenate([x[..., 3:], -mu * r / rn**3 + u], axis=-1)


def linearisation(r: ArrayLike, mu: float) -> NDArray:
    """A = [[0, I], [G, 0]] with G = (mu/rho^3)(3 r r^T/rho^2 - I): the Jacobian of two_body_rhs at r."""
    r = np.asarray(r, dtype=float)
    rho = float(np.linalg.norm(r))
    g = (mu / rho**3) * (3.0 * np.outer(r, r) / rho**2 - np.eye(3))
    a = np.zeros((6, 6))
    a[:3, 3:] = np.eye(3)
    a[3:, :3] = g
    return a


@nb.njit(cache=True, inline="always")
def _deriv(x: NDArray, u: NDArray, mu: float, out: NDArray) -> None:
    r2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2]
    k = -mu / (r2 * math.sqrt(r2))
    for i in range(3):
        out[i] = x[3 + i]
        out[3 + i] = k * x[i] + u[i]


@nb.njit(cache=True)
def rk4_kernel(x: NDArray, u: NDArray, dt: float, substeps: int, mu: float, out: NDArray) -> None:
    """Classical RK4 over ``dt`` in ``substeps`` equal steps with u held constant; writes ``out``.

    ``out`` may alias ``x``.
    """
    h = dt / substeps
    y = x.copy()
    k1 = np.empty(6)
    k2 = np.empty(6)
    k3 = np.empty(6)
    k4 = np.empty(6)
    tmp = np.empty(6)
    for _ in range(substeps):
        _deriv(y, u, mu, k1)
        for i in range(6):
            tmp[i] = y[i] + 0.5 * h * k1[i]
        _deriv(tmp, u, mu, k2)
        for i in range(6):
            tmp[i] = y[i] + 0.5 * h * k2[i]
        _deriv(tmp, u, mu, k3)
        for i in range(6):
            tmp[i] = y[i] + h * k3[i]
        _deriv(tmp, u, mu, k4)
        for i in range(6):
            y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    for i in range(6):
        out[i] = y[i]


@nb.njit(cache=True)
def rk4_batch_kernel(x: NDArray, u: NDArray, dt: float, substeps: int, mu: float, out: NDArray) -> None:
    """:func:`rk4_kernel` for a batch: x (B, 6), u (B, 3) -> out (B, 6)."""
    for b in range(x.shape[0]):
        rk4_kernel(x[b], u[b], dt, substeps, mu, out[b])


def rk4_step(x: ArrayLike, u: ArrayLike, dt: float, mu: float, substeps: int = 1) -> NDArray:
    """One ZOH step of RK4 for one state (6,) or a batch of trajectories (B, 6) with u (B, 3)."""
    x = np.ascontiguousarray(x, dtype=float)
    u = np.ascontiguousarray(np.broadcast_to(np.asarray(u, dtype=float), x.shape[:-1] + (3,)))
    out = np.empty_like(x)
    if x.ndim == 1:
        rk4_kernel(x, u, float(dt), int(substeps), float(mu), out)
    else:
        rk4_batch_kernel(x.reshape(-1, 6), u.reshape(-1, 3), float(dt), int(substeps), float(mu),
                         out.reshape(-1, 6))
    return out


def dop853_step(x: ArrayLike, u: ArrayLike, dt: float, mu: float,
                rtol: float = 1e-10, atol: float = 1e-10) -> NDArray:
    """One ZOH step with scipy's adaptive DOP853 (the reference integrator)."""
    u = np.asarray(u, dtype=float)
    sol = solve_ivp(lambda _t, y: two_body_rhs(y, u, mu), (0.0, float(dt)), np.asarray(x, dtype=float),
                    method="DOP853", rtol=rtol, atol=atol)
    return sol.y[:, -1]


class Plant:
    """The simulator's deputy integrator: RK4 with fine substeps (default) or adaptive DOP853.

    RK4 at 1-s steps on this orbit has a local error far below a micrometre (the step is 1e-3 of
    the fastest orbital time scale at periapsis); DOP853 (rtol = atol = 1e-10) is there for users
    who want an adaptive reference at ~100x the cost.
    """

    METHODS = ("rk4", "dop853")

    def __init__(self, mu: float, substeps: int = 10, method: str = "rk4") -> None:
        if method not in self.METHODS:
            raise ConfigError(f"invalid plant integrator {method!r}: choose one of {self.METHODS}")
        self.mu = mu
        self.substeps = substeps
        self.method = method

    def step(self, x: NDArray, u: NDArray, dt: float) -> NDArray:
        """Deputy state after dt seconds with the acceleration u (km/s^2) held constant."""
        if self.method == "rk4":
            return rk4_step(x, u, dt, self.mu, self.substeps)
        return dop853_step(x, u, dt, self.mu)
