"""The closed-loop step (update schedule, virtual target + saturated FTRE command, docking test),
the offline closed loop built from it, Monte Carlo starts and per-run metrics (SPEC §6, §9).

No ROS here: the ROS nodes call the same :class:`ClosedLoop` (sim_node: schedule and docking
test, governor_node: the decision of step k, controller_node: the command), so the graph and
:func:`run_mission` run one implementation of the step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq

from .ancillary import AncillaryLaw, Plan
from .config import Config
from .constraints import Margins, constraint_params, margins, step_margins_kernel
from .control import ftre_control
from .errors import NoFeasibleShiftError, StateError
from .governor import Governor, UpdateRecord, is_active
from .orbit import check_states
from .progress import Bar
from .truth import Truth
from .tsg import ChiefAnchor, Predictor
from .units import ns_to_seconds, seconds_to_ns, through_si

#: Attempts of the Monte Carlo rejection sampler before it gives up on a seed.
MAX_DRAWS = 1000


def nominal_shift(predictor: Predictor) -> float:
    """tau_nom: the chief orbit point at straight-line distance D from the chief at t = 0, behind
    it (tau_nom < 0) or ahead of it (tau_nom > 0) as ``mission.approach`` says."""
    orbit = predictor.orbit
    dist = predictor.config.mission.nominal_distance_km
    side = predictor.side
    p0 = orbit.state(0.0)[:3]

    def gap(tau: float) -> float:
        return float(np.linalg.norm(orbit.state(tau)[:3] - p0)) - dist

    far = side * dist / float(np.linalg.norm(orbit.state(0.0)[3:]))
    while gap(far) < 0.0:
        far *= 2.0
        if abs(far) > orbit.period / 2:
            raise StateError(f"mission.nominal_distance_km = {dist} is too large for the chief orbit")
    return float(brentq(gap, min(far, 0.0), max(far, 0.0), xtol=1e-13, rtol=1e-15))


def nominal_start(predictor: Predictor) -> NDArray:
    """Deputy state at t = 0 of the nominal start: x_c(tau_nom) (SPEC §6)."""
    return predictor.orbit.state(nominal_shift(predictor))


def sample_start(predictor: Predictor, seed: int, sigma_km: float | None = None) -> NDArray:
    """A Monte Carlo start: nominal position + N(0, sigma^2 I) km, nominal velocity, drawn with
    ``numpy.random.default_rng(seed)`` until h1 <= 0 and an initial shift exists (SPEC §6) for
    nominal Verify (robust Verify flies the same starts, or reports that none is feasible).

    ``sigma_km`` overrides ``mission.mc_sigma_km`` (the data generator widens the distribution).
    """
    cfg = predictor.config
    predictor = predictor.nominal()  # the same starts for nominal and robust Verify
    sigma = cfg.mission.mc_sigma_km if sigma_km is None else sigma_km
    rng = np.random.default_rng(seed)
    x_nom = nominal_start(predictor)
    x_c0 = predictor.orbit.state(0.0)
    for _ in range(MAX_DRAWS):
        x = x_nom.copy()
        x[:3] += rng.normal(0.0, sigma, 3)
        m = margins(x, x_c0, np.zeros(3), cfg.constraints, cfg.control.u_max_kmps2, cfg.side)
        if not m.h1[0] <= 0.0:
            continue
        try:
            predictor.initial_shift(x, 0.0)
        except NoFeasibleShiftError:
            continue
        return x
    raise NoFeasibleShiftError(f"no admissible Monte Carlo start in {MAX_DRAWS} draws for seed {seed}")


def docked(x_d: ArrayLike, x_c: ArrayLike, cfg: Config) -> NDArray:
    """The docking test (|p_rel| < dock distance and |v_rel| < dock speed) per row of (..., 6)."""
    rel = np.asarray(x_d, dtype=float) - np.asarray(x_c, dtype=float)
    return (np.linalg.norm(rel[..., :3], axis=-1) < cfg.mission.dock_distance_km) \
        & (np.linalg.norm(rel[..., 3:], axis=-1) < cfg.mission.dock_speed_kmps)


class Schedule:
    """The lockstep schedule of a mission (SPEC §6): K = T_sim / T_c control steps at t_k = k T_c
    (whole nanoseconds); the governor decides at the first state it sees (the first-instant
    search) and then at every k > 0 with k T_c a multiple of P_upd, holding its shift in between;
    the mission ends at k = K (or when docked, if asked)."""

    def __init__(self, cfg: Config) -> None:
        self.config = cfg
        self.period_ns = seconds_to_ns(cfg.control.period_s)
        self.n_steps = round(cfg.mission.duration_s / cfg.control.period_s)
        #: Control steps per governor update (P_upd / T_c).
        self.every = round(cfg.tsg.update_period_s / cfg.control.period_s)

    def time(self, k: int) -> float:
        """t_k (s since the epoch): the float both the offline loop and the nodes use."""
        return ns_to_seconds(k * self.period_ns)

    def times(self) -> NDArray:
        """t_0 .. t_K (s)."""
        return np.array([self.time(k) for k in range(self.n_steps + 1)])

    def update_due(self, k: int) -> bool:
        """Is a governor update due at step k (after the first instant)?"""
        return k > 0 and k % self.every == 0

    def finished(self, k: int, x_d: NDArray, x_c: NDArray, stop_on_dock: bool = False) -> bool:
        """Does the mission end at step k (T_sim reached, or docked when ``stop_on_dock``)?"""
        return k >= self.n_steps or (stop_on_dock and bool(docked(x_d, x_c, self.config)))


class ClosedLoop(Schedule):
    """One step k of the closed loop, the single implementation used by :func:`run_mission` and
    by the ROS nodes: the :class:`Schedule`, the governor's decision, and the saturated FTRE
    command toward the virtual target x_v = x_c(t_k + tau)."""

    def __init__(self, predictor: Predictor) -> None:
        super().__init__(predictor.config)
        self.predictor = predictor
        #: The controller's own chief anchor (the governor holds another): the ROS nodes
        #: anchor alike, whichever process computes the command.
        self.anchor = ChiefAnchor(predictor)
        #: The ancillary tube's tracking law and the plan it tracks (``tsg.tube`` ancillary under
        #: robust Verify): None otherwise.
        self.ancillary = AncillaryLaw(predictor) if predictor.ancillary else None
        self.plan: Plan | None = None
        #: The chief model the plans are verified with: anchored as the library's governors anchor
        #: theirs (:meth:`observe`), so the plan is the rollout the governor's Verify accepted,
        #: bit for bit, whichever process builds it (the controller node holds its own).
        self.plan_anchor = ChiefAnchor(predictor)

    def warm_up(self, x_d: NDArray, x_c: NDArray) -> None:
        """Compile or load every kernel a step of this loop may take, on a copy of it (this
        loop's plan and anchors stay as they are): the FTRE command, and under the ancillary tube
        a plan of the first-instant shift from the deputy x_d (its rollout, the tracking command,
        the command after the plan). Measured: without it the controller node's first step under
        the ancillary tube took 15 ms more (numba's cached kernels loading) than the ones after."""
        loop = ClosedLoop(self.predictor)
        loop.observe(0, x_c, None)
        loop.command(0, 0.0, x_d, x_c)
        if loop.ancillary is None:
            return
        try:
            tau, _ = self.predictor.initial_shift(x_d, loop.time(0))
        except NoFeasibleShiftError:  # robust Verify refuses this state: what is loaded is loaded
            return
        if loop.take_effect(0, tau, x_d) and loop.plan is not None:
            loop.command(0, tau, x_d, x_c)
            loop.command(len(loop.plan.x_p), tau, x_d, x_c)

    def observe(self, k: int, x_c: NDArray, tau_prev: float | None) -> None:
        """Step k's measured chief x_c, with the shift in force before it (None at the first
        instant): anchor the plans' chief model where the library's governors anchor theirs, at
        the first instant and at each update that predicts (tau_prev != 0)."""
        if self.ancillary is not None and (tau_prev is None or (self.update_due(k) and tau_prev != 0.0)):
            self.plan_anchor(x_c, self.time(k))

    def take_effect(self, k: int, tau: float, x_d: NDArray) -> bool:
        """A new shift tau takes effect at step k from the measured deputy x_d: under the ancillary
        tube the rollout robust Verify accepts for it becomes the plan the command tracks (built
        here with :attr:`plan_anchor`). False when that rollout does not pass (a governor that anchors
        otherwise; the plan in force is kept); True otherwise, and without the ancillary tube."""
        if self.ancillary is None:
            return True
        try:
            self.plan = Plan.accepted(self.plan_anchor.current, k, self.time(k), tau, x_d)
        except StateError:
            return False
        return True

    def certified_ball(self, k: int) -> tuple[float, float] | None:
        """Under the ancillary tube with tau = 0 in force: the ball (km, km/s) about the chief
        robust Verify's terminal test certifies for the truth at step k (the docking test it
        guarantees: :meth:`Plan.certified_ball`); None otherwise."""
        if self.plan is None or self.plan.tau != 0.0:
            return None
        return self.plan.certified_ball(self.plan_anchor.current, k)

    def decide(self, governor: Governor, k: int, x_d: NDArray, x_c: NDArray,
               tau_prev: float | None) -> UpdateRecord | None:
        """The governor's part of step k: the first-instant search while no shift is in force
        (``tau_prev`` None), an update when one is due, else None (the shift in force holds)."""
        t = self.time(k)
        if tau_prev is None:
            return governor.initial(x_d, x_c, t)
        if self.update_due(k):
            return governor.update(x_d, x_c, t, tau_prev)
        return None

    def command(self, k: int, tau: float, x_d: NDArray, x_c: NDArray) -> NDArray:
        """Saturated FTRE acceleration (km/s^2, ECI) at t_k toward x_v = x_c(t_k + tau), the
        measured chief x_c at t_k propagated by tau with the prediction model."""
        t = self.time(k)
        pred = self.anchor(x_c, t)
        x_v, nu_v = pred.orbit.state_and_anomaly(t + tau)
        if self.plan is not None and self.ancillary is not None:
            j = self.plan.sample(k)
            if j is not None:
                return self.ancillary.command(self.plan, j, float(nu_v), x_d)
            if self.plan.holds_target:
                return self.ancillary.hold(self.plan, float(nu_v), x_d, x_v)
            return ftre_control(self.ancillary.handoff_gains, float(nu_v), x_d, x_v, self.config.control.u_max_kmps2)
        return ftre_control(pred.gains, float(nu_v), x_d, x_v, self.config.control.u_max_kmps2)


def violation_masks(m: Margins, cfg: Config, thrust_limit_factor: float = 1.0) -> tuple[NDArray, NDArray, NDArray]:
    """Where the plant violates h1, h2 and h3 (three (N,) bool arrays; SPEC §9): normalised h1
    above ``constraints.plant_h1_tolerance``, h2 (against the thrust limit u_max times
    ``thrust_limit_factor``) above 1e-12 of that limit, h3 above
    ``constraints.plant_h3_tolerance_kmps``; where a constraint is not evaluated (NaN), never."""
    h1_bad, h3_bad = state_violations(m, cfg)
    return h1_bad, m.h2 > 1e-12 * cfg.control.u_max_kmps2 * thrust_limit_factor, h3_bad


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
    #: What the governor and the controller saw (measured states, before the SI round trip);
    #: None: the truth itself (the nominal truth measures exactly).
    x_d_seen: NDArray | None = None
    x_c_seen: NDArray | None = None
    #: |applied thrust| allowed on the truth: u_max times 1 + the declared bias bound (km/s^2).
    thrust_limit: float | None = None
    #: (K+1,) truth states violating h1 or h3 strictly between t_k and t_{k+1}, at the plant's
    #: substeps (:func:`between_violations`; last entry 0; NaN where unknown); None: not judged.
    between: NDArray | None = None
    #: Commands the ancillary tube's last guard saturated (None: not the ancillary tube).
    guard_saturations: int | None = None
    #: The ball (km, km/s) about the chief robust Verify certified for the final step once tau = 0
    #: took effect under the ancillary tube (:meth:`ClosedLoop.certified_ball`); None otherwise.
    dock_certified: tuple[float, float] | None = None

    @property
    def thrust_limit_factor(self) -> float:
        return 1.0 if self.thrust_limit is None else self.thrust_limit / self.config.control.u_max_kmps2

    def metrics(self) -> dict[str, Any]:
        """Per-run metrics (SPEC §6, §9), judged on the truth; margins are -h (>= 0 safe), h1
        normalised, h2 against the thrust limit on the truth."""
        cfg = self.config
        rel = self.x_d - self.x_c
        dist = np.linalg.norm(rel[:, :3], axis=1)
        speed = np.linalg.norm(rel[:, 3:], axis=1)
        m = self.margins
        h1_bad, h2_bad, h3_bad = violation_masks(m, cfg, self.thrust_limit_factor)
        violations = int(np.count_nonzero(h1_bad | h2_bad | h3_bad))
        between = self.between
        zero_idx = np.flatnonzero(self.tau == 0.0)
        tau_zero = bool(self.tau[-1] == 0.0)
        at_dock = docked(self.x_d, self.x_c, cfg)
        walls = np.array([r.wall_s for r in self.updates]) * 1e3
        active = np.array([r.wall_s for r in self.updates if r.active]) * 1e3
        cpu = np.array([r.cpu_s for r in self.updates]) * 1e3
        cpu_active = np.array([r.cpu_s for r in self.updates if r.active]) * 1e3
        # Wall and CPU times and Verify calls are unknown (NaN / None) in a run rebuilt from the
        # typed topics alone (a governor without governor_node's decision records).
        timed = all(math.isfinite(r.wall_s) for r in [self.initial, *self.updates])
        dv = cfg.control.period_s * float(np.sum(np.linalg.norm(self.u, axis=1)))
        h1n = m.h1_normalised[np.isfinite(m.h1_normalised)]
        h3 = m.h3[np.isfinite(m.h3)]
        docked_idx = np.flatnonzero(at_dock)
        return {
            "governor": self.governor,
            "success": bool(tau_zero and at_dock[-1] and violations == 0),
            "violations": violations,
            "violations_h1": int(np.count_nonzero(h1_bad)),
            "violations_h3": int(np.count_nonzero(h3_bad)),
            "violations_between": int(np.sum(between)) if between is not None
            and np.all(np.isfinite(between)) else None,
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
            "verify_calls": int(self.initial.verify_calls + sum(r.verify_calls for r in self.updates))
            if timed else None,
            "active_verify_calls_max": max((r.verify_calls for r in self.updates if r.active), default=0)
            if timed else None,
            "duration_s": float(self.t[-1] - self.t[0]),
            "dock_distance_m": cfg.mission.dock_distance_km * 1e3,
            "dock_speed_mps": cfg.mission.dock_speed_kmps * 1e3,
            "truth": cfg.truth.name,
            "truth_scale": cfg.truth.scale,
            "robust": cfg.tsg.robust,
            **({"corner": cfg.truth.corner} if cfg.truth.draw == "corner" else {}),
            **({"guard_saturations": self.guard_saturations} if self.guard_saturations is not None else {}),
            **({"dock_certified_m": self.dock_certified[0] * 1e3, "dock_certified_mps": self.dock_certified[1] * 1e3,
                "docked_certified": bool(dist[-1] <= self.dock_certified[0] and speed[-1] <= self.dock_certified[1])}
               if self.dock_certified is not None else {}),
        }

    def update_states(self, active_only: bool = True) -> list["UpdateState"]:
        """What the governor was given at each update (after the first instant) and its answer."""
        x_d = self.x_d if self.x_d_seen is None else self.x_d_seen
        x_c = self.x_c if self.x_c_seen is None else self.x_c_seen
        return update_states(self.config, self.t, x_d, x_c,
                             [(r.k, r.tau_prev, r.tau_s) for r in self.updates], active_only)


def state_violations(m: Margins, cfg: Config) -> tuple[NDArray, NDArray]:
    """(h1 violated, h3 violated) per row of the margins of truth states: beyond the plant's
    tolerances (a constraint not evaluated, NaN, is not violated)."""
    return (m.h1_normalised > cfg.constraints.plant_h1_tolerance,
            m.h3 > cfg.constraints.plant_h3_tolerance_kmps)


def between_violations(cfg: Config, x_d_path: NDArray, x_c_path: NDArray) -> int:
    """Truth states violating h1 or h3 strictly between two control samples: rows 1 .. S-1 of
    the deputy's and the chief's states at the plant's substeps (:meth:`Truth.deputy_path`,
    :meth:`Truth.chief_path`; the samples themselves, rows 0 and S, are judged as ``violations``).
    h2 is a property of the command, judged once per sample (:class:`StepJudge`, which the
    simulator calls with the sample's margins too)."""
    return StepJudge(cfg, 1.0)(x_d_path[0], x_c_path[0], np.zeros(3), x_d_path, x_c_path)[3]


class StepJudge:
    """What the simulator logs of each control step of the truth, in one compiled call: the
    margins of the state at t_k (as :func:`~cikan_ros.constraints.margins`, h2 against
    ``u_limit``) and :func:`between_violations` over the step's substeps."""

    def __init__(self, cfg: Config, u_limit: float) -> None:
        self.cp = constraint_params(cfg.constraints, u_limit, cfg.side)
        self.tol = (cfg.constraints.plant_h1_tolerance, cfg.constraints.plant_h3_tolerance_kmps)
        self.out = np.empty(4)

    def __call__(self, x_d: NDArray, x_c: NDArray, u: NDArray, x_d_path: NDArray,
                 x_c_path: NDArray) -> tuple[float, float, float, int]:
        """(normalised h1, h2 (km/s^2), h3 (km/s) at t_k, violations between the samples)."""
        bad = step_margins_kernel(np.asarray(x_d, dtype=float), np.asarray(x_c, dtype=float),
                                  np.asarray(u, dtype=float), x_d_path, x_c_path, self.cp, *self.tol, self.out)
        return float(self.out[1]), float(self.out[2]), float(self.out[3]), int(bad)


@dataclass(frozen=True)
class UpdateState:
    """One update: index k, time t (s since epoch), x_d, x_c (km, km/s, as the governor saw them,
    through SI), the previous shift tau_prev and the answer tau (s). Active when tau_prev != 0."""

    k: int
    t: float
    x_d: NDArray
    x_c: NDArray
    tau_prev: float
    tau: float

    @property
    def active(self) -> bool:
        return is_active(self.tau_prev)


def update_states(cfg: Config, t: NDArray, x_d: NDArray, x_c: NDArray,
                  updates: list[tuple[int, float, float]], active_only: bool = True
                  ) -> list[UpdateState]:
    """Update states of a run from its per-step arrays and its updates (k, tau_prev, tau): the
    one place that maps an update index to its control step and decides what is active."""
    per_update = round(cfg.tsg.update_period_s / cfg.control.period_s)
    out = []
    for k, tau_prev, tau in updates:
        if active_only and not is_active(tau_prev):
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


@dataclass(frozen=True)
class ShiftAudit:
    """A run's time shifts checked against the governor contract, independently of the governor.

    ``unverified``: steps where a shift took effect (a decision was due, or the shift changed)
    that is not known feasible: Verify from the recorded state rejects it, and it is not the
    previous verified shift held (feasible by recursive feasibility). ``off_schedule``: steps
    where the shift changed although no decision was due. ``decisions``: steps where one was due.
    """

    unverified: int
    off_schedule: int
    decisions: int


def audit_shifts(predictor: Predictor, x_d: NDArray, tau: NDArray, x_c: NDArray | None = None
                 ) -> ShiftAudit:
    """Audit the shift in force ``tau`` (K+1,) (NaN: none yet) against the deputy states ``x_d``
    (K+1, 6) as the governor saw them (a bag's states are; offline ones go through SI first),
    with the chief anchored on the chief states ``x_c`` it saw (None: the configured chief)."""
    loop = ClosedLoop(predictor)
    anchor = ChiefAnchor(predictor)
    unverified = off_schedule = decisions = 0
    prev: float | None = None
    prev_ok = False
    for k in range(min(len(tau) - 1, loop.n_steps)):   # the final state gets no shift
        if not math.isfinite(tau[k]):
            continue
        due = prev is None or loop.update_due(k)
        changed = prev is None or float(tau[k]) != prev
        decisions += due
        if not (due or changed):
            continue
        off_schedule += changed and not due
        t = loop.time(k)
        pred = predictor if x_c is None else anchor(x_c[k], t)
        ok = (not changed and prev_ok) or (pred.side * tau[k] >= 0.0 and pred.verify(x_d[k], t, float(tau[k])))
        unverified += not ok
        prev, prev_ok = float(tau[k]), ok
    return ShiftAudit(int(unverified), int(off_schedule), int(decisions))


def run_mission(governor: Governor, x_d0: NDArray, seed: int | None = None,
                truth: Truth | None = None, progress: bool = False) -> MissionResult:
    """Closed loop from the true deputy state x_d0 at t = 0 for T_sim: the :class:`ClosedLoop`
    step on the states the :class:`Truth` of ``seed`` measures, the truth stepped under the
    applied thrust (ZOH). The governor and the controller see what crosses the ROS boundary (SI
    and back), as the nodes do; violations, docking and Delta-V are judged on the truth. A
    ``truth`` given (e.g. pinned to a corner) is flown instead of the seed's draw.
    ``progress``: show a progress bar over the steps (:mod:`cikan_ros.progress`).
    """
    pred = governor.predictor
    cfg = pred.config
    loop = ClosedLoop(pred)
    governor.anchor.reset()  # each mission starts on the configured chief
    x = np.array(x_d0, dtype=float)
    check_states(x, "initial deputy state")
    truth = truth or Truth(cfg, seed, loop.n_steps)
    tc = cfg.control.period_s
    n_steps = loop.n_steps
    t = loop.times()
    x_c = truth.chief[: n_steps + 1]
    x_d = np.empty((n_steps + 1, 6))
    seen_d = np.empty((n_steps + 1, 6))
    seen_c = np.empty((n_steps + 1, 6))
    u = np.zeros((n_steps + 1, 3))
    between = np.zeros(n_steps + 1)
    taus = np.empty(n_steps + 1)
    updates: list[UpdateRecord] = []
    update_t: list[float] = []
    first: UpdateRecord | None = None
    tau: float | None = None
    with Bar(n_steps, "cikan mission", "steps", progress) as bar:
        for k in range(n_steps):
            seen_d[k] = truth.measure_deputy(k, x)[0]
            seen_c[k] = truth.measure_chief(k)
            x_seen, xc_seen = through_si(seen_d[k]), through_si(seen_c[k])
            loop.observe(k, xc_seen, tau)
            rec = loop.decide(governor, k, x_seen, xc_seen, tau)
            if rec is not None:
                if first is None:
                    first = rec
                else:
                    updates.append(rec)
                    update_t.append(float(t[k]))
                if rec.tau_s != tau:
                    loop.take_effect(k, rec.tau_s, x_seen)
                tau = rec.tau_s
            x_d[k] = x
            taus[k] = tau
            u[k] = truth.applied_thrust(through_si(loop.command(k, tau, x_seen, xc_seen)))
            path = truth.deputy_path(k, x, u[k])
            between[k] = between_violations(cfg, path, truth.chief_path(k))
            x = path[-1]
            bar.advance()
    x_d[-1] = x
    taus[-1] = tau
    seen_d[-1] = truth.measure_deputy(n_steps, x)[0]
    seen_c[-1] = truth.measure_chief(n_steps)
    limit = cfg.thrust_limit_kmps2
    m = margins(x_d, x_c, u, cfg.constraints, limit, cfg.side)
    m.h2[-1] = math.nan  # no command is applied at the final instant
    nominal = truth.nominal
    # judged in the truth's configuration: the governor's, and how the truth drew its errors
    return MissionResult(truth.config, governor.name, t, x_d, x_c, u, taus, m, first, np.array(update_t),
                         updates, None if nominal else seen_d, None if nominal else seen_c, limit,
                         between, None if loop.ancillary is None else loop.ancillary.guard_saturations,
                         loop.certified_ball(n_steps))
