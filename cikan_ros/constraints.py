"""Constraints of the rendezvous (SPEC §4); each h <= 0 is feasible, h > 0 a violation.

- h1, line of sight: the deputy stays in the cone of half-angle alpha around the docking port's
  axis. Approaching from behind (the paper's), the port points against the chief's velocity:
  h1 = v_c^T p_rel + cos(alpha) |v_c| |p_rel| (the paper prints the opposite sign; it contradicts
  its own docking-port statement). Approaching from ahead it points along v_c:
  h1 = -v_c^T p_rel + cos(alpha) |v_c| |p_rel|. One kernel: h1 = a v_c^T p_rel + ..., with the
  port sign a = -side (:class:`~cikan_ros.config.Side`: -1 behind, +1 ahead; every caller passes
  the mission's side, ``Config.side``).
- h2, thrust: |u| - u_max.
- h3, approach velocity, active when |p_rel| <= gamma1: h3 = |v_rel| - gamma2 |p_rel| - gamma3.

p_rel, v_rel are deputy minus the REAL chief at the same instant, and v_c is the real chief's
velocity. A constraint that is not evaluated (h1 within the apex radius, h3 beyond gamma1)
returns NaN, which compares False with every threshold. Units: km, km/s, km/s^2.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .config import ConstraintConfig, Side

# Layout of the packed constraint parameters used by compiled kernels.
C_COS_ALPHA, C_APEX, C_GAMMA1, C_GAMMA2, C_GAMMA3, C_UMAX, C_PORT = range(7)


def constraint_params(cfg: ConstraintConfig, u_max: float, side: Side) -> NDArray:
    """Pack the constraint parameters for the kernels (layout ``C_*``); the approach ``side``
    points the docking port (C_PORT = -side). ValueError unless side is -1 or +1."""
    port = -float(Side(side))
    return np.array([math.cos(math.radians(cfg.los_half_angle_deg)), cfg.los_apex_radius_km,
                     cfg.gamma1_km, cfg.gamma2_per_s, cfg.gamma3_kmps, u_max, port])


@nb.njit(cache=True, error_model="numpy", inline="always")
def los_terms_kernel(x_d: NDArray, x_c: NDArray, port: float) -> tuple[float, float, float]:
    """(port v_c . p_rel, |p_rel|, |v_c|) of deputy x_d and chief x_c (6,), port sign ``port``
    (+1: the port faces -v_c, -1: +v_c): what h1 is made of."""
    dot = 0.0
    p2 = 0.0
    vc2 = 0.0
    for i in range(3):
        p = x_d[i] - x_c[i]
        dot += x_c[3 + i] * p
        p2 += p * p
        vc2 += x_c[3 + i] * x_c[3 + i]
    return port * dot, math.sqrt(p2), math.sqrt(vc2)


@nb.njit(cache=True, error_model="numpy")
def h1_line_of_sight_kernel(x_d: NDArray, x_c: NDArray, cp: NDArray) -> float:
    """h1 (km^2/s) of deputy x_d and chief x_c (6,); NaN within the apex radius."""
    dot, pn, vn = los_terms_kernel(x_d, x_c, cp[C_PORT])
    if pn <= cp[C_APEX]:
        return math.nan
    return dot + cp[C_COS_ALPHA] * vn * pn


@nb.njit(cache=True, error_model="numpy", inline="always")
def rel_norms_kernel(x_d: NDArray, x_c: NDArray) -> tuple[float, float]:
    """(|p_rel|, |v_rel|) of deputy x_d and chief x_c (6,): what h3 is made of."""
    p2 = 0.0
    v2 = 0.0
    for i in range(3):
        p = x_d[i] - x_c[i]
        v = x_d[3 + i] - x_c[3 + i]
        p2 += p * p
        v2 += v * v
    return math.sqrt(p2), math.sqrt(v2)


@nb.njit(cache=True, error_model="numpy")
def h3_approach_velocity_kernel(x_d: NDArray, x_c: NDArray, cp: NDArray) -> float:
    """h3 (km/s) of deputy x_d and chief x_c (6,); NaN when |p_rel| > gamma1."""
    pn, vn = rel_norms_kernel(x_d, x_c)
    if pn > cp[C_GAMMA1]:
        return math.nan
    return vn - cp[C_GAMMA2] * pn - cp[C_GAMMA3]


@nb.njit(cache=True, error_model="numpy")
def h2_thrust_kernel(u: NDArray, cp: NDArray) -> float:
    """h2 = |u| - u_max (km/s^2)."""
    return math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]) - cp[C_UMAX]


@nb.njit(cache=True, error_model="numpy")
def margins_kernel(x_d: NDArray, x_c: NDArray, u: NDArray, cp: NDArray, out: NDArray) -> None:
    """Row-wise (N, 6), (N, 6), (N, 3) -> out (N, 4): h1, h1 normalised, h2, h3."""
    for k in range(x_d.shape[0]):
        h1 = h1_line_of_sight_kernel(x_d[k], x_c[k], cp)
        out[k, 0] = h1
        vc = math.sqrt(x_c[k, 3] ** 2 + x_c[k, 4] ** 2 + x_c[k, 5] ** 2)
        pr = math.sqrt((x_d[k, 0] - x_c[k, 0]) ** 2 + (x_d[k, 1] - x_c[k, 1]) ** 2
                       + (x_d[k, 2] - x_c[k, 2]) ** 2)
        out[k, 1] = h1 / (vc * pr) if pr > 0.0 else math.nan
        out[k, 2] = h2_thrust_kernel(u[k], cp)
        out[k, 3] = h3_approach_velocity_kernel(x_d[k], x_c[k], cp)


@nb.njit(cache=True, error_model="numpy")
def step_margins_kernel(x_d: NDArray, x_c: NDArray, u: NDArray, path: NDArray, chief_path: NDArray,
                        cp: NDArray, h1_tol: float, h3_tol: float, out: NDArray) -> int:
    """One control step of the truth in one call: ``out`` (4,) the margins of (x_d, x_c, u) as
    :func:`margins_kernel` (h1, h1 normalised, h2, h3), and the number of rows 1 .. S-1 of the
    substep paths (S + 1, 6) whose normalised h1 exceeds ``h1_tol`` or whose h3 exceeds ``h3_tol``
    (NaN, not evaluated, is not a violation)."""
    margins_kernel(x_d[None, :], x_c[None, :], u[None, :], cp, out[None, :])
    row = np.empty((1, 4))
    bad = 0
    for j in range(1, path.shape[0] - 1):
        margins_kernel(path[j:j + 1], chief_path[j:j + 1], u[None, :], cp, row)
        if row[0, 1] > h1_tol or row[0, 3] > h3_tol:
            bad += 1
    return bad


class Margins(NamedTuple):
    """Constraint values along a trajectory, each (N,): NaN where not evaluated."""

    h1: NDArray             # km^2/s
    h1_normalised: NDArray  # h1 / (|v_c| |p_rel|), in [cos a - 1, cos a + 1]
    h2: NDArray             # km/s^2
    h3: NDArray             # km/s


def margins(x_d: ArrayLike, x_c: ArrayLike, u: ArrayLike, cfg: ConstraintConfig, u_max: float,
            side: Side) -> Margins:
    """h1, normalised h1, h2, h3 for deputy states (N, 6), chief states (N, 6), accelerations
    (N, 3) of a mission approaching from ``side`` (the docking port's side in h1)."""
    x_d = np.ascontiguousarray(np.atleast_2d(x_d), dtype=float)
    x_c = np.ascontiguousarray(np.broadcast_to(np.atleast_2d(np.asarray(x_c, dtype=float)), x_d.shape))
    u = np.ascontiguousarray(np.broadcast_to(np.atleast_2d(np.asarray(u, dtype=float)), x_d.shape[:-1] + (3,)))
    out = np.empty((x_d.shape[0], 4))
    margins_kernel(x_d, x_c, u, constraint_params(cfg, u_max, side), out)
    return Margins(*out.T.copy())


def h1_line_of_sight(x_d: ArrayLike, x_c: ArrayLike, cfg: ConstraintConfig, side: Side) -> NDArray:
    """h1 (km^2/s) for states (N, 6), approach side ``side``; NaN within the apex radius."""
    return margins(x_d, x_c, np.zeros(3), cfg, 1.0, side).h1


def h3_approach_velocity(x_d: ArrayLike, x_c: ArrayLike, cfg: ConstraintConfig) -> NDArray:
    """h3 (km/s) for states (N, 6); NaN beyond gamma1. h3 does not depend on the approach side
    (either side packs the same gammas)."""
    return margins(x_d, x_c, np.zeros(3), cfg, 1.0, Side.BEHIND).h3


def h2_thrust(u: ArrayLike, u_max: float) -> NDArray:
    """h2 = |u| - u_max (km/s^2) for accelerations (N, 3)."""
    return np.linalg.norm(np.atleast_2d(np.asarray(u, dtype=float)), axis=-1) - u_max
