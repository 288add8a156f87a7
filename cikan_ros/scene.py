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
from dataclasses import dataclass

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .config import Config, Side
from .orbit import KeplerOrbit, lvlh_frame


@nb.njit(cache=True)
def relative_lvlh_kernel(x_d: NDArray, x_c: NDArray, out: NDArray) -> None:
    """Row-wise (N, 6), (N, 6) -> out (N, 6): :func:`relative_lvlh` compiled (the simulator calls
    it every step)."""
    for k in range(x_d.shape[0]):
        r = x_c[k, :3]
        v = x_c[k, 3:]
        rn = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        h = np.cross(r, v)
        hn = math.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2])
        xh = r / rn
        zh = h / hn
        yh = np.cross(zh, xh)
        p = x_d[k, :3] - r
        w = h / (rn * rn)
        dv = x_d[k, 3:] - v - np.cross(w, p)
        for i, e in enumerate((xh, yh, zh)):
            out[k, i] = e[0] * p[0] + e[1] * p[1] + e[2] * p[2]
            out[k, 3 + i] = e[0] * dv[0] + e[1] * dv[1] + e[2] * dv[2]


def relative_lvlh(x_d: ArrayLike, x_c: ArrayLike) -> tuple[NDArray, NDArray]:
    """(position (N, 3) km, velocity (N, 3) km/s) of deputy x_d relative to chief x_c (N, 6) or
    (6,) in the chief's LVLH frame (:func:`cikan_ros.orbit.lvlh_frame`); the velocity is the rate
    seen in the rotating frame, R (v_rel - w x p_rel) with the frame's rate w = (r_c x v_c) /
    |r_c|^2 (two-body)."""
    x_d = np.ascontiguousarray(np.atleast_2d(x_d), dtype=float)
    x_c = np.ascontiguousarray(np.broadcast_to(np.atleast_2d(np.asarray(x_c, dtype=float)), x_d.shape))
    out = np.empty(x_d.shape)
    relative_lvlh_kernel(x_d, x_c, out)
    return out[:, :3], out[:, 3:]


@nb.njit(cache=True)
def port_axis_kernel(x_c: NDArray, side: float, out: NDArray) -> None:
    """Row-wise (N, 6) -> out (N, 3): :func:`port_axis_lvlh` compiled."""
    for k in range(x_c.shape[0]):
        r = x_c[k, :3]
        v = x_c[k, 3:]
        rv = math.sqrt(r @ r) * math.sqrt(v @ v)
        h = np.cross(r, v)
        # R v = (r.v/|r|, |r x v|/|r|, 0): v has no orbit-normal part
        out[k, 0] = side * (r @ v) / rv
        out[k, 1] = side * math.sqrt(h @ h) / rv
        out[k, 2] = 0.0


def port_axis_lvlh(x_c: ArrayLike, side: Side) -> NDArray:
    """Unit axis (N, 3) of the docking port and the line-of-sight cone in LVLH, for chief states
    (N, 6) or (6,): side * v_c/|v_c| (the deputy approaches along it, from ``side``)."""
    x_c = np.ascontiguousarray(np.atleast_2d(x_c), dtype=float)
    out = np.empty((x_c.shape[0], 3))
    port_axis_kernel(x_c, float(Side(side)), out)
    return out


def _normal_pair(axis: NDArray) -> tuple[NDArray, NDArray]:
    """Two unit vectors completing ``axis`` (3,) to a right-handed orthonormal basis."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def cone_rim(axis: ArrayLike, half_angle_deg: float, length_km: float, n: int = 32) -> NDArray:
    """(n, 3) points of the cone's rim circle at ``length_km`` along ``axis`` (3,), apex at the
    origin (the port): every point sits at ``half_angle_deg`` from the axis (h1 = 0)."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    e1, e2 = _normal_pair(axis)
    phi = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    radius = length_km * math.tan(math.radians(half_angle_deg))
    return length_km * axis + radius * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)


def cone_triangles(axis: ArrayLike, half_angle_deg: float, length_km: float, n: int = 32) -> NDArray:
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
    return np.concatenate([p[0], v[0]])


# -- the scene as shapes (the markers; :func:`cikan_ros.ros.convert.markers_msg` makes messages) --
#: RGBA colours of the shapes.
COLORS = {"deputy": (0.2, 0.5, 1.0, 1.0), "target": (1.0, 0.55, 0.0, 1.0), "path": (0.6, 0.75, 1.0, 1.0),
          "cone": (0.2, 0.9, 0.3, 0.25), "port": (1.0, 0.2, 0.2, 1.0), "sphere": (1.0, 0.9, 0.2, 0.15)}


@dataclass(frozen=True)
class Shape:
    """One marker in LVLH (km): ``kind`` sphere (``points`` (1, 3) its centre, ``size`` its
    diameter), sphere_list (a sphere of diameter ``size`` at each point, coloured by ``colors``),
    line_strip (``size`` the line width), triangle_list, or arrow (two points: tail and head;
    ``size`` the shaft diameter). ``ns``/``ident`` name it: a newer shape of the same name replaces
    it in a viewer."""

    ns: str
    ident: int
    kind: str
    points: NDArray
    size: float
    color: tuple[float, float, float, float]
    colors: tuple[tuple[float, float, float, float], ...] = ()


class SceneBuilder:
    """The shapes of a mission's scene, step by step, with little work per step: the deputy and
    the virtual target every step; the path so far (one point every ``path_every`` steps plus the
    current one) every ``path_every`` steps; the cone, the port and the approach-velocity sphere
    at the first step and again when the port axis has turned by ``turn_deg`` in LVLH."""

    def __init__(self, cfg: Config, path_every: int, turn_deg: float = 1.0) -> None:
        c = cfg.constraints
        self.half_angle_deg = c.los_half_angle_deg
        #: The cone is drawn out to 1.2 x the nominal start distance (or gamma1, if larger).
        self.cone_length_km = 1.2 * max(cfg.mission.nominal_distance_km, c.gamma1_km)
        self.sphere_radius_km = c.gamma1_km
        self.path_every = max(1, int(path_every))
        self.cos_turn = math.cos(math.radians(turn_deg))
        self.axis: NDArray | None = None
        self.path: list[NDArray] = []

    def constraints(self, axis: NDArray, force: bool = False) -> list[Shape] | None:
        """Cone, port and sphere about the port ``axis`` (LVLH, :func:`port_axis_lvlh` of the chief
        now), when first asked, when ``force``d or when the axis has turned (else None)."""
        if not force and self.axis is not None and float(axis @ self.axis) >= self.cos_turn:
            return None
        self.axis = np.array(axis, dtype=float)  # a copy: the caller may reuse its buffer
        port_len = 0.05 * self.cone_length_km
        origin = np.zeros((1, 3))
        return [Shape("cone", 0, "triangle_list", cone_triangles(axis, self.half_angle_deg, self.cone_length_km),
                      1.0, COLORS["cone"]),
                Shape("port", 0, "arrow", np.stack([axis * port_len, np.zeros(3)]), 0.1 * port_len,
                      COLORS["port"]),
                Shape("approach_sphere", 0, "sphere", origin, 2.0 * self.sphere_radius_km, COLORS["sphere"])]

    def moving(self, p_d: ArrayLike, p_v: ArrayLike | None) -> list[Shape]:
        """The deputy at p_d and the virtual target at p_v (LVLH, km; None: no shift yet) as one
        sphere list (deputy first; one marker serialises in a third of the time of two), sized
        2 % of the range (at least 1 m) so both show at 100 km and at the port."""
        p_d = np.asarray(p_d, dtype=float)
        size = max(0.02 * math.sqrt(p_d @ p_d), 1e-3)   # |p_d|, as numpy's norm computes it
        if p_v is None:
            return [Shape("bodies", 0, "sphere_list", p_d[None, :], size, COLORS["deputy"], (COLORS["deputy"],))]
        return [Shape("bodies", 0, "sphere_list", np.array([p_d, p_v], dtype=float), size,
                      COLORS["deputy"], (COLORS["deputy"], COLORS["target"]))]

    def trail(self, k: int, p_d: ArrayLike, last: bool = False) -> Shape | None:
        """The path so far as a line strip at every ``path_every``-th step k (and at the ``last``),
        else None; keeps one point per ``path_every`` steps."""
        p_d = np.asarray(p_d, dtype=float)
        due = k % self.path_every == 0
        if due:
            self.path.append(p_d)
        if not (due or last):
            return None
        pts = np.array(self.path if due else [*self.path, p_d])
        width = max(2e-3 * float(np.max(np.linalg.norm(pts, axis=1))), 1e-4)
        return Shape("path", 0, "line_strip", pts, width, COLORS["path"])
