"""The telemetry dictionary: every quantity a viewer or a check plots or judges (the time shift,
the constraint margins, the thrust, the approach speed, the range, the relative state in LVLH),
with its unit, frame, limits and where it is published, generated from the configuration and the
topic table (:data:`cikan_ros.ros.graph_spec.TOPICS`) so every viewer and check reads units and
limits from one place; and the values themselves, computed from states with the constraint
kernels of :mod:`cikan_ros.constraints`.

Units: SI, as on every topic (m, m/s, m/s^2, s, deg); one unit per quantity (h3 in m/s). A margin
is within its limit when <= 0 (SPEC §4); a quantity with ``limit_key`` is judged against the
value of that other point at the same instant (the approach-speed limit shrinks with the range).
The values are published per control step on :data:`TELEMETRY_TOPIC` (sensor_msgs/JointState
used as a stamped list of named numbers: ``name[i]`` is the key, ``position[i]`` the value, in
dictionary order) and shipped with each bag (:func:`to_json`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .config import Config, Side
from .constraints import (C_COS_ALPHA, C_GAMMA1, C_GAMMA2, C_GAMMA3, constraint_params, margins_kernel,
                          rel_norms_kernel)
from .ros.graph_spec import TELEMETRY, TIME_SHIFT, TOPICS
from .scene import relative_lvlh_kernel
from .units import KM

#: The document format written by :func:`to_json` and read by :func:`from_json`.
FORMAT = "cikan-telemetry"
VERSION = 1
#: The topic the per-step values go out on.
TELEMETRY_TOPIC = TELEMETRY
#: How many values a step has (the points of :func:`dictionary`).
N_VALUES = 15
#: The frame of relative positions and velocities (the chief's LVLH, :mod:`cikan_ros.scene`).
FRAME_LVLH = "lvlh"


@dataclass(frozen=True)
class TelemetryPoint:
    """One telemetry quantity. ``unit``: SI symbol ("1" dimensionless); ``frame``: "" for a scalar;
    ``topic``/``field``: where its value is published (a message path in that topic's message);
    ``limit_low``/``limit_high``: the bounds it must stay within (None: no bound on that side);
    ``limit_key``: the key of another point holding a limit that varies in time; ``goal_high``:
    the docking test's bound (the mission docks once it is below; not a limit)."""

    key: str
    name: str
    type: str
    unit: str
    frame: str
    topic: str | None
    field: str | None
    limit_low: float | None
    limit_high: float | None
    description: str
    limit_key: str | None = None
    goal_high: float | None = None


def _tau_limits(side: Side) -> tuple[float | None, float | None]:
    """tau <= 0 behind, >= 0 ahead (the shift's sign is the side's)."""
    return (None, 0.0) if side == Side.BEHIND else (0.0, None)


def dictionary(cfg: Config) -> list[TelemetryPoint]:
    """The telemetry points of a mission flown with ``cfg``, in the order of the telemetry
    topic's values (``field`` is ``position[i]``)."""
    c = cfg.constraints
    side = cfg.side
    axis = "-v_c" if side == Side.BEHIND else "+v_c"
    tau_lo, tau_hi = _tau_limits(side)
    u_lim = cfg.thrust_limit_kmps2 * KM
    g1_m = c.gamma1_km * KM
    rows: list[tuple[Any, ...]] = [
        ("tau", "time shift τ", "s", "", tau_lo, tau_hi,
         f"the virtual target is the chief's orbit τ ahead in time (approach {side.approach}: τ "
         f"{'<= 0 rising' if side == Side.BEHIND else '>= 0 falling'} to 0 at docking); also "
         f"{TIME_SHIFT} as time_ref - header.stamp", {}),
        ("h1", "line-of-sight margin h1/(|v_c||p_rel|)", "1", "", None, 0.0,
         f"normalised h1 (SPEC §4): cos α - cos θ, θ the angle of p_rel from the port axis {axis}; "
         f"<= 0 inside the {c.los_half_angle_deg:g}° cone; not evaluated (NaN) within "
         f"{c.los_apex_radius_km * KM:g} m of the port; a violation is > {c.plant_h1_tolerance:g}", {}),
        ("los_angle", "angle from the port axis θ", "deg", "", 0.0, c.los_half_angle_deg,
         f"angle of p_rel from the port axis {axis}; the cone's half angle α is its limit", {}),
        ("h2", "thrust margin |u| - u_lim", "m/s^2", "", None, 0.0,
         f"applied thrust minus the limit on the truth ({u_lim:g} m/s^2: u_max "
         f"{cfg.control.u_max_kmps2 * KM:g} m/s^2 times 1 + the declared thrust-bias bound)", {}),
        ("thrust", "applied thrust |u|", "m/s^2", "", 0.0, u_lim,
         "magnitude of the acceleration the thrusters applied over [t_k, t_k+1) (ECI)", {}),
        ("h3", "approach-velocity margin h3", "m/s", "", None, 0.0,
         f"|v_rel| - γ2 |p_rel| - γ3 (γ2 = {c.gamma2_per_s:g} 1/s, γ3 = {c.gamma3_kmps * KM:g} m/s), "
         f"active within γ1 = {g1_m:g} m of the chief (NaN beyond); a violation is > "
         f"{c.plant_h3_tolerance_kmps * KM:g} m/s", {}),
        ("speed", "approach speed |v_rel|", "m/s", "", 0.0, None,
         f"relative speed (ECI difference, as h3 takes it); the docking test needs < "
         f"{cfg.mission.dock_speed_kmps * KM:g} m/s",
         {"limit_key": "speed_limit", "goal_high": cfg.mission.dock_speed_kmps * KM}),
        ("speed_limit", "approach-speed limit γ2 |p_rel| + γ3", "m/s", "", None, None,
         f"the limit of |v_rel| at the current range (h3 = 0), within γ1 = {g1_m:g} m (NaN beyond)", {}),
        ("range", "range to the chief (the docking port) |p_rel|", "m", "", 0.0, None,
         f"distance from the chief's centre, which is the docking port and the cone's apex; the "
         f"docking test needs < {cfg.mission.dock_distance_km * KM:g} m",
         {"goal_high": cfg.mission.dock_distance_km * KM}),
    ]
    for axis_name, what in (("x", "radial"), ("y", "along-track"), ("z", "orbit normal")):
        rows.append((f"p_{axis_name}", f"relative position {axis_name} ({what})", "m", FRAME_LVLH,
                     None, None, f"deputy minus chief, chief's LVLH axis {axis_name} ({what})", {}))
    for axis_name, what in (("x", "radial"), ("y", "along-track"), ("z", "orbit normal")):
        rows.append((f"v_{axis_name}", f"relative velocity {axis_name} ({what})", "m/s", FRAME_LVLH,
                     None, None, f"rate of the relative position in the rotating LVLH frame, axis "
                                 f"{axis_name} ({what})", {}))
    topic = TOPICS[TELEMETRY_TOPIC].name
    return [TelemetryPoint(key=key, name=name, type="float64", unit=unit, frame=frame, topic=topic,
                           field=f"position[{i}]", limit_low=lo, limit_high=hi,
                           description=desc, **extra)
            for i, (key, name, unit, frame, lo, hi, desc, extra) in enumerate(rows)]


def keys(cfg: Config) -> list[str]:
    """The keys of :func:`dictionary`, in order (the telemetry topic's ``name`` list)."""
    return [p.key for p in dictionary(cfg)]


@nb.njit(cache=True)
def values_kernel(x_c: NDArray, x_d: NDArray, u: NDArray, tau: NDArray, cp: NDArray, out: NDArray) -> None:
    """Row-wise (N, 6), (N, 6), (N, 3), (N,) -> out (N, len(dictionary)): :func:`values` compiled
    (the simulator calls it every step); the margins are :func:`margins_kernel`'s."""
    n = x_d.shape[0]
    m = np.empty((n, 4))
    margins_kernel(x_d, x_c, u, cp, m)
    rel = np.empty((n, 6))
    relative_lvlh_kernel(x_d, x_c, rel)
    for k in range(n):
        rng, speed = rel_norms_kernel(x_d[k], x_c[k])
        cos_theta = min(1.0, max(-1.0, cp[C_COS_ALPHA] - m[k, 1])) if m[k, 1] == m[k, 1] else math.nan
        limit = cp[C_GAMMA2] * rng + cp[C_GAMMA3] if rng <= cp[C_GAMMA1] else math.nan
        unorm = math.sqrt(u[k, 0] ** 2 + u[k, 1] ** 2 + u[k, 2] ** 2)
        row = (tau[k], m[k, 1], math.degrees(math.acos(cos_theta)), m[k, 2] * KM, unorm * KM,
               m[k, 3] * KM, speed * KM, limit * KM, rng * KM)
        for i in range(9):
            out[k, i] = row[i]
        for i in range(6):
            out[k, 9 + i] = rel[k, i] * KM


def values(cfg: Config, x_c: ArrayLike, x_d: ArrayLike, u: ArrayLike, tau: ArrayLike) -> NDArray:
    """The telemetry values (N, len(dictionary)) in dictionary order and units, of chief states
    x_c (N, 6), deputy states x_d (N, 6) (km, km/s, ECI), applied accelerations u (N, 3) (km/s^2)
    and shifts tau (N,) (s); NaN where a constraint is not evaluated. The margins are those of
    :func:`cikan_ros.constraints.margins`, h2 against the thrust limit on the truth."""
    x_d = np.ascontiguousarray(np.atleast_2d(np.asarray(x_d, dtype=float)))
    x_c = np.ascontiguousarray(np.broadcast_to(np.atleast_2d(np.asarray(x_c, dtype=float)), x_d.shape))
    u = np.ascontiguousarray(np.broadcast_to(np.atleast_2d(np.asarray(u, dtype=float)), x_d.shape[:-1] + (3,)))
    tau = np.ascontiguousarray(np.broadcast_to(np.asarray(tau, dtype=float), x_d.shape[:1]))
    out = np.empty((x_d.shape[0], N_VALUES))
    values_kernel(x_c, x_d, u, tau, constraint_params(cfg.constraints, cfg.thrust_limit_kmps2, cfg.side), out)
    return out


# -- the document --------------------------------------------------------------------------------
def to_json(points: list[TelemetryPoint], cfg: Config | None = None) -> dict[str, Any]:
    """The versioned document of a dictionary (strict JSON: no NaN), with the configuration facts
    a viewer needs when ``cfg`` is given: scenario, side, cone half angle, docking test, γ1."""
    doc: dict[str, Any] = {"format": FORMAT, "version": VERSION,
                           "points": [asdict(p) for p in points]}
    if cfg is not None:
        doc["config"] = {
            "scenario": cfg.scenario.name, "side": cfg.side.approach, "frame": FRAME_LVLH,
            "los_half_angle_deg": cfg.constraints.los_half_angle_deg,
            "los_apex_radius_m": cfg.constraints.los_apex_radius_km * KM,
            "approach_sphere_radius_m": cfg.constraints.gamma1_km * KM,
            "thrust_limit_mps2": cfg.thrust_limit_kmps2 * KM,
            "dock_distance_m": cfg.mission.dock_distance_km * KM,
            "dock_speed_mps": cfg.mission.dock_speed_kmps * KM,
            "control_period_s": cfg.control.period_s, "duration_s": cfg.mission.duration_s,
        }
    return doc


def from_json(doc: dict[str, Any]) -> list[TelemetryPoint]:
    """The points of a document written by :func:`to_json`; ValueError for another format or a
    newer version."""
    if doc.get("format") != FORMAT:
        raise ValueError(f"not a telemetry dictionary: format {doc.get('format')!r}, expected {FORMAT!r}")
    if not isinstance(doc.get("version"), int) or doc["version"] > VERSION:
        raise ValueError(f"telemetry dictionary version {doc.get('version')!r} is not supported "
                         f"(this reader knows up to {VERSION})")
    known = {f.name for f in fields(TelemetryPoint)}
    return [TelemetryPoint(**{k: v for k, v in p.items() if k in known}) for p in doc["points"]]
