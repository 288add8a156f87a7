"""Offline closed loop (plant + FTRE controller every T_c + governor every P_upd), Monte Carlo
starts and per-run metrics (SPEC §6, §9). No ROS here: the ROS graph runs the same steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import brentq

from .config import Config
from .constraints import Margins, margins
from .control import ftre_control
from .dynamics import Plant
from .errors import NoFeasibleShiftError, StateError
from .governor import Governor, UpdateRecord
from .orbit import check_states
from .tsg import Predictor
from .units import ns_to_seconds, seconds_to_ns, through_si

#: Attempts of the Monte Carlo rejection sampler before it gives up on a seed.
MAX_DRAWS = 1000


def nominal_shift(predictor: Predictor) -> float:
    """tau_nom < 0: the chief orbit point at straight-line distance D behind the chief at t = 0."""
    orbit = predictor.orbit
    dist = predictor.config.mission.nominal_distance_km
    p0 = orbit.state(0.0)[:3]

    def gap(tau: float) -> float:
        return float(np.linalg.norm(orbit.state(tau)[:3] - p0)) - dist

    lo = -dist / float(np.linalg.norm(orbit.state(0.0)[3:]))
    while gap(lo) < 0.0:
        lo *= 2.0
        if -lo > orbit.period / 2:
            raise StateError(f"mission.nominal_distance_km = {dist} is too large for the chief orbit")
    return float(brentq(gap, lo, 0.0, xtol=1e-13, rtol=1e-15))


def nominal_start(predictor: Predictor) -> NDArray:
    """Deputy state at t = 0 of the nominal start: x_c(tau_nom) (SPEC §6)."""
    return predictor.orbit.state(nominal_shift(predictor))


def sample_start(predictor: Predictor, seed: int, sigma_km: float | None = None) -> NDArray:
    """A Monte Carlo start: nominal position + N(0, sigma^2 I) km, nominal velocity, drawn with
    ``numpy.random.default_rng(seed)`` until h1 <= 0 and an initial shift exists (SPEC §6).

    ``sigma_km`` overrides ``mission.mc_sigma_km`` (the data generator widens the distribution).
    """
    cfg = predictor.config
    sigma = cfg.mission.mc_sigma_km if sigma_km is None else sigma_km
    rng = np.random.default_rng(seed)
    x_nom = nominal_start(predictor)
    x_c0 = predictor.orbit.state(0.0)
    for _ in range(MAX_DRAWS):
        x = x_nom.copy()
        x[:3] += rng.normal(0.0, sigma, 3)
        m = margins(x, x_c0, np.zeros(3), cfg.constraints, cfg.control.u_max_kmps2)
        if not m.h1[0] <= 0.0:
            continue
        try:
            predictor.initial_shift(x, 0.0)
        except NoFeasibleShiftError:
            continue
        return x
    raise NoFeasibleShiftError(f"no admissible Monte Carlo start in {MAX_DRAWS} draws for seed {seed}")


@dataclass
class MissionResult:
    """A whole closed-loop run. Arrays are per control step k = 0 .. K (K = T_sim / T_c)."""

    config: Config
    governor: str
    t: NDArray          # (K+1,) s since epoch
    x_d: NDArray        # (K+1, 6) deputy, km, km/s, ECI
    x_c: NDArray        # (K+1, 6) chief
    u: NDArray          # (K+1, 3) km/s^2 applied over [t_k, t_k+1); last row 0 (no command)
    tau: NDArray        # (K+1,) shift in force at t_k, s
    margins: Margins    # h1, h1 normalised, h2, h3 at every step
    initial: UpdateRecord
    update_t: NDArray   # (U,) times of the updates after the first instant
    updates: list[UpdateRecord] = field(default_factory=list)

    def metrics(self) -> dict[str, Any]:
        """Per-run metrics (SPEC §6, §9); margins are -h (>= 0 safe), h1 normalised."""
        cfg = self.config
        rel = self.x_d - self.x_c
        dist = np.linalg.norm(rel[:, :3], axis=1)
        speed = np.linalg.norm(rel[:, 3:], axis=1)
        m = self.margins
        h1_bad = m.h1_normalised > cfg.constraints.plant_h1_tolerance
        h3_bad = m.h3 > cfg.constraints.plant_h3_tolerance_kmps
        h2_bad = m.h2 > 1e-12 * cfg.control.u_max_kmps2
        violations = int(np.count_nonzero(h1_bad | h2_bad | h3_bad))
        zero_idx = np.flatnonzero(self.tau == 0.0)
        tau_zero = bool(self.tau[-1] == 0.0)
        docked = bool(dist[-1] < cfg.mission.dock_distance_km and speed[-1] < cfg.mission.dock_speed_kmps)
        walls = np.array([r.wall_s for r in self.updates]) * 1e3
        active = np.array([r.wall_s for r in self.updates if r.active]) * 1e3
        cpu = np.array([r.cpu_s for r in self.updates]) * 1e3
        cpu_active = np.array([r.cpu_s for r in self.updates if r.active]) * 1e3
        dv = cfg.control.period_s * float(np.sum(np.linalg.norm(self.u, axis=1)))
        h1n = m.h1_normalised[np.isfinite(m.h1_normalised)]
        h3 = m.h3[np.isfinite(m.h3)]
        docked_idx = np.flatnonzero((dist < cfg.mission.dock_distance_km)
                                    & (speed < cfg.mission.dock_speed_kmps))
        return {
            "governor": self.governor,
            "success": bool(tau_zero and docked and violations == 0),
            "violations": violations,
            "violations_h1": int(np.count_nonzero(h1_bad)),
            "violations_h3": int(np.count_nonzero(h3_bad)),
            "final_distance_m": float(dist[-1] * 1e3),
            "final_speed_mps": float(speed[-1] * 1e3),
            "delta_v_kmps": dv,
            "delta_v_mps": dv * 1e3,
            "min_h1_margin": float(-h1n.max()) if h1n.size else None,
            "max_h3": float(h3.max()) if h3.size else None,
            "max_h2": float(np.nanmax(m.h2)),
            "tau0_s": self.initial.tau_s,
            "t_tau_zero_s": float(self.t[zero_idx[0]]) if zero_idx.size else None,
            "t_docked_s": float(self.t[docked_idx[0]]) if docked_idx.size else None,
            "initial_ms": self.initial.wall_s * 1e3,
            "updates": len(self.updates),
            "active_updates": int(active.size),
            "update_ms_mean": float(walls.mean()) if walls.size else 0.0,
            "update_ms_max": float(walls.max()) if walls.size else 0.0,
            "active_update_ms_mean": float(active.mean()) if active.size else 0.0,
            "active_update_ms_max": float(active.max()) if active.size else 0.0,
            # CPU time of the deciding thread (wall time counts waits for a core on a busy machine)
            "update_cpu_ms_mean": float(cpu.mean()) if cpu.size else 0.0,
            "update_cpu_ms_max": float(cpu.max()) if cpu.size else 0.0,
            "active_update_cpu_ms_mean": float(cpu_active.mean()) if cpu_active.size else 0.0,
            "active_update_cpu_ms_max": float(cpu_active.max()) if cpu_active.size else 0.0,
            "verify_calls": int(self.initial.verify_calls + sum(r.verify_calls for r in self.updates)),
            "active_verify_calls_max": max((r.verify_calls for r in self.updates if r.active), default=0),
            "duration_s": float(self.t[-1] - self.t[0]),
        }


    def update_states(self, active_only: bool = True) -> list["UpdateState"]:
        """What the governor was given at each update (after the first instant) and its answer."""
        return update_states(self.config, self.t, self.x_d, self.x_c,
                             [(r.k, r.tau_prev, r.tau_s) for r in self.updates], active_only)


@dataclass(frozen=True)
class UpdateState:
    """One update: index k, time t (s since epoch), x_d, x_c (km, km/s, as the governor saw them,
    through SI), the previous shift tau_prev and the answer tau (s). Active when tau_prev < 0."""

    k: int
    t: float
    x_d: NDArray
    x_c: NDArray
    tau_prev: float
    tau: float

    @property
    def active(self) -> bool:
        return self.tau_prev < 0.0


def update_states(cfg: Config, t: NDArray, x_d: NDArray, x_c: NDArray,
                  updates: list[tuple[int, float, float]], active_only: bool = True
                  ) -> list[UpdateState]:
    """Update states of a run from its per-step arrays and its updates (k, tau_prev, tau): the
    one place that maps an update index to its control step and decides what is active."""
    per_update = round(cfg.tsg.update_period_s / cfg.control.period_s)
    out = []
    for k, tau_prev, tau in updates:
        if active_only and not tau_prev < 0.0:
            continue
        step = int(k) * per_update
        out.append(UpdateState(int(k), float(t[step]), through_si(x_d[step]), through_si(x_c[step]),
                               float(tau_prev), float(tau)))
    return out


def errors_against_optimal(predictor: Predictor, states: list[UpdateState]) -> NDArray:
    """tau - pi* at each active update state, pi* solved there from the same tau_prev (SPEC §9)."""
    return np.array([s.tau - predictor.optimal_shift(s.x_d, s.t, s.tau_prev)[0]
                     for s in states if s.active])


def rmse(errors: NDArray) -> float:
    """Root mean square of errors (NaN when there are none)."""
    return float(np.sqrt(np.mean(np.square(errors)))) if len(errors) else math.nan


def run_mission(governor: Governor, x_d0: NDArray, plant: Plant | None = None) -> MissionResult:
    """Closed loop from deputy state x_d0 at t = 0 for T_sim: governor every P_upd, control every T_c.

    At step k: chief state, governor update (every P_upd after the first instant), control
    toward x_v = x_c(t_k + tau), plant step with the control held (ZOH).
    """
    pred = governor.predictor
    cfg = pred.config
    x = np.array(x_d0, dtype=float)
    check_states(x, "initial deputy state")
    plant = plant or Plant(pred.orbit.mu, cfg.mission.plant_substeps)
    tc = cfg.control.period_s
    n_steps = round(cfg.mission.duration_s / tc)
    every = round(cfg.tsg.update_period_s / tc)
    t = np.array([ns_to_seconds(k * seconds_to_ns(tc)) for k in range(n_steps + 1)])
    x_c = pred.orbit.state(t)
    x_d = np.empty((n_steps + 1, 6))
    u = np.zeros((n_steps + 1, 3))
    taus = np.empty(n_steps + 1)
    updates: list[UpdateRecord] = []
    update_t: list[float] = []
    first = governor.initial(through_si(x), through_si(x_c[0]), 0.0)
    tau = first.tau_s
    u_max = cfg.control.u_max_kmps2
    for k in range(n_steps):
        # The governor and the controller see what crosses the ROS boundary (SI and back).
        x_seen = through_si(x)
        if k > 0 and k % every == 0:
            rec = governor.update(x_seen, through_si(x_c[k]), float(t[k]), tau)
            updates.append(rec)
            update_t.append(float(t[k]))
            tau = rec.tau_s
        x_d[k] = x
        taus[k] = tau
        (x_v, nu_v) = pred.orbit.state_and_anomaly(t[k] + tau)
        u[k] = through_si(ftre_control(pred.gains, float(nu_v), x_seen, x_v, u_max))
        x = plant.step(x, u[k], tc)
    x_d[-1] = x
    taus[-1] = tau
    m = margins(x_d, x_c, u, cfg.constraints, u_max)
    m.h2[-1] = math.nan  # no command is applied at the final instant
    return MissionResult(cfg, governor.name, t, x_d, x_c, u, taus, m, first, np.array(update_t), updates)
