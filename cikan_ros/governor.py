"""The Governor interface and the conventional (optimal) Time Shift Governor.

A governor answers, at update time t_k, the time shift tau_k <= 0 for the deputy state x_d and
chief state x_c, given the previous shift tau_{k-1}; with the answer comes a record of what it did.
The learned governor (Algorithm 1, ``cikan_ros.learn``) implements the same protocol.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from numpy.typing import ArrayLike

from .config import Config
from .tsg import Predictor

#: Decision paths, as published in /tsg/time_shift ``source`` and kept in mission records.
PATH_INITIAL = "initial"        # first-instant search
PATH_ZERO = "zero"              # tau_prev = 0: answer 0 without prediction (recursive feasibility)
PATH_VERIFY_ZERO = "verify-zero"  # tau = 0 passed Verify
PATH_BISECT = "bisect"          # bisection over [tau_prev, 0]
PATH_NN = "nn"                  # network proposal passed Verify
PATH_NN_BISECT = "nn+bisect"    # network proposal failed Verify; bisection over [tau_prev, tau_nn]
PATH_KEEP = "keep"              # keep rule: tau_prev kept without prediction (no progress proposed)
PATH_PROBE = "probe"            # keep rule: budgeted bisection over [tau_prev, 0] on schedule


def update_index(t: float, update_period_s: float) -> int:
    """k of the update at time t (s since the mission epoch): updates fall at t = k P_upd."""
    return int(round(t / update_period_s))


@dataclass(frozen=True)
class UpdateRecord:
    """One governor decision: the shift (s), the path taken, Verify calls, wall time (s), the
    update index k (0 at the first instant) and the shift tau_{k-1} it started from (NaN at k = 0).

    An update is *active* when tau_{k-1} < 0: the states where a governor decides something
    (SPEC §9); with tau_{k-1} = 0 the answer is 0 without prediction."""

    tau_s: float
    path: str
    verify_calls: int
    wall_s: float
    k: int = 0
    tau_prev: float = math.nan

    @property
    def active(self) -> bool:
        return self.tau_prev < 0.0


@runtime_checkable
class Governor(Protocol):
    """What the mission loop and the governor node need from a governor."""

    name: str
    predictor: Predictor

    def initial(self, x_d: ArrayLike, x_c: ArrayLike, t: float) -> UpdateRecord:
        """First shift at the mission start (raises NoFeasibleShiftError if there is none)."""
        ...

    def update(self, x_d: ArrayLike, x_c: ArrayLike, t: float, tau_prev: float) -> UpdateRecord:
        """Shift at update time t (s since epoch) with previous shift tau_prev <= 0 (s)."""
        ...


def initial_update(predictor: Predictor, x_d: ArrayLike, t: float) -> UpdateRecord:
    """The first-instant search (SPEC §5) as a timed record; every governor starts with it."""
    start = time.perf_counter()
    tau, calls = predictor.initial_shift(x_d, t)
    return UpdateRecord(tau, PATH_INITIAL, calls, time.perf_counter() - start,
                        update_index(t, predictor.config.tsg.update_period_s))


class ConventionalGovernor:
    """The optimal TSG pi*: zero test, then bisection to the tolerance over [tau_prev, 0]."""

    name = "conventional"

    def __init__(self, predictor: Predictor) -> None:
        self.predictor = predictor

    @classmethod
    def from_config(cls, cfg: Config) -> "ConventionalGovernor":
        return cls(Predictor.from_config(cfg))

    def initial(self, x_d: ArrayLike, x_c: ArrayLike, t: float) -> UpdateRecord:
        return initial_update(self.predictor, x_d, t)

    def update(self, x_d: ArrayLike, x_c: ArrayLike, t: float, tau_prev: float) -> UpdateRecord:
        start = time.perf_counter()
        tau, calls = self.predictor.optimal_shift(x_d, t, tau_prev)
        path = PATH_ZERO if calls == 0 else PATH_VERIFY_ZERO if tau == 0.0 else PATH_BISECT
        return UpdateRecord(tau, path, calls, time.perf_counter() - start,
                            update_index(t, self.predictor.config.tsg.update_period_s), tau_prev)


#: Names of the learned model families shipped in ``models/`` (see ``cikan_ros.learn``).
LEARNED_NAMES = ("cikan", "grbf", "rswaf", "relu", "gelu")
GOVERNOR_NAMES = ("conventional",) + LEARNED_NAMES


def make_governor(name: str, cfg: Config, predictor: Predictor | None = None) -> Governor:
    """The governor called ``name``: "conventional", a shipped model family, or a model path.

    Learned governors (Algorithm 1) come from ``cikan_ros.learn``; their files are checked on
    load and a bad file raises a CikanError naming the problem.
    """
    predictor = predictor or Predictor.from_config(cfg)
    if name == "conventional":
        return ConventionalGovernor(predictor)
    from .learn.governor import load_learned_governor  # torch is imported only when needed

    return load_learned_governor(name, predictor)
