"""Update states and per-update timing shared by the sections of ``cikan bench``.

Below ``cikan_ros.bench`` (the conventional TSG's sections), ``cikan_ros.learn.bench`` (the
learned governors' section) and ``cikan_ros.commands.bench`` (``cikan bench``: every section, the
ROS one included), so that ``learn/`` never reaches ``ros/`` through the benchmark. Every timing
goes through :func:`thread_timed` (one call) or :func:`median_thread_time` (the median of repeats).

States come from conventional-TSG missions flown under the configuration being benchmarked
(truth and Verify): the nominal start (truth seed None, as ``cikan mission``) and the Monte
Carlo starts of seeds 1..N-1 (truth seed = the start's seed, as ``cikan montecarlo``). Under a
non-nominal truth the states are what the governor saw: measured deputy and chief states.

Chief anchoring. A governor anchors its chief prediction on the measured chief state it
receives (:class:`cikan_ros.tsg.ChiefAnchor`); under a J2 truth the measured chief leaves the
anchored Kepler orbit between two updates, so every active update of a mission re-anchors and
pays for a new chief table. The timed updates pay for it as a mission does: before every timed
call (every repeat, every governor) the governor's anchor is set back, untimed, to the chief
orbit the mission's governor held just before that update (``BenchStates.priors``, recorded
while the missions flew). The anchor is therefore neither left on the state's own chief between
repeats (which would make repeats 2..n skip the re-anchoring, and the median hide it) nor carried
from one benchmark state to the next (whose chief is not the mission's previous one). Under a
two-body truth the recorded prior is the configured chief (None) and the anchor stays on the
governor's own predictor, whose chief table the updates share, as before the truth model.
A prior other than the configured chief gets a fresh predictor per timed call, whose chief table
is empty: that is the mission's cost whenever the update re-anchors (always, under J2); an update
that would not re-anchor from such a prior (none under the shipped truths) would be charged the
table fill that the mission had partly paid at the previous update.

Update times are the CPU time of the calling thread (``time.thread_time``): on a shared machine
wall time also counts the time the process waits for a core (SPEC §9: compare ratios from one run).
"""

from __future__ import annotations

import functools
import math
import statistics
import time
from dataclasses import dataclass, field
from typing import Any, Callable, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .config import Config, truth_overrides
from .errors import CikanError, NoFeasibleShiftError
from .governor import ConventionalGovernor, Governor, UpdateRecord
from .mission import UpdateState, nominal_start, run_mission, sample_start
from .orbit import KeplerOrbit

T = TypeVar("T")


def thread_timed(fn: Callable[..., T], *args: Any) -> tuple[T, float]:
    """``fn(*args)`` and the CPU time (s) the calling thread spent in it (``time.thread_time``)."""
    start = time.thread_time()
    out = fn(*args)
    return out, time.thread_time() - start


def median_thread_time(fn: Callable[..., T], *args: Any, repeats: int,
                       setup: Callable[[], object] | None = None) -> tuple[float, T]:
    """The median over ``repeats`` calls of ``fn(*args)`` of its thread CPU time (s), each call
    preceded by ``setup()`` (untimed) when given, and the first call's result."""
    runs = []
    for _ in range(repeats):
        if setup is not None:
            setup()
        runs.append(thread_timed(fn, *args))
    return statistics.median(cpu for _, cpu in runs), runs[0][0]


@dataclass
class BenchStates:
    """Update states of a fixed set of conventional missions, plus their start states."""

    updates: list[UpdateState]
    starts: list[NDArray]
    mission_wall_s: list[float]
    #: Per update state: the chief orbit the mission governor's anchor held before that update
    #: (None: the configured chief); see the module docstring.
    priors: list[KeplerOrbit | None] = field(default_factory=list)
    #: Chief re-anchors of the mission governor (first-instant search and updates) per mission,
    #: and its anchor calls (the first instant and every update with tau_prev != 0).
    mission_re_anchors: list[int] = field(default_factory=list)
    mission_anchor_calls: list[int] = field(default_factory=list)
    #: Seeds whose start has no feasible first shift under this configuration (not flown).
    infeasible_seeds: list[int | None] = field(default_factory=list)
    #: The deputy state the governor saw at each start (measured; the start itself under the
    #: nominal truth): what the first-instant search is timed on.
    first_seen: list[NDArray] = field(default_factory=list)
    #: Per update state: the mission's last progress before it, 1 - tau_{k-1} / tau_{k-2} of its
    #: last update that moved tau (NaN: none yet), what a learned governor's rule for robust
    #: Verify's tail remembers (:func:`prime`).
    progress: list[float] = field(default_factory=list)
    #: Per update state: the index of its mission in ``starts`` (the states of a mission are
    #: consecutive).
    mission: list[int] = field(default_factory=list)
    #: Conventional TSG per-state wall times (s), filled by ``conventional_section`` (runs first)
    #: so later sections report speed-ups measured in the same run on the same states.
    conventional_walls: NDArray | None = None
    conventional_taus: NDArray | None = None

    def __post_init__(self) -> None:
        if not self.priors:
            self.priors = [None] * len(self.updates)
        if not self.mission:
            self.mission = [0] * len(self.updates)

    @property
    def n_missions(self) -> int:
        """Missions asked for: flown, or with an infeasible start."""
        return len(self.starts) + len(self.infeasible_seeds)

    @property
    def seeds(self) -> list[int | None]:
        """The seed of each start flown, in the order of ``starts`` (None: the nominal start)."""
        return [s for s in [None] + list(range(1, self.n_missions)) if s not in self.infeasible_seeds]


def is_nominal(cfg: Config) -> bool:
    """True when the configuration flies the nominal truth with nominal Verify: the benchmark
    of the paper's setting, whose report keeps its keys as they were."""
    return cfg.truth.is_nominal and not cfg.tsg.robust


def nominal_config(cfg: Config) -> Config:
    """``cfg`` with the shipped nominal truth and nominal Verify (everything else unchanged)."""
    return cfg.replace(**truth_overrides("nominal"), **{"tsg.robust": False})


class _AnchorRecorder:
    """A governor that forwards to ``gov`` and notes, per update time, the chief orbit its
    anchor held before the update (None: the configured chief)."""

    def __init__(self, gov: Governor) -> None:
        self.gov = gov
        self.name = gov.name
        self.predictor = gov.predictor
        self.anchor = gov.anchor
        self.before: dict[float, KeplerOrbit | None] = {}
        self.calls = 0

    def initial(self, x_d: ArrayLike, x_c: ArrayLike, t: float) -> UpdateRecord:
        self.calls += 1
        return self.gov.initial(x_d, x_c, t)

    def update(self, x_d: ArrayLike, x_c: ArrayLike, t: float, tau_prev: float) -> UpdateRecord:
        a = self.anchor
        self.before[float(t)] = None if a.current is a.base else a.current.orbit
        self.calls += tau_prev != 0.0
        return self.gov.update(x_d, x_c, t, tau_prev)


def collect_states(cfg: Config, n_missions: int = 6) -> BenchStates:
    """Fly ``n_missions`` conventional missions under ``cfg`` (nominal start with truth seed
    None, then Monte Carlo seeds 1, 2, ... with truth seed = start seed) and keep the inputs of
    every active update, with the anchor each update started from. A start with no feasible
    first shift (robust Verify may reject a start nominal Verify accepts) is noted, not flown."""
    gov = ConventionalGovernor.from_config(cfg)
    pred = gov.predictor
    anchor = gov.anchor
    try:
        run_mission(gov, nominal_start(pred))  # compile (or load cached) kernels before timing
    except NoFeasibleShiftError:
        pass   # compiled all the same; robust Verify refuses this start (noted below)
    out = BenchStates([], [], [])
    for i in range(n_missions):
        seed = None if i == 0 else i
        x0 = nominal_start(pred) if seed is None else sample_start(pred, seed)
        anchor.current, anchor.re_anchors = anchor.base, 0  # each mission starts on the configured chief
        rec = _AnchorRecorder(gov)
        start = time.perf_counter()
        try:
            res = run_mission(rec, x0, seed)  # type: ignore[arg-type]
        except NoFeasibleShiftError:
            out.infeasible_seeds.append(seed)
            continue
        out.mission_wall_s.append(time.perf_counter() - start)
        out.starts.append(x0)
        out.first_seen.append(x0 if res.x_d_seen is None else res.x_d_seen[0])
        out.mission_re_anchors.append(anchor.re_anchors)
        out.mission_anchor_calls.append(rec.calls)
        progress, before = math.nan, None
        for s in res.update_states():
            if before is not None and s.tau_prev != before:
                progress = 1.0 - s.tau_prev / before
            before = s.tau_prev
            out.updates.append(s)
            out.priors.append(rec.before[s.t])
            out.progress.append(progress)
            out.mission.append(len(out.starts) - 1)
    anchor.current = anchor.base
    if len(out.infeasible_seeds) == n_missions:
        raise EveryStartRefusedError(
            f"Verify refuses all {n_missions} starts (the nominal start and {n_missions - 1} Monte Carlo "
            f"starts: no feasible first shift); nothing to time")
    if not out.updates:
        raise CikanError(f"cikan bench: no active update state in {n_missions} missions "
                         f"({len(out.infeasible_seeds)} starts without a feasible first shift)")
    return out


class EveryStartRefusedError(NoFeasibleShiftError):
    """Verify (robust Verify, typically) refuses every start of a benchmark: a result of the
    configuration (``cikan bench`` reports it as such), not a failure of the benchmark."""


def prime(governor: Governor, prior: KeplerOrbit | None, progress: float = math.nan) -> None:
    """Set what a governor carries from the mission's earlier updates to what the mission's
    governor held before this one: the chief anchor (:func:`prime_anchor`) and, for a learned
    governor, the last progress its rule for robust Verify's tail starts from. So every timed
    repeat of an update does the same work, whatever was timed before it. Untimed."""
    prime_anchor(governor, prior)
    remember = getattr(governor, "remember_progress", None)
    if remember is not None:
        remember(progress)


def prime_anchor(governor: Governor, prior: KeplerOrbit | None) -> None:
    """Set the governor's chief anchor to what a mission's held before the update (module
    docstring): its own predictor for the configured chief (None), else a fresh predictor on
    ``prior``. Untimed."""
    a = governor.anchor
    a.current = a.base if prior is None else a.base.with_orbit(prior)


def timed_update(governor: Governor, s: UpdateState, prior: KeplerOrbit | None = None,
                 progress: float = math.nan) -> tuple[UpdateRecord, float]:
    """One update at state s, the anchor first set to ``prior`` and the tail's last progress to
    ``progress`` (:func:`prime`, untimed), and its CPU time (s) in this thread: the anchoring,
    any re-anchoring and chief-table fill included."""
    prime(governor, prior, progress)
    return thread_timed(governor.update, s.x_d, s.x_c, s.t, s.tau_prev)


def time_updates(governor: Governor, states: BenchStates, repeats: int = 3,
                 then: Callable[[int, UpdateRecord], None] | None = None
                 ) -> tuple[NDArray, NDArray, list[str], NDArray, NDArray]:
    """Per state: median CPU time (s) of ``repeats`` updates, tau, path, Verify calls, and
    whether the (first) update re-anchored the chief. ``then(i, record)``, if given, runs after
    state i is timed (what is timed beside the updates, state by state, sees the same machine)."""
    n = len(states.updates)
    walls, taus, calls, re_anchored = np.empty(n), np.empty(n), np.empty(n), np.zeros(n, dtype=bool)
    paths: list[str] = []
    for i, (s, prior) in enumerate(zip(states.updates, states.priors)):
        before = governor.anchor.re_anchors
        walls[i], rec = median_thread_time(governor.update, s.x_d, s.x_c, s.t, s.tau_prev, repeats=repeats,
                                           setup=functools.partial(prime, governor, prior, states.progress[i]))
        re_anchored[i] = governor.anchor.re_anchors > before
        taus[i] = rec.tau_s
        calls[i] = rec.verify_calls
        paths.append(rec.path)
        if then is not None:
            then(i, rec)
    governor.anchor.current = governor.anchor.base
    return walls, taus, paths, calls, re_anchored


#: Chief offset (km, km/s) that makes the anchor re-anchor in :func:`anchoring_figures`.
_OFFSET_KM = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])


def anchoring_figures(governor: ConventionalGovernor, states: BenchStates, repeats: int
                      ) -> dict[str, Any]:
    """What re-anchoring the chief costs, on the benchmark states (conventional TSG, CPU times,
    median of ``repeats`` per state, mean over states):

    - ``anchor_ms_mean``: one ``ChiefAnchor`` call that re-anchors (tolerance test, osculating
      orbit of the measured chief, new predictor); ``anchor_check_ms_mean``: one that does not
      (the tolerance test alone, the anchor already on the state's chief);
    - ``verify_cold_ms_mean``: Verify at tau_prev (a full rollout) right after re-anchoring,
      filling the new chief table; ``verify_ms_mean``: the same Verify again (table filled);
    - ``conventional_update_anchored_ms_mean`` / ``_max``: the update with the anchor already on
      the state's chief and its table filled (no re-anchoring): the update without the cost;
      ``re_anchor_cost_ms_mean``: the mission-like update mean minus that mean (filled in by
      the caller, which has both).
    """
    a = governor.anchor

    def aim(orbit: KeplerOrbit) -> None:
        a.current = a.base.with_orbit(orbit)

    anchor_ms, check_ms, cold_ms, warm_ms, upd_ms = [], [], [], [], []
    for s in states.updates:
        off = KeplerOrbit.from_state(np.asarray(s.x_c) + _OFFSET_KM, s.t, a.base.orbit.mu)
        # 1 km off the state's chief before each call: every call re-anchors.
        cpu, pred = median_thread_time(a, s.x_c, s.t, repeats=repeats, setup=functools.partial(aim, off))
        anchor_ms.append(cpu)
        check_ms.append(median_thread_time(a, s.x_c, s.t, repeats=repeats)[0])
        cold, warm = [], []
        for _ in range(repeats):
            fresh = a.base.with_orbit(pred.orbit)
            cold.append(thread_timed(fresh.verify, s.x_d, s.t, s.tau_prev)[1])
            warm.append(thread_timed(fresh.verify, s.x_d, s.t, s.tau_prev)[1])
        cold_ms.append(statistics.median(cold))
        warm_ms.append(statistics.median(warm))
        a.current = pred
        governor.update(s.x_d, s.x_c, s.t, s.tau_prev)  # fills the table (untimed)
        upd_ms.append(median_thread_time(governor.update, s.x_d, s.x_c, s.t, s.tau_prev, repeats=repeats)[0])
    a.current = a.base
    upd = np.array(upd_ms)
    return {
        "anchor_ms_mean": float(np.mean(anchor_ms) * 1e3),
        "anchor_check_ms_mean": float(np.mean(check_ms) * 1e3),
        "verify_cold_ms_mean": float(np.mean(cold_ms) * 1e3),
        "verify_ms_mean": float(np.mean(warm_ms) * 1e3),
        "conventional_update_anchored_ms_mean": float(upd.mean() * 1e3),
        "conventional_update_anchored_ms_max": float(upd.max() * 1e3),
    }
