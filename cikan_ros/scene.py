"""The rendezvous as a scene in the chief's LVLH frame (pure numpy): relative states, the
line-of-sight cone, the docking port, the approach-velocity sphere, the virtual target.

LVLH (:func:`cikan_ros.orbit.lvlh_frame`): x radial, y along-track, z orbit normal, origin at the
chief's centre, which is the docking port and the cone's apex (SPEC §4: p_rel is measured from
the chief's centre; h1 is not evaluated within ``constraints.los_apex_radius_km`` of it). The
cone's axis is the port's: side * v_c (behind: -v_c, ahead: +v_c), so on an elliptic orbit it
turns in LVLH with the flight-path angle. Units: km, km/s (the message side converts).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .config import Side
from .orbit import KeplerOrbit, lvlh_frame


def relative_lvlh(x_d: ArrayLike, x_c: ArrayLike) -> tuple[NDArray, NDArray]:
    """(position (..., 3) km, velocity (..., 3) km/s) of deputy x_d relative to chief x_c (..., 6)
    in the chief's LVLH frame; the velocity is the rate seen in the rotating frame,
    R (v_rel - w x p_rel) with the frame's rate w = (r_c x v_c) / |r_c|^2 (two-body)."""
    x_d = np.asarray(x_d, dtype=float)
    x_c = np.asarray(x_c, dtype=float)
    rot = lvlh_frame(x_c)
    p = x_d[..., :3] - x_c[..., :3]
    v = x_d[..., 3:] - x_c[..., 3:]
    w = np.cross(x_c[..., :3], x_c[..., 3:]) / np.sum(x_c[..., :3] ** 2, axis=-1, keepdims=True)
    v = v - np.cross(w, p)
    return np.einsum("...ij,...j->...i", rot, p), np.einsum("...ij,...j->...i", rot, v)


def port_axis_lvlh(x_c: ArrayLike, side: Side) -> NDArray:
    """Unit axis (..., 3) of the docking port and the line-of-sight cone in LVLH: side * v_c/|v_c|
    (the deputy approaches along it, from ``side``)."""
    x_c = np.asarray(x_c, dtype=float)
    v = x_c[..., 3:] / np.linalg.norm(x_c[..., 3:], axis=-1, keepdims=True)
    return float(Side(side)) * np.einsum("...ij,...j->...i", lvlh_frame(x_c), v)


def _normal_pair(axis: NDArray) -> tuple[NDArray, NDArray]:
    """Two unit vectors completing ``axis`` (3,) to a right-handed orthonormal basis."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def cone_rim(axis: ArrayLike, half_angle_deg: float, length_km: float, n: int = 48) -> NDArray:
    """(n, 3) points of the cone's rim circle at ``length_km`` along ``axis`` (3,), apex at the
    origin (the port): every point sits at ``half_angle_deg`` from the axis (h1 = 0)."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    e1, e2 = _normal_pair(axis)
    phi = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    radius = length_km * math.tan(math.radians(half_angle_deg))
    return length_km * axis + radius * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)


def cone_triangles(axis: ArrayLike, half_angle_deg: float, length_km: float, n: int = 48) -> NDArray:
    """(3 n, 3) vertices of the cone's mantle as a triangle list (apex, rim i, rim i+1)."""
    rim = cone_rim(axis, half_angle_deg, length_km, n)
    nxt = np.roll(rim, -1, axis=0)
    tri = np.stack([np.zeros_like(rim), rim, nxt], axis=1)
    return tri.reshape(-1, 3)


def virtual_target_lvlh(orbit: KeplerOrbit, x_c: ArrayLike, t: float, tau: float) -> NDArray:
    """The virtual target x_c(t + tau) of the chief's ``orbit`` (the prediction model's; the
    controller steers to it) relative to the chief state x_c (6,) at t, in LVLH: (position km,
    velocity km/s) as one (6,) array."""
    p, v = relative_lvlh(orbit.state(t + tau), x_c)
    return np.concatenate([p, v])
