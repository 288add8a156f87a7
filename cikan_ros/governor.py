"""The Governor interface and the conventional (optimal) Time Shift Governor.

A governor answers, at update time t_k, the time shift tau_k (<= 0 behind the chief, >= 0 ahead) for the deputy state x_d and
chief state x_c, given the previous shift tau_{k-1}; with the answer comes a record of what it did.
The learned governor (Algorithm 1, ``cikan_ros.learn``) implements the same protocol; governors are
made by name in :mod:`cikan_ros.registry` (this module never imports ``learn/``).
"""

from __future__ import annotations

import gc
import math
import time
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from numpy.typing import ArrayLike

from .config import Config
from .errors import NoFeasibleShiftError
from .tsg import ChiefAnchor, Predictor

#: Decision paths, as published in /tsg/time_shift ``source`` and kept in mission records.
PATH_INITIAL = "initial"        # first-instant search
PATH_ZERO = "zero"              # tau_prev = 0: answer 0 without prediction (recursive feasibility)
PATH_VERIFY_ZERO = "verify-zero"  # tau = 0 passed Verify
PATH_BISECT = "bisect"          # bisection over [tau_prev, 0]
PATH_NN = "nn"                  # network proposal passed Verify
PATH_NN_BISECT = "nn+bisect"    # network proposal failed Verify; bisection over [tau_prev, tau_nn]
PATH_KEEP = "keep"              # keep rule: tau_prev kept without prediction (no progress proposed)
PATH_PROBE = "probe"            # keep rule: budgeted bisection over [tau_prev, 0] on schedule
PATH_SEARCH = "search"          # keep rule, network not trusted: the conventional TSG's pi*
PATH_AUDIT = "audit"            # keep rule: the scheduled audit found the answer lagging and took the audited shift
PATH_STALL = "stall"            # keep rule: tau held for learned.stall_updates updates; the conventional TSG's pi*
PATH_TAIL = "tail"              # keep rule, robust Verify, |tau_prev| <= learned.robust_tail_s: the conventional TSG's pi*
PATH_GALLOP = "gallop"          # keep rule, robust Verify's tail: a search around the last update's progress (learned.tail_rule)
PATH_SEARCH_HOLD = "search-hold"      # keep rule, not trusted, learned.search_rule "hold-first": none passed, tau_prev held
PATH_SEARCH_LADDER = "search-ladder"  # keep rule, not trusted, "hold-first": the first of its candidates that passed
#: Paths of a learned update the network did not decide because it was not trusted or a search was
#: due (the "searching" share of a learned governor's updates).
SEARCHING_PATHS = (PATH_SEARCH, PATH_STALL, PATH_TAIL, PATH_SEARCH_HOLD, PATH_SEARCH_LADDER)


Clock = tuple[float, float]


def start_clock() -> Clock:
    """Wall and thread-CPU start times of one decision (for :func:`make_record`)."""
    return time.perf_counter(), time.thread_time()


def make_record(started: Clock, tau: float, path: str, calls: int, k: int = 0,
                tau_prev: float = math.nan) -> UpdateRecord:
    """The record of a decision started at ``started`` (wall and CPU time until now)."""
    return UpdateRecord(tau, path, calls, time.perf_counter() - started[0], k, tau_prev,
                        time.thread_time() - started[1])


def update_index(t: float, update_period_s: float) -> int:
    """k of the update at time t (s since the mission epoch): updates fall at t = k P_upd."""
    return int(round(t / update_period_s))


def is_active(tau_prev: float) -> bool:
    """An update searches when its previous shift is set and away from 0 (either side of the
    chief); the first instant (tau_prev NaN) and tau_prev = 0 do not."""
    return tau_prev != 0.0 and not math.isnan(tau_prev)


@dataclass(frozen=True)
class UpdateRecord:
    """One governor decision: the shift (s), the path taken, Verify calls, wall time (s), the
    update index k (0 at the first instant) and the shift tau_{k-1} it started from (NaN at k = 0).

    An update is *active* when tau_{k-1} < 0: the states where a governor decides something
    (SPEC §9); with tau_{k-1} = 0 the answer is 0 without prediction. ``cpu_s`` is the CPU time
    of the deciding thread: unlike ``wall_s`` it does not count time spent waiting for a core on
    a loaded machine, so campaign statistics use it."""

    tau_s: float
    path: str
    verify_calls: int
    wall_s: float
    k: int = 0
    tau_prev: float = math.nan
    cpu_s: float = math.nan

    @property
    def active(self) -> bool:
        """The update searched (a previous shift away from 0, on either side of the chief)."""
        return is_active(self.tau_prev)


@runtime_checkable
class Governor(Protocol):
    """What the mission loop and the governor node need from a governor."""

    name: str
    predictor: Predictor
    anchor: ChiefAnchor

    def initial(self, x_d: ArrayLike, x_c: ArrayLike, t: float) -> UpdateRecord:
        """First shift at the mission start (raises NoFeasibleShiftError if there is none)."""
        ...

    def update(self, x_d: ArrayLike, x_c: ArrayLike, t: float, tau_prev: float) -> UpdateRecord:
        """Shift at update time t (s since epoch) with previous shift tau_prev (s; <= 0 behind
        the chief, >= 0 ahead of it)."""
        ...


def initial_update(anchor: ChiefAnchor, x_d: ArrayLike, x_c: ArrayLike, t: float) -> UpdateRecord:
    """The first-instant search (SPEC §5) from the measured chief x_c, as a timed record; every
    governor starts with it."""
    started = start_clock()
    predictor = anchor(x_c, t)
    tau, calls = predictor.initial_shift(x_d, t)
    return make_record(started, tau, PATH_INITIAL, calls,
                       update_index(t, predictor.config.tsg.update_period_s))


class ConventionalGovernor:
    """The optimal TSG pi*: zero test, then bisection to the tolerance over [tau_prev, 0]."""

    name = "conventional"

    def __init__(self, predictor: Predictor) -> None:
        self.predictor = predictor
        self.anchor = ChiefAnchor(predictor)

    @classmethod
    def from_config(cls, cfg: Config) -> "ConventionalGovernor":
        return cls(Predictor.from_config(cfg))

    def initial(self, x_d: ArrayLike, x_c: ArrayLike, t: float) -> UpdateRecord:
        return initial_update(self.anchor, x_d, x_c, t)

    def update(self, x_d: ArrayLike, x_c: ArrayLike, t: float, tau_prev: float) -> UpdateRecord:
        started = start_clock()
        # tau_prev = 0 predicts nothing: the chief is anchored only on updates that predict.
        pred = self.predictor if tau_prev == 0.0 else self.anchor(x_c, t)
        tau, calls = pred.optimal_shift(x_d, t, tau_prev)
        path = PATH_ZERO if calls == 0 else PATH_VERIFY_ZERO if tau == 0.0 else PATH_BISECT
        return make_record(started, tau, path, calls,
                           update_index(t, self.predictor.config.tsg.update_period_s), tau_prev)


def warm_up(governor: Governor, x_d: ArrayLike, x_c: ArrayLike, t: float = 0.0) -> None:
    """Prepare a process to fly a governor: compile or load every kernel its decisions use
    (first-instant search, Verify, bisection, the network) by deciding once at a representative
    state (answers discarded), then move every object alive so far out of the garbage
    collector's reach (``gc.freeze``). Measured: with torch and the kernels loaded, a full
    collection took 65-85 ms and landed inside an update now and then; after the freeze only
    objects made later are scanned."""
    pred = governor.predictor
    try:
        tau0 = pred.side * max(abs(governor.initial(x_d, x_c, t).tau_s), pred.config.tsg.tolerance_s)
    except NoFeasibleShiftError:  # robust Verify may refuse this state: the kernels compiled anyway
        tau0 = pred.side * 10.0
    t1 = t + pred.config.tsg.update_period_s
    # Every kernel entry point a decision may take (the update itself may take only one path).
    pred.verify(x_d, t1, tau0)
    pred.bisect(x_d, t1, tau0, 0.0, budget=1)
    pred.first_feasible(x_d, t1, [0.0], tau0, 1)
    pred.gallop(x_d, t1, tau0, 0.5, 2.0, 1)
    pred.optimal_shift(x_d, t1, tau0)
    governor.update(x_d, x_c, t1, tau0)
    # The warm-up's anchoring is part of no mission: x_c is not the chief at t1, so the update
    # re-anchored on it; a governor left so flew its mission on that osculating orbit, not the
    # configured one (GEO: another first shift than the offline loop's).
    governor.anchor.reset()
    gc.collect()
    gc.freeze()
