"""Parameters of the mission, read from ``config/*.yaml`` (ROS 2 params format).

The same file feeds the ROS nodes (as declared parameters named ``group.key``) and the offline
code, so both run on one set of values. Every value is validated on load; a bad one raises
:class:`ConfigError` naming it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field, fields
from enum import IntEnum
from pathlib import Path
from typing import Any, Mapping

import yaml

from .errors import ConfigError
from .paths import shipped

#: The default parameter file shipped with the package.
DEFAULT_CONFIG_PATH = shipped("config/cikan.yaml")


def _check(cond: bool, name: str, value: Any, what: str) -> None:
    if not cond:
        raise ConfigError(f"invalid configuration value {name} = {value!r}: {what}")


def _positive(name: str, value: float) -> None:
    _check(isinstance(value, (int, float)) and math.isfinite(value) and value > 0, name, value,
           "must be a finite number > 0")


@dataclass(frozen=True)
class OrbitConfig:
    """Chief orbit: classical elements (km, deg) and Earth's gravitational parameter."""

    mu_km3_s2: float = 398600.4418
    a_km: float = 26646.6808
    e: float = 0.74
    i_deg: float = 62.8
    raan_deg: float = 0.0
    argp_deg: float = 280.0
    nu0_deg: float = 0.0
    epoch_utc: str = "2025-01-01T00:00:00Z"

    def __post_init__(self) -> None:
        _positive("orbit.mu_km3_s2", self.mu_km3_s2)
        _positive("orbit.a_km", self.a_km)
        _check(0.0 <= self.e < 1.0, "orbit.e", self.e, "the chief orbit must be elliptic (0 <= e < 1)")
        _check(self.a_km * (1.0 - self.e) > 6378.137, "orbit.a_km", self.a_km,
               f"periapsis radius a(1-e) = {self.a_km * (1 - self.e):.1f} km is inside the Earth")
        for name in ("i_deg", "raan_deg", "argp_deg", "nu0_deg"):
            v = getattr(self, name)
            _check(math.isfinite(v), f"orbit.{name}", v, "must be finite")
        _check(0.0 <= self.i_deg <= 180.0, "orbit.i_deg", self.i_deg, "must lie in [0, 180]")
        from datetime import datetime

        try:
            datetime.fromisoformat(self.epoch_utc.replace("Z", "+00:00"))
        except (ValueError, AttributeError):
            _check(False, "orbit.epoch_utc", self.epoch_utc, "must be an ISO 8601 UTC time")

    @property
    def epoch_unix_s(self) -> float:
        """The mission epoch as seconds since 1970-01-01 UTC."""
        from datetime import datetime, timezone

        dt = datetime.fromisoformat(self.epoch_utc.replace("Z", "+00:00"))
        if dt.tzinfo is None:
            dt = dt.replace(tzinfo=timezone.utc)
        return dt.timestamp()


@dataclass(frozen=True)
class ControlConfig:
    """Frozen-time Riccati (FTRE) controller: ZOH period, LQ weights, gain grid, thrust limit."""

    period_s: float = 10.0
    q_diag: tuple[float, ...] = (10.0, 10.0, 10.0, 1.0, 1.0, 1.0)
    r_diag: tuple[float, ...] = (1.0, 1.0, 1.0)
    robust_r_diag: tuple[float, ...] = (1e7, 1e7, 1e7)
    grid_deg: float = 0.5
    u_max_kmps2: float = 5e-4

    def __post_init__(self) -> None:
        _positive("control.period_s", self.period_s)
        object.__setattr__(self, "q_diag", tuple(float(q) for q in self.q_diag))
        object.__setattr__(self, "r_diag", tuple(float(r) for r in self.r_diag))
        object.__setattr__(self, "robust_r_diag", tuple(float(r) for r in self.robust_r_diag))
        _check(len(self.q_diag) == 6 and all(math.isfinite(q) and q >= 0 for q in self.q_diag)
               and any(q > 0 for q in self.q_diag), "control.q_diag", self.q_diag,
               "must be 6 finite weights >= 0, not all zero")
        _check(len(self.r_diag) == 3 and all(math.isfinite(r) and r > 0 for r in self.r_diag),
               "control.r_diag", self.r_diag, "must be 3 finite weights > 0")
        _check(len(self.robust_r_diag) == 3 and all(math.isfinite(r) and r > 0 for r in self.robust_r_diag),
               "control.robust_r_diag", self.robust_r_diag, "must be 3 finite weights > 0")
        _positive("control.grid_deg", self.grid_deg)
        n = 360.0 / self.grid_deg
        _check(abs(n - round(n)) < 1e-9 and round(n) >= 4, "control.grid_deg", self.grid_deg,
               "must divide 360 degrees into at least 4 cells")
        _positive("control.u_max_kmps2", self.u_max_kmps2)


@dataclass(frozen=True)
class ConstraintConfig:
    """Line-of-sight cone (h1), thrust (h2) and approach-velocity (h3) constraint parameters."""

    los_half_angle_deg: float = 20.0
    los_apex_radius_km: float = 1e-3
    gamma1_km: float = 5.0
    gamma2_per_s: float = 20.0
    gamma3_kmps: float = 1e-3
    plant_h1_tolerance: float = 1e-9
    plant_h3_tolerance_kmps: float = 1e-9

    def __post_init__(self) -> None:
        _check(0.0 < self.los_half_angle_deg < 90.0, "constraints.los_half_angle_deg",
               self.los_half_angle_deg, "must lie in (0, 90) degrees")
        _check(math.isfinite(self.los_apex_radius_km) and self.los_apex_radius_km >= 0,
               "constraints.los_apex_radius_km", self.los_apex_radius_km, "must be >= 0")
        _positive("constraints.gamma1_km", self.gamma1_km)
        for name in ("gamma2_per_s", "gamma3_kmps", "plant_h1_tolerance", "plant_h3_tolerance_kmps"):
            v = getattr(self, name)
            _check(math.isfinite(v) and v >= 0, f"constraints.{name}", v, "must be finite and >= 0")


@dataclass(frozen=True)
class TSGConfig:
    """Time Shift Governor: prediction (Verify), search and update schedule."""

    sample_period_s: float = 10.0
    horizon_s: float = 0.0
    rk4_substeps: int = 2
    terminal_pos_km: float = 1e-3
    terminal_vel_kmps: float = 1e-4
    tolerance_s: float = 1e-5
    initial_window_s: float = 600.0
    initial_grid_s: float = 1.0
    update_period_s: float = 60.0
    zero_snap_s: float = 1e-2
    robust: bool = False
    robust_zeta_s: float = 0.0
    chief_anchor_tolerance_km: float = 1e-6
    prediction_gravity: str = "auto"
    #: Robust Verify's tube (docs/robustness.md, "The ancillary tube"): "ball", the FTRE truth
    #: bounded around the prediction; "ancillary", the truth tracks the accepted prediction
    #: (flown at ``ancillary_gamma`` u_max) with the linear gain of LQ weight
    #: ``ancillary_r_diag``, which must never saturate. Read only under ``tsg.robust``.
    tube: str = "ancillary"
    ancillary_gamma: float = 0.5
    ancillary_r_diag: tuple[float, ...] = (1e10, 1e10, 1e10)
    #: LQ control weight of the FTRE law the ancillary tube hands the truth to at the terminal
    #: sample (docs/robustness.md, "Docking, certified"): stiffer than the robust controller, so
    #: the ball it certifies at the chief fits the docking test.
    ancillary_handoff_r_diag: tuple[float, ...] = (1e5, 1e5, 1e5)
    #: The ancillary tube also bounds the truth between samples (docs/robustness.md, "Between
    #: samples, derived"); false: at the samples only, as the ball tube.
    ancillary_between: bool = True
    #: How the ancillary tube bounds a loop's response to a forcing bounded over many samples
    #: (docs/robustness.md, "The l1 bound"): "geometric", the lam-weighted constants alone
    #: (C / (1 - lam)); "l1", also the l1 norms of the loops' impulse responses for the forcing's
    #: constant part and the terminal balls, and the tracking handoff continuing the plan's
    #: recursions.
    ancillary_bound: str = "geometric"
    #: The ancillary tube's gain schedule (docs/robustness.md, "Gains by range"): a plan that
    #: starts at a measured range of at least ``ancillary_bands_km[i]`` (km, ascending) tracks
    #: with the LQ weight ``ancillary_bands_r[i]`` I; nearer, ``ancillary_r_diag``. Each plan
    #: keeps its gain, so each tube is that of one linear loop. Empty: one gain.
    ancillary_bands_km: tuple[float, ...] = ()
    ancillary_bands_r: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        _check(isinstance(self.robust, bool), "tsg.robust", self.robust, "must be true or false")
        _check(math.isfinite(self.robust_zeta_s) and 0.0 <= self.robust_zeta_s <= 60.0,
               "tsg.robust_zeta_s", self.robust_zeta_s, "must lie in [0, 60] s")
        _check(math.isfinite(self.chief_anchor_tolerance_km) and self.chief_anchor_tolerance_km >= 0,
               "tsg.chief_anchor_tolerance_km", self.chief_anchor_tolerance_km, "must be finite and >= 0")
        _check(self.prediction_gravity in ("auto",) + GRAVITY_MODELS, "tsg.prediction_gravity",
               self.prediction_gravity, f"must be one of {('auto',) + GRAVITY_MODELS}")
        _check(self.tube in ("ball", "ancillary"), "tsg.tube", self.tube, "must be 'ball' or 'ancillary'")
        _check(isinstance(self.ancillary_between, bool), "tsg.ancillary_between", self.ancillary_between,
               "must be true or false")
        _check(self.ancillary_bound in ANCILLARY_BOUNDS, "tsg.ancillary_bound", self.ancillary_bound,
               f"must be one of {ANCILLARY_BOUNDS}")
        _check(math.isfinite(self.ancillary_gamma) and 0.0 < self.ancillary_gamma <= 1.0,
               "tsg.ancillary_gamma", self.ancillary_gamma, "must lie in (0, 1]")
        object.__setattr__(self, "ancillary_r_diag", tuple(float(r) for r in self.ancillary_r_diag))
        _check(len(self.ancillary_r_diag) == 3 and all(math.isfinite(r) and r > 0 for r in self.ancillary_r_diag),
               "tsg.ancillary_r_diag", self.ancillary_r_diag, "must be 3 finite weights > 0")
        object.__setattr__(self, "ancillary_handoff_r_diag", tuple(float(r) for r in self.ancillary_handoff_r_diag))
        _check(len(self.ancillary_handoff_r_diag) == 3
               and all(math.isfinite(r) and r > 0 for r in self.ancillary_handoff_r_diag),
               "tsg.ancillary_handoff_r_diag", self.ancillary_handoff_r_diag, "must be 3 finite weights > 0")
        object.__setattr__(self, "ancillary_bands_km", tuple(float(r) for r in self.ancillary_bands_km))
        object.__setattr__(self, "ancillary_bands_r", tuple(float(r) for r in self.ancillary_bands_r))
        km, rs = self.ancillary_bands_km, self.ancillary_bands_r
        _check(all(math.isfinite(r) and r > 0 for r in km) and all(a < b for a, b in zip(km, km[1:])),
               "tsg.ancillary_bands_km", km, "must be finite ranges > 0 km, ascending")
        _check(len(rs) == len(km) and all(math.isfinite(r) and r > 0 for r in rs), "tsg.ancillary_bands_r",
               rs, f"must be {len(km)} finite weights > 0, one per range of tsg.ancillary_bands_km")
        for name in ("sample_period_s", "terminal_pos_km", "terminal_vel_kmps", "tolerance_s",
                     "initial_window_s", "initial_grid_s", "update_period_s"):
            _positive(f"tsg.{name}", getattr(self, name))
        _check(math.isfinite(self.horizon_s) and self.horizon_s >= 0, "tsg.horizon_s",
               self.horizon_s, "must be >= 0 (0 means one chief orbital period)")
        _check(isinstance(self.rk4_substeps, int) and 1 <= self.rk4_substeps <= 1000,
               "tsg.rk4_substeps", self.rk4_substeps, "must be an integer in [1, 1000]")
        _check(self.tolerance_s >= 1e-9, "tsg.tolerance_s", self.tolerance_s,
               "must be at least 1e-9 s (shifts are whole nanoseconds)")
        _check(self.initial_grid_s <= self.initial_window_s, "tsg.initial_grid_s",
               self.initial_grid_s, "must not exceed tsg.initial_window_s")
        _check(math.isfinite(self.zero_snap_s) and self.zero_snap_s >= 0, "tsg.zero_snap_s",
               self.zero_snap_s, "must be >= 0")


class Side(IntEnum):
    """The side of the chief a deputy approaches from (``mission.approach``), valued as the sign
    of its time shifts: BEHIND = -1 (tau <= 0 rising to 0; the paper's), AHEAD = +1 (tau >= 0
    falling to 0). The docking port faces the approach: against the chief's velocity behind,
    along it ahead (the port's sign in h1 is -side). Built once per configuration
    (:attr:`Config.side`); compiled kernels take ``int(side)`` or ``float(side)``."""

    BEHIND = -1
    AHEAD = 1

    @classmethod
    def of(cls, approach: str) -> "Side":
        """The side named by a ``mission.approach`` value ("behind" or "ahead")."""
        return cls[approach.upper()]

    @property
    def approach(self) -> str:
        """The ``mission.approach`` value naming this side."""
        return self.name.lower()


#: The ``mission.approach`` values, one per :class:`Side`.
APPROACHES = tuple(side.approach for side in Side)


@dataclass(frozen=True)
class MissionConfig:
    """Closed-loop mission: duration, nominal start, Monte Carlo spread, plant, success test."""

    duration_s: float = 14400.0
    approach: str = "behind"
    nominal_distance_km: float = 100.0
    mc_sigma_km: float = 10.0
    plant_substeps: int = 10
    dock_distance_km: float = 1e-3
    dock_speed_kmps: float = 1e-6

    def __post_init__(self) -> None:
        for name in ("duration_s", "nominal_distance_km", "dock_distance_km", "dock_speed_kmps"):
            _positive(f"mission.{name}", getattr(self, name))
        _check(self.approach in APPROACHES, "mission.approach", self.approach,
               f"must be one of {APPROACHES} (the side of the chief the deputy starts on)")
        _check(math.isfinite(self.mc_sigma_km) and self.mc_sigma_km >= 0, "mission.mc_sigma_km",
               self.mc_sigma_km, "must be >= 0")
        _check(isinstance(self.plant_substeps, int) and 1 <= self.plant_substeps <= 10000,
               "mission.plant_substeps", self.plant_substeps, "must be an integer in [1, 10000]")


#: Gravity models of the truth and of the prediction: two-body, or two-body plus Earth's J2.
GRAVITY_MODELS = ("two-body", "j2")
#: How the ancillary tube bounds a loop's response to a lasting forcing (``tsg.ancillary_bound``).
ANCILLARY_BOUNDS = ("geometric", "l1")


#: Navigation error models of the truth: a rate-limited Gauss-Markov output ("realistic") or a
#: filter's output, constant between measurement updates and jumping at each ("filter").
NAV_MODELS = ("realistic", "filter")
#: How the truth's per-run errors are drawn: at random within the bounds, or pinned to a corner.
TRUTH_DRAWS = ("random", "corner")
#: Axes of the chief's VNB frame at the epoch that a corner's pointing error rotates about.
CORNER_AXES = ("along", "normal", "radial")
#: The navigation error's bounds: floors and range fractions (position, velocity).
NAV_BOUNDS = ("nav_pos_floor_km", "nav_pos_range_fraction", "nav_vel_floor_kmps",
              "nav_vel_range_fraction_per_s")


@dataclass(frozen=True)
class Corner:
    """A corner of the declared error bounds (docs/robustness.md, "Corners"): each sign is +1 or
    -1. ``bias``: b = bias b_max; ``axis``, ``rotation``: a rotation by rotation theta_max about
    that axis of the chief's VNB frame at the epoch; ``disturbance``: d = disturbance d_max along
    the chief's velocity; ``nav``: navigation error nav (b_p, b_v) along the line of sight from
    the chief to the deputy (+: away from the chief)."""

    bias: int
    axis: str
    rotation: int
    disturbance: int
    nav: int

    @property
    def name(self) -> str:
        """The corner's name, e.g. ``b+.normal-.d+.n-``."""
        def s(v: int) -> str:
            return "+" if v > 0 else "-"
        return f"b{s(self.bias)}.{self.axis}{s(self.rotation)}.d{s(self.disturbance)}.n{s(self.nav)}"


_CORNER_SYNTAX = ("must name a corner: b+ or b-, then " + ", ".join(CORNER_AXES)
                  + " with + or -, then d+ or d-, then n+ or n-, joined by '.' (e.g. b+.normal-.d+.n-)")


def parse_corner(name: str) -> Corner:
    """The :class:`Corner` of a name (``Corner.name``); ConfigError naming truth.corner."""
    parts = name.split(".") if isinstance(name, str) else []
    signs = {"+": 1, "-": -1}
    ok = (len(parts) == 4 and all(len(p) >= 2 and p[-1] in signs for p in parts)
          and parts[0][:-1] == "b" and parts[1][:-1] in CORNER_AXES and parts[2][:-1] == "d"
          and parts[3][:-1] == "n")
    _check(ok, "truth.corner", name, _CORNER_SYNTAX)
    return Corner(signs[parts[0][-1]], parts[1][:-1], signs[parts[1][-1]], signs[parts[2][-1]],
                  signs[parts[3][-1]])


def corners(tc: "TruthConfig") -> list[Corner]:
    """Every distinct corner of the declared bounds of ``tc``: bias sign x rotation axis x rotation
    sign x disturbance sign x navigation sign (48). A component whose bound is 0 gives the same
    truth at either sign (and a pointing bound 0, about any axis): only its first is kept."""
    sides = (1, -1)
    bias = sides if tc.bound("thrust_bias_max") > 0 else (1,)
    pointing = [(a, s) for a in CORNER_AXES for s in sides] \
        if tc.bound("thrust_pointing_max_deg") > 0 else [(CORNER_AXES[0], 1)]
    dist = sides if tc.bound("disturbance_max_kmps2") > 0 else (1,)
    nav = sides if any(tc.bound(n) > 0 for n in NAV_BOUNDS) else (1,)
    return [Corner(b, a, r, d, n) for b in bias for a, r in pointing for d in dist for n in nav]


@dataclass(frozen=True)
class TruthConfig:
    """The world the simulator flies, and the declared bounds of its errors (docs/robustness.md).

    Every error bound is multiplied by ``scale`` (0: the nominal model exactly). The simulator
    draws the errors within these bounds (seeded); robust Verify tightens the constraints by the
    same declared bounds. Units: km, s; fractions are dimensionless.

    ``nav_model``: "realistic" (a Gauss-Markov output moving by at most ``nav_rate_per_s`` of
    its bound per second) or "filter" (constant between measurement updates every
    ``nav_update_s``, a new draw within the bound at each). ``draw``: "random" (per-run draws
    from the run's seed) or "corner": every draw pinned to the corner named ``corner`` (a
    :class:`Corner` name), at ``corner_fraction`` of the declared bounds (1: on them).
    """

    name: str = "nominal"
    scale: float = 1.0
    gravity: str = "two-body"
    thrust_bias_max: float = 0.0
    thrust_pointing_max_deg: float = 0.0
    disturbance_max_kmps2: float = 0.0
    disturbance_correlation_s: float = 600.0
    nav_pos_floor_km: float = 0.0
    nav_pos_range_fraction: float = 0.0
    nav_vel_floor_kmps: float = 0.0
    nav_vel_range_fraction_per_s: float = 0.0
    nav_correlation_s: float = 300.0
    nav_rate_per_s: float = 0.02
    nav_model: str = "realistic"
    nav_update_s: float = 10.0
    draw: str = "random"
    corner: str = ""
    corner_fraction: float = 1.0

    def __post_init__(self) -> None:
        _positive("truth.nav_rate_per_s", self.nav_rate_per_s)
        _check(self.nav_model in NAV_MODELS, "truth.nav_model", self.nav_model,
               f"must be one of {NAV_MODELS}")
        _positive("truth.nav_update_s", self.nav_update_s)
        _check(self.draw in TRUTH_DRAWS, "truth.draw", self.draw, f"must be one of {TRUTH_DRAWS}")
        if self.draw == "corner":
            parse_corner(self.corner)   # ConfigError naming truth.corner
        else:
            _check(self.corner == "", "truth.corner", self.corner,
                   "is set, but truth.draw is 'random' (set truth.draw=corner to fly a corner)")
        _check(isinstance(self.corner_fraction, (int, float)) and 0.0 < self.corner_fraction <= 1.0,
               "truth.corner_fraction", self.corner_fraction,
               "must lie in (0, 1]: a corner pins the draws at this fraction of the declared bounds, "
               "and a pin beyond them (> 1) is outside the bounds robust Verify covers")
        _check(isinstance(self.name, str) and self.name != "", "truth.name", self.name,
               "must be a non-empty string")
        _check(self.gravity in GRAVITY_MODELS, "truth.gravity", self.gravity,
               f"must be one of {GRAVITY_MODELS}")
        for name in ("scale", "thrust_bias_max", "thrust_pointing_max_deg", "disturbance_max_kmps2",
                     "nav_pos_floor_km", "nav_pos_range_fraction", "nav_vel_floor_kmps",
                     "nav_vel_range_fraction_per_s"):
            v = getattr(self, name)
            _check(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0, f"truth.{name}", v,
                   "must be a finite number >= 0")
        _positive("truth.disturbance_correlation_s", self.disturbance_correlation_s)
        _positive("truth.nav_correlation_s", self.nav_correlation_s)
        _check(self.scale * self.thrust_bias_max < 0.5, "truth.thrust_bias_max", self.thrust_bias_max,
               "times truth.scale must stay below 0.5 (a thruster error of 50 % or more)")
        _check(self.scale * self.thrust_pointing_max_deg < 45.0, "truth.thrust_pointing_max_deg",
               self.thrust_pointing_max_deg, "times truth.scale must stay below 45 degrees")
        _check(self.scale * self.nav_pos_range_fraction < 0.3, "truth.nav_pos_range_fraction",
               self.nav_pos_range_fraction, "times truth.scale must stay below 0.3")

    def bound(self, name: str) -> float:
        """The declared bound ``name`` times ``scale``."""
        return self.scale * float(getattr(self, name))

    @property
    def max_thrust_factor(self) -> float:
        """|applied thrust| / |commanded| at most: 1 + the declared bias bound (h2 on the truth)."""
        return 1.0 + self.bound("thrust_bias_max")

    def nav_change_bound(self, t0_s: float, t1_s: float) -> float:
        """The largest change of the navigation error from t0 to t1 >= t0 (s since the epoch),
        as a fraction of its bound: |e(t1)/b(r1) - e(t0)/b(r0)| <= this (the error is a vector
        in the unit ball times the bound at the true range). ``realistic``: the rate limit,
        ``nav_rate_per_s`` (t1 - t0), at most 2; ``filter``: 2 when a measurement update
        (t = j ``nav_update_s``, j >= 1) falls in (t0, t1], else 0 (constant between updates)."""
        if self.nav_model == "realistic":
            return min(2.0, self.nav_rate_per_s * (t1_s - t0_s))
        return 2.0 if self.nav_update_index(t1_s) > self.nav_update_index(t0_s) else 0.0

    def nav_update_index(self, t_s: float) -> int:
        """The filter model's measurement update in force at t (s since the epoch): updates come
        at t = j ``nav_update_s``, j = 0, 1, ...; the error is constant from one to the next."""
        return math.floor(t_s / self.nav_update_s)

    @property
    def effective_gravity(self) -> str:
        """The gravity the truth flies: ``gravity``, but two-body at scale 0 (the nominal model)."""
        return self.gravity if self.scale > 0 else "two-body"

    @property
    def is_nominal(self) -> bool:
        """True when the truth equals the prediction model (two-body, every bound 0)."""
        return self.effective_gravity == "two-body" and all(
            self.bound(n) == 0.0 for n in ("thrust_bias_max", "thrust_pointing_max_deg",
                                           "disturbance_max_kmps2", *NAV_BOUNDS))


def prediction_gravity(cfg: "Config") -> str:
    """The gravity of the governors' prediction model: ``tsg.prediction_gravity``, where "auto"
    is J2 when robust Verify declares a J2 world (``truth.gravity`` j2 at a scale > 0), else
    two-body (the paper's model)."""
    if cfg.tsg.prediction_gravity != "auto":
        return cfg.tsg.prediction_gravity
    return cfg.truth.effective_gravity if cfg.tsg.robust else "two-body"


def control_config(cfg: "Config") -> ControlConfig:
    """The controller the loop flies: ``control``, with the LQ control weight
    ``control.robust_r_diag`` in place of ``control.r_diag`` under robust Verify. The paper's
    weight (R = I) gives a loop with a 3 % gain margin and minute-long saturated bang-bang
    approaches that no error tube can follow; docs/robustness.md, "The controller", says how
    the robust weight was chosen. Set ``control.robust_r_diag`` equal to ``control.r_diag`` to
    fly the paper's controller under robust Verify."""
    if not cfg.tsg.robust or cfg.control.robust_r_diag == cfg.control.r_diag:
        return cfg.control
    return dataclasses.replace(cfg.control, r_diag=cfg.control.robust_r_diag)


def ancillary_control_config(cfg: "Config") -> ControlConfig:
    """The controller of the ancillary tube's tracking gain K_a (``tsg.tube`` ancillary): the
    FTRE DARE with the LQ weight ``tsg.ancillary_r_diag`` (docs/robustness.md, "The ancillary
    tube")."""
    return dataclasses.replace(cfg.control, r_diag=cfg.tsg.ancillary_r_diag)


def ancillary_band_configs(cfg: "Config") -> list[tuple[float, "Config"]]:
    """The ancillary tube's gain bands (``tsg.ancillary_bands_km``): (the least measured range
    at which a plan starts in the band, km; the configuration whose ``tsg.ancillary_r_diag`` is
    the band's weight), ascending from (0, cfg)."""
    return [(0.0, cfg)] + [(km, cfg.replace(**{"tsg.ancillary_r_diag": [r, r, r], "tsg.ancillary_bands_km": [],
                                                "tsg.ancillary_bands_r": []}))
                           for km, r in zip(cfg.tsg.ancillary_bands_km, cfg.tsg.ancillary_bands_r)]


def handoff_control_config(cfg: "Config") -> ControlConfig:
    """The FTRE law the ancillary tube hands the truth to at the terminal sample: the FTRE DARE
    with the LQ weight ``tsg.ancillary_handoff_r_diag`` (docs/robustness.md, "Docking,
    certified"; set it to ``control.robust_r_diag`` to hand over to the robust controller)."""
    return dataclasses.replace(cfg.control, r_diag=cfg.tsg.ancillary_handoff_r_diag)


#: Update rules of learned governors: the default ("keep", SPEC §8 beyond the paper) and the
#: paper's Algorithm 1 ("paper").
LEARNED_ALGORITHMS = ("keep", "paper")
#: How the keep rule answers robust Verify's tail (|tau_prev| <= learned.robust_tail_s): the
#: conventional TSG's search, or a search around the last progress (docs/learned_update_rule.md).
TAIL_RULES = ("gallop", "search", "network")
#: How the keep rule searches while its network is not trusted (and for the stall rule): the
#: conventional TSG's search, or "hold-first": 0, coarse midpoints, the last progress and a hold
#: test verified in order, the first that passes answered (docs/learned_update_rule.md).
SEARCH_RULES = ("conventional", "hold-first")


@dataclass(frozen=True)
class LearnedConfig:
    """Update rule of the learned governors (SPEC §8): which rule, and the keep rule's settings."""

    algorithm: str = "keep"
    ladder: tuple[float, ...] = (0.08, 0.03, 0.0, -0.05)
    min_step_s: float = 1e-3
    min_progress: float = 0.0
    fallback_budget: int = 1
    probe_every: int = 3
    probe_budget: int = 2
    trust_credit: int = 3
    trust_hits: int = 3
    trust_retry: int = 2
    robust_trust_retry: int = 0
    audit_step: float = 0.1
    stall_updates: int = 10
    stall_judge: str = "progress"
    robust_tail_s: float = 0.1
    tail_rule: str = "network"
    tail_ladder: tuple[float, ...] = (0.0, -0.05)
    tail_growth: float = 1.5
    tail_budget: int = 5
    tail_min_progress: float = 0.05
    tail_backoff: int = 0
    search_rule: str = "conventional"
    hold_test: float = 1e-3
    hold_first_above_s: float = 0.1
    search_depth: int = 4
    search_ladder: tuple[float, ...] = (4.0, 2.0, 1.0, 0.5, 0.25)
    search_budget: int = 0
    search_backoff: int = 0
    trust_at_start: str = "network"
    foreign_model: bool = False

    def __post_init__(self) -> None:
        _check(self.algorithm in LEARNED_ALGORITHMS, "learned.algorithm", self.algorithm,
               f"must be one of {LEARNED_ALGORITHMS}")
        for name in ("ladder", "tail_ladder"):   # s of the candidates tau_c (1 - s), in order
            rungs = tuple(float(s) for s in getattr(self, name))
            object.__setattr__(self, name, rungs)
            _check(1 <= len(rungs) <= 8 and all(-1.0 <= s < 1.0 for s in rungs)
                   and all(a > b for a, b in zip(rungs, rungs[1:])), f"learned.{name}",
                   list(rungs), "must be 1 to 8 numbers in [-1, 1), strictly decreasing")
        _check(math.isfinite(self.min_step_s) and self.min_step_s >= 0, "learned.min_step_s",
               self.min_step_s, "must be >= 0")
        _check(math.isfinite(self.min_progress) and 0.0 <= self.min_progress < 1.0,
               "learned.min_progress", self.min_progress, "must be in [0, 1)")
        for name in ("fallback_budget", "probe_budget"):
            v = getattr(self, name)
            _check(isinstance(v, int) and 0 <= v <= 64, f"learned.{name}", v,
                   "must be an integer in [0, 64]")
        _check(isinstance(self.probe_every, int) and self.probe_every >= 1, "learned.probe_every",
               self.probe_every, "must be an integer >= 1")
        _check(isinstance(self.trust_credit, int) and 0 <= self.trust_credit <= 64, "learned.trust_credit",
               self.trust_credit, "must be an integer in [0, 64] (0: never trust the network)")
        _check(isinstance(self.trust_hits, int) and 1 <= self.trust_hits <= 64, "learned.trust_hits",
               self.trust_hits, "must be an integer in [1, 64]")
        for name in ("trust_retry", "robust_trust_retry"):
            v = getattr(self, name)
            _check(isinstance(v, int) and 0 <= v <= 1000, f"learned.{name}", v,
                   "must be an integer in [0, 1000] (0: only shadow hits give trust back)")
        _check(self.trust_at_start in ("network", "search"), "learned.trust_at_start", self.trust_at_start,
               "must be 'network' (a mission starts with it on probation) or 'search' (it must earn trust)")
        _check(math.isfinite(self.audit_step) and 0.0 <= self.audit_step < 1.0, "learned.audit_step",
               self.audit_step, "must be in [0, 1) (0: no audit)")
        _check(isinstance(self.stall_updates, int) and 0 <= self.stall_updates <= 1000,
               "learned.stall_updates", self.stall_updates,
               "must be an integer in [0, 1000] (0: never search after a stall)")
        _check(math.isfinite(self.robust_tail_s) and self.robust_tail_s >= 0.0, "learned.robust_tail_s",
               self.robust_tail_s, "must be a finite number of seconds >= 0 (0: no handover)")
        _check(self.tail_rule in TAIL_RULES, "learned.tail_rule", self.tail_rule, f"must be one of {TAIL_RULES}")
        _check(math.isfinite(self.tail_growth) and self.tail_growth > 1.0, "learned.tail_growth",
               self.tail_growth, "must be a number > 1")
        _check(isinstance(self.tail_budget, int) and 1 <= self.tail_budget <= 64, "learned.tail_budget",
               self.tail_budget, "must be an integer in [1, 64]")
        _check(math.isfinite(self.tail_min_progress) and 0.0 <= self.tail_min_progress <= 1.0,
               "learned.tail_min_progress", self.tail_min_progress, "must be in [0, 1]")
        _check(isinstance(self.tail_backoff, int) and 0 <= self.tail_backoff <= 1024, "learned.tail_backoff",
               self.tail_backoff, "must be an integer in [0, 1024] (0: off)")
        _check(self.search_rule in SEARCH_RULES, "learned.search_rule", self.search_rule,
               f"must be one of {SEARCH_RULES}")
        _check(math.isfinite(self.hold_test) and 0.0 < self.hold_test < 1.0, "learned.hold_test",
               self.hold_test, "must be in (0, 1)")
        _check(math.isfinite(self.hold_first_above_s) and self.hold_first_above_s >= 0.0,
               "learned.hold_first_above_s", self.hold_first_above_s, "must be a finite number of seconds >= 0")
        object.__setattr__(self, "search_ladder", tuple(float(f) for f in self.search_ladder))
        _check(len(self.search_ladder) <= 16 and all(math.isfinite(f) and f > 0 for f in self.search_ladder),
               "learned.search_ladder", list(self.search_ladder), "must be at most 16 numbers > 0")
        _check(isinstance(self.search_depth, int) and 0 <= self.search_depth <= 30, "learned.search_depth",
               self.search_depth, "must be an integer in [0, 30]")
        _check(isinstance(self.search_backoff, int) and 0 <= self.search_backoff <= 1024, "learned.search_backoff",
               self.search_backoff, "must be an integer in [0, 1024] (0: off)")
        _check(isinstance(self.search_budget, int) and 0 <= self.search_budget <= 64, "learned.search_budget",
               self.search_budget, "must be an integer in [0, 64]")
        _check(self.stall_judge in ("progress", "audit"), "learned.stall_judge", self.stall_judge,
               "must be 'progress' (any progress a stall search finds is a miss) or 'audit' "
               "(only progress beyond audit_step)")


@dataclass(frozen=True)
class ScenarioConfig:
    """Which mission this is: a name, one line saying what it is, and the directory of its
    trained models (relative to the project root or an install's share/cikan_ros; a model of
    family F for approach A is ``<models_dir>/F`` behind and ``<models_dir>/F-ahead`` ahead)."""

    name: str = "paper"
    description: str = "the paper's 12-h Molniya-like orbit (e = 0.74), deputy 100 km from the chief"
    models_dir: str = "models"

    def __post_init__(self) -> None:
        _check(isinstance(self.name, str) and self.name.replace("-", "").replace("_", "").isalnum(),
               "scenario.name", self.name, "must be a word (letters, digits, - and _)")
        _check(isinstance(self.models_dir, str) and self.models_dir.strip() != "", "scenario.models_dir",
               self.models_dir, "must name a directory")


@dataclass(frozen=True)
class Config:
    """All parameters of one mission; cross-group consistency is checked here."""

    orbit: OrbitConfig = field(default_factory=OrbitConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    constraints: ConstraintConfig = field(default_factory=ConstraintConfig)
    tsg: TSGConfig = field(default_factory=TSGConfig)
    mission: MissionConfig = field(default_factory=MissionConfig)
    learned: LearnedConfig = field(default_factory=LearnedConfig)
    truth: TruthConfig = field(default_factory=TruthConfig)
    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)

    @functools.cached_property
    def side(self) -> Side:
        """The approach side of this mission (``mission.approach``, the one place it is read):
        BEHIND (tau <= 0) or AHEAD (tau >= 0)."""
        return Side.of(self.mission.approach)

    @property
    def thrust_limit_kmps2(self) -> float:
        """The h2 limit on the thrust the truth applies (km/s^2): the commanded bound u_max times
        the declared thruster error's largest magnification (``truth.max_thrust_factor``)."""
        return self.control.u_max_kmps2 * self.truth.max_thrust_factor

    def __post_init__(self) -> None:
        ratio = self.tsg.update_period_s / self.control.period_s
        _check(abs(ratio - round(ratio)) < 1e-9 and round(ratio) >= 1, "tsg.update_period_s",
               self.tsg.update_period_s, "must be a whole multiple of control.period_s")
        _check(abs(self.tsg.sample_period_s - self.control.period_s) < 1e-12,
               "tsg.sample_period_s", self.tsg.sample_period_s,
               "must equal control.period_s (the prediction uses the controller's ZOH)")
        ratio = self.mission.duration_s / self.control.period_s
        _check(abs(ratio - round(ratio)) < 1e-9, "mission.duration_s", self.mission.duration_s,
               "must be a whole multiple of control.period_s")

    # -- conversions ----------------------------------------------------------------------------
    def flat(self) -> dict[str, Any]:
        """Parameters as ``{"group.key": value}`` (the ROS parameter names)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            group = getattr(self, f.name)
            for g in fields(group):
                v = getattr(group, g.name)
                out[f"{f.name}.{g.name}"] = list(v) if isinstance(v, tuple) else v
        return out

    def replace(self, **dotted: Any) -> "Config":
        """A copy with values changed by dotted name, e.g. ``replace(**{"tsg.tolerance_s": 1e-4})``."""
        return config_from_flat({**self.flat(), **dotted})


_GROUP_CLASSES = {
    "orbit": OrbitConfig, "control": ControlConfig, "constraints": ConstraintConfig,
    "tsg": TSGConfig, "mission": MissionConfig, "learned": LearnedConfig, "truth": TruthConfig,
    "scenario": ScenarioConfig,
}


def _coerce(name: str, default: Any, value: Any) -> Any:
    """Convert a YAML/ROS value to the type of the field's default, or raise ConfigError."""
    if isinstance(default, bool):
        _check(isinstance(value, bool), name, value, "must be true or false")
        return value
    if isinstance(default, int):
        _check(isinstance(value, int) and not isinstance(value, bool), name, value, "must be an integer")
        return value
    if isinstance(default, float):
        _check(isinstance(value, (int, float)) and not isinstance(value, bool), name, value, "must be a number")
        return float(value)
    if isinstance(default, tuple):
        if value is None and default == ():
            return ()  # a ROS params file cannot type an empty list: the node reads it unset
        _check(isinstance(value, (list, tuple)) and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                        for v in value), name, value, "must be a list of numbers")
        return tuple(float(v) for v in value)
    if isinstance(default, str):
        _check(isinstance(value, str), name, value, "must be a string")
        return value
    raise AssertionError(name)  # pragma: no cover - every field has one of the types above


def config_from_flat(flat: Mapping[str, Any]) -> Config:
    """Build a validated :class:`Config` from ``{"group.key": value}``; unknown names are errors."""
    groups: dict[str, dict[str, Any]] = {g: {} for g in _GROUP_CLASSES}
    for name, value in flat.items():
        group, _, key = name.partition(".")
        cls = _GROUP_CLASSES.get(group)
        known = {f.name: f for f in fields(cls)} if cls else {}
        if key not in known:
            raise ConfigError(f"unknown configuration parameter {name!r}")
        default = known[key].default if known[key].default is not dataclasses.MISSING \
            else known[key].default_factory()  # type: ignore[misc]
        groups[group][key] = _coerce(name, default, value)
    try:
        return Config(**{g: _GROUP_CLASSES[g](**kv) for g, kv in groups.items()})
    except TypeError as exc:  # pragma: no cover - guarded by the name check above
        raise ConfigError(str(exc)) from None


def _flatten(prefix: str, node: Mapping[str, Any], out: dict[str, Any]) -> None:
    for k, v in node.items():
        name = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, Mapping):
            _flatten(name, v, out)
        else:
            out[name] = v


def read_params(path: str | Path) -> dict[str, Any]:
    """``{"group.key": value}`` of the ``/**: ros__parameters:`` section of a ROS 2 params file;
    ConfigError naming what is wrong with the file."""
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
    except FileNotFoundError:
        raise ConfigError(f"configuration file not found: {p}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"configuration file {p} is not valid YAML: {exc}") from None
    if not isinstance(doc, Mapping):
        raise ConfigError(f"configuration file {p} must hold a mapping")
    section = doc.get("/**", doc)
    params = section.get("ros__parameters") if isinstance(section, Mapping) else None
    if not isinstance(params, Mapping):
        raise ConfigError(f"configuration file {p} has no '/**: ros__parameters:' section")
    flat: dict[str, Any] = {}
    _flatten("", params, flat)
    return flat


#: Shipped truth models: ``config/truth/<name>.yaml``.
TRUTH_DIR = shipped("config/truth")
#: Keys a truth file may set besides ``truth.*``: the docking test its navigation accuracy allows.
TRUTH_FILE_EXTRA_KEYS = ("mission.dock_distance_km", "mission.dock_speed_kmps")


def truth_names() -> list[str]:
    """Names of the shipped truth models."""
    return sorted(p.stem for p in TRUTH_DIR.glob("*.yaml"))


def truth_overrides(name_or_path: str) -> dict[str, Any]:
    """``{"group.key": value}`` of a truth model: a shipped name (``nominal``, ``realistic``) or a
    params file with a ``truth`` group (and optionally the docking test, ``mission.dock_*``).
    ConfigError naming an unknown name, a missing file or a key a truth file may not set."""
    p = _params_file(name_or_path, TRUTH_DIR, "truth model", truth_names())
    flat = read_params(p)
    bad = [k for k in flat if not k.startswith("truth.") and k not in TRUTH_FILE_EXTRA_KEYS]
    if bad:
        raise ConfigError(f"truth file {p} sets {bad[0]!r}: a truth file holds the truth group "
                          f"and {', '.join(TRUTH_FILE_EXTRA_KEYS)} only")
    flat.setdefault("truth.name", p.stem)
    return flat


#: Shipped scenarios: ``config/scenarios/<name>.yaml`` (docs/scenarios.md).
SCENARIO_DIR = shipped("config/scenarios")


def scenario_names() -> list[str]:
    """Names of the shipped scenarios."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))


def _params_file(name_or_path: str, directory: Path, what: str, names: list[str]) -> Path:
    """A shipped ``<directory>/<name>.yaml`` or a YAML file path; ConfigError naming an unknown name."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        return p
    shipped_file = directory / f"{name_or_path}.yaml"
    if not shipped_file.exists():
        raise ConfigError(f"unknown {what} {name_or_path!r}: choose one of {names} or give a YAML file")
    return shipped_file


def scenario_overrides(name_or_path: str) -> dict[str, Any]:
    """``{"group.key": value}`` of a scenario: a shipped name (``paper``, ``leo``, ``geo``) or a
    params file over config/cikan.yaml (orbit, control, constraints, tsg, mission, learned and
    the ``scenario`` group; no ``truth``: the world flown is chosen apart, with ``--truth``).
    Every key and value is checked here, so a bad file is refused with one line naming it."""
    p = _params_file(name_or_path, SCENARIO_DIR, "scenario", scenario_names())
    flat = read_params(p)
    bad = [k for k in flat if k.startswith("truth.")]
    if bad:
        raise ConfigError(f"scenario file {p} sets {bad[0]!r}: a scenario does not choose the truth "
                          f"(use --truth)")
    flat.setdefault("scenario.name", p.stem)
    try:
        config_from_flat(flat)
    except ConfigError as exc:
        raise ConfigError(f"scenario file {p}: {exc}") from None
    return flat


def load_config(path: str | Path | None = None, **overrides: Any) -> Config:
    """Read a ROS 2 params YAML file (the ``/**`` section) and apply dotted-name overrides.

    ``path=None`` reads the shipped default file; a missing default file falls back to the
    built-in defaults, which equal it.
    """
    flat: dict[str, Any] = {}
    p = Path(path) if path is not None else DEFAULT_CONFIG_PATH
    if path is not None or p.exists():
        flat = read_params(p)
    flat.update(overrides)
    return config_from_flat(flat)
