"""Learned Time Shift Governors: a network π̃_θ proposes the shift, Verify checks it (SPEC §8).

Two update rules, chosen by ``learned.algorithm``; both start from the conventional initial search
and share the zero rule (τ_prev = 0 -> 0 with no prediction, path "zero") and the final zero test
(τ < 0, |τ| <= tsg.zero_snap_s and Verify(0) -> 0, path "verify-zero"). τ_c is the network's
proposal -exp(NN) on the nanosecond grid (NaN when the output is not finite or out of range).

``keep`` (default; k = round(t_k / P_upd), δ = learned.min_step_s, s_1 > ... > s_L =
learned.ladder, S = learned.probe_every, B = learned.fallback_budget, B_p = learned.probe_budget;
the update is *scheduled* when k % S == 0; bisect_b = bisection that stops after b Verify calls
and returns its verified lower end, b = 0 meaning τ_prev). The candidates are the proposal made
more optimistic by each rung, c_i = τ_c (1 - s_i) on the nanosecond grid, and C = those with
τ_prev + δ <= c_i <= 0, in ladder order (closest to 0 first); C is empty when τ_c moves τ by less
than ρ |τ_prev| (ρ = learned.min_progress)::

  C not empty (the ladder proposes progress):
      Verify(c_1), Verify(c_2), ... -> the first c_i that passes                    [path "nn"]
      none passes                 -> bisect_b(lo = τ_prev, hi = last c_i),
                                     b = B_p if scheduled else B          [path "nn+bisect" or "keep"]
  C empty (no progress proposed, or τ_c unusable):
      not scheduled               -> τ_prev, no prediction                          [path "keep"]
      scheduled                   -> bisect_{B_p}(lo = τ_prev, hi = 0)              [path "probe"]

The trust (:class:`Trust`) and the stall rule wrap this: an untrusted network's updates are the
conventional TSG's (path "search"), and after learned.stall_updates trusted updates in a row
that held τ_prev the next one is too (path "stall"); the audit checks the answer and judges the
network (path "audit"; docs/learned_update_rule.md). Under robust Verify every update with
|τ_prev| <= learned.robust_tail_s is answered before the trust (``learned.tail_rule``): by a
network of the step's candidates (path "nn"), else a search around the last update's progress
(path "gallop"), or by the conventional search (path "tail"), and
a scheduled update with |τ_prev| <= tsg.zero_snap_s probes with it, before the ladder. In the code
(:meth:`LearnedGovernor._keep`) the steps are one method each, in this order: ``_robust_tail``
(then ``_tail``),
``_search`` (the trust), ``_stall``, ``_last_approach``, ``_ladder_step``, ``_probe``,
``_audit``, ``_judge``.

The ladder exists because a failed Verify is cheap (it stops at the first violation) and the
networks' proposals are biased low: trying an optimistic candidate first keeps τ near π*, and
with it the time to τ = 0 and the ΔV, at less cost than a search (docs/learned_update_rule.md).
``ladder: [0]`` is the plain proposal.

``paper`` (the paper's Algorithm 1)::

  τ_prev <= τ_c <= 0: Verify(τ_c) -> τ_c [path "nn"], else bisect(τ_prev, τ_c) [path "nn+bisect"]
  otherwise                       -> bisect(τ_prev, 0)                              [path "bisect"]

Safety (both rules): the answer passed Verify or equals τ_prev, which recursive feasibility keeps
feasible (SPEC §5; the conventional bisection relies on the same unverified lower end). The keep
rule's cost is bounded: one forward plus at most L + max(B, B_p) Verify calls, plus the zero
test. Progress: whatever the network outputs, every S-th update either moves by a verified
proposal or searches below it or over [τ_prev, 0] with B_p calls, so τ cannot stall.

No torch here: the network runs through :class:`cikan_ros.learn.arch.NumpyNet`.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any, Callable, Iterable

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..config import Config, Side, scenario_names, truth_names
from ..governor import (PATH_AUDIT, PATH_BISECT, PATH_GALLOP, PATH_INITIAL, PATH_KEEP, PATH_NN, PATH_NN_BISECT,
                        PATH_PROBE, PATH_SEARCH, PATH_SEARCH_HOLD, PATH_SEARCH_LADDER, PATH_STALL, PATH_TAIL,
                        PATH_VERIFY_ZERO, PATH_ZERO, SEARCHING_PATHS, UpdateRecord,
                        initial_update, make_record, start_clock, update_index)
from ..tsg import ChiefAnchor, ChiefCache, Predictor, quantise_shift
from ..units import ns_to_seconds, seconds_to_ns as to_ns
from .arch import FAMILIES, NumpyNet, log_shift_kernel
from .errors import ModelFileError
from .features import FEATURE_CODES
from .modelfile import CARD, LoadedModel, flown_model_dir, label_mismatch, load_model, model_scenario

#: ln|τ| above this (|τ| > ~1.4e17 s) is treated like a non-finite output: out of range.
MAX_LOG_SHIFT = 40.0
#: The stall rule waits at most this many times learned.stall_updates holds between searches.
STALL_BACKOFF = 8
#: A searching governor's wait before it puts its network on probation again
#: (``learned.trust_retry``) grows up to this many times the configured wait.
RETRY_BACKOFF = 8
#: Gallop updates in a row that found no progress after which robust Verify's tail searches like
#: the conventional TSG (learned.tail_rule "gallop").
TAIL_MISSES = 2
#: Paths answered by the conventional TSG's search (its own zero test included).
SEARCHED = (PATH_SEARCH, PATH_STALL, PATH_TAIL)


def stall_miss(side: Side, tau_prev: float, tau: float, reach: float) -> bool:
    """Did a stall search's answer tau move beyond ``reach`` (a fraction of |tau_prev|) from
    tau_prev? reach 0: any progress. In magnitudes m = side · τ."""
    return side * tau < side * tau_prev * (1.0 - reach)


@nb.njit(cache=True)
def ladder_kernel(tau_c: float, tau_prev: float, side: int, ladder: NDArray, min_step_s: float,
                  min_progress: float, out_ns: NDArray) -> int:
    """The keep rule's candidates c_i = τ_c (1 - s_i) on the nanosecond grid (as
    :func:`quantise_shift`: half-even rounding) into ``out_ns`` (int64, >= len(ladder)), in ladder
    order, those with 0 <= |c_i| <= |τ_prev| - δ, without repeats; returns how many. None when
    τ_c is NaN or moves τ by less than ρ |τ_prev|. In magnitudes m = side · τ (s)."""
    m_prev = side * tau_prev
    if tau_c != tau_c or side * tau_c > m_prev * (1.0 - min_progress):
        return 0
    n = 0
    for s in ladder:
        ns = np.int64(np.rint(tau_c * (1.0 - s) * 1e9))
        m = side * (ns / 1e9)
        if 0.0 <= m <= m_prev - min_step_s and (n == 0 or m > side * (out_ns[n - 1] / 1e9)):
            out_ns[n] = ns
            n += 1
    return n


class Trust:
    """Whether the keep rule trusts the network (docs/learned_update_rule.md, "A network that
    does not fit"): a credit c in [0, cap].

    - c > 0: the network is trusted (the keep rule). Judged updates move c: a *miss* (the audit
      found the answer lagging π* by its reach, or a probe found progress the network did not
      propose) takes one credit, a *hit* (the audit found none) adds one, up to ``cap``. Below
      the cap the network is on probation: every update is audited, not only scheduled ones,
      so a network that does not fit loses trust at its first lagging answer.
    - c = 0: searching. Each update is the conventional TSG's π*; the proposal is judged
      against it for free (a *shadow* hit or miss, :meth:`LearnedGovernor.would_pay`), and
      ``hits`` consecutive shadow hits give back one credit (probation).

    - ``retry`` R > 0: after R searching updates in a row the network goes on probation again
      (c = 1) without the shadow hits; a retry that loses its credit before it reaches the cap
      doubles the wait (up to RETRY_BACKOFF x R), reaching the cap resets it. Shadow hits need
      π* to move beyond the audit's reach, which can be rare for many updates (the paper's
      orbit: a whole first phase searching after one miss); a failed retry costs one ladder
      and its audit, the update that loses the credit answering π* as a search does.

    A mission starts on probation (``start`` "network", c = 1) or searching ("search").
    Deterministic: a function of the mission's updates."""

    def __init__(self, cap: int, hits: int, start: str = "network", stall: int = 0, retry: int = 0) -> None:
        self.cap, self.need_hits, self.start, self.stall, self.retry = cap, hits, start, stall, retry
        self.credit = 0
        self.hits = 0
        #: Searching updates in a row, the wait before the next retry, and whether the
        #: current probation is a retry's (not earned by shadow hits) that has not reached the cap.
        self.searched = 0
        self.retry_wait = retry
        self.retried = False
        #: Trusted updates in a row that answered tau_prev (the stall rule's count), and how
        #: many of them the rule waits for before it searches (``stall``, doubled after each
        #: search that found no progress, up to STALL_BACKOFF x ``stall``).
        self.held = 0
        self.stall_wait = stall
        self.reset()

    def stall_due(self) -> bool:
        """The stall rule searches this update (0 < stall_wait <= held)."""
        return 0 < self.stall_wait <= self.held

    def after_update(self, moved: bool, searched: bool) -> None:
        """Count a hold (a trusted update that kept tau_prev); a move resets the stall rule.
        Count a searching update; the retry's wait reached, the network is on probation again."""
        self.held = self.held + 1 if not (moved or searched) else 0
        if moved:
            self.stall_wait = self.stall
        if self.credit == 0 and self.cap > 0:
            self.searched += 1
            if self.retry and self.searched >= self.retry_wait:
                self.credit, self.hits, self.searched, self.retried = 1, 0, 0, True

    def stall_found_nothing(self) -> None:
        """A stall search kept tau_prev: a true stall; wait twice as long before the next."""
        self.stall_wait = min(2 * self.stall_wait, STALL_BACKOFF * self.stall)

    @property
    def searching(self) -> bool:
        return self.credit == 0

    @property
    def probation(self) -> bool:
        """Trusted, below the cap: every update is audited."""
        return 0 < self.credit < self.cap

    def reset(self) -> None:
        """A mission's start."""
        self.credit = min(1, self.cap) if self.start == "network" else 0
        self.hits = 0
        self.held = 0
        self.stall_wait = self.stall
        self.searched = 0
        self.retry_wait = self.retry
        self.retried = False

    def grant(self) -> None:
        """Full trust now (the benchmark times the network's path this way): a mission's start,
        at the cap."""
        self.reset()
        self.credit = self.cap

    def judge(self, miss: bool) -> None:
        """One trusted update's outcome."""
        self.credit = max(self.credit - 1, 0) if miss else min(self.credit + 1, self.cap)
        if self.credit == self.cap:
            self.retry_wait, self.retried = self.retry, False
        elif self.credit == 0:
            self.searched = 0
            if self.retried:  # the retry did not pay: wait longer before the next
                self.retry_wait = min(2 * self.retry_wait, RETRY_BACKOFF * self.retry)
                self.retried = False

    def shadow(self, hit: bool) -> None:
        """One searching update's shadow judgement of the proposal."""
        self.hits = self.hits + 1 if hit else 0
        if self.hits >= self.need_hits:
            self.credit, self.hits, self.searched, self.retried = min(1, self.cap), 0, 0, False


class KeepStep:
    """The keep rule's answer in the making: τ (s), its path, the Verify calls, the chief cache;
    and what the audit and the trust read from it: ``stuck`` (every candidate failed and the
    search below them found nothing) and ``miss`` (True: a miss, False: a hit, None: no
    evidence)."""

    __slots__ = ("tau", "path", "calls", "cache", "stuck", "miss")

    def __init__(self, tau: float, path: str, calls: int, cache: ChiefCache, stuck: bool = False,
                 miss: bool | None = None) -> None:
        self.tau, self.path, self.calls, self.cache = tau, path, calls, cache
        self.stuck, self.miss = stuck, miss


class LearnedGovernor:
    """Algorithm 1 with a network π̃_θ (ln|τ| from z-scored features) and Verify/bisection fallback."""

    def __init__(self, net: NumpyNet, predictor: Predictor, name: str = "learned") -> None:
        self.net = net
        self.predictor = predictor
        self.anchor = ChiefAnchor(predictor)
        self.name = name
        self._z = np.empty((1, net.arch.n_in))
        lc = predictor.config.learned
        self.trust = Trust(lc.trust_credit, lc.trust_hits, lc.trust_at_start, lc.stall_updates,
                           lc.robust_trust_retry if predictor.robust else lc.trust_retry)
        #: None, or what a model flown on another scenario or side was trained for.
        self.foreign: str | None = None
        #: The model directory and weights digest flown (None for a network built in memory).
        self.model_dir: Path | None = None
        self.weights_sha256: str | None = None
        self._code = FEATURE_CODES[net.arch.features]
        self._rungs = np.array(lc.ladder, dtype=np.float64)
        self._tail_rungs = np.array(lc.tail_ladder, dtype=np.float64)
        # the ladder's candidates, or 0 and the tail's (robust Verify's last approach: :meth:`_tail`)
        self._cands_ns = np.empty(max(len(lc.ladder), len(lc.tail_ladder)) + 1, dtype=np.int64)
        #: The tail's memory (:meth:`_tail`): the last progress, 1 - τ_k / τ_{k-1} of the last
        #: update that moved τ (NaN: none yet), the gallops in a row that found none, and
        #: (learned.tail_backoff) the holds left before the next search and the current wait.
        self.remember_progress(math.nan)
        self._zero_failed = False  # this update verified 0 itself, and it failed (reset per update)

    @classmethod
    def from_model(cls, model: LoadedModel, predictor: Predictor, name: str | None = None
                   ) -> "LearnedGovernor":
        gov = cls(NumpyNet(model.arch, model.tensors), predictor, name or model.arch.family)
        gov.model_dir = Path(model.path)
        gov.weights_sha256 = str(model.card.get("weights_sha256", ""))
        return gov

    def log_shift(self, x_d: ArrayLike, x_c: ArrayLike, tau_prev: float = math.nan) -> float:
        """NN(features): predicted ln|τ| (s) at states x_d, x_c (km, km/s) with previous shift
        τ_{k-1} (s; an input of "vnb-prev" networks only)."""
        net = self.net
        return log_shift_kernel(np.asarray(x_d, dtype=np.float64), np.asarray(x_c, dtype=np.float64),
                                self._code, float(tau_prev), net.feature_mean, net.feature_inv_std,
                                net.target_mean, net.target_std, net.relative, self._z, net.kernel_args)

    def proposal(self, x_d: ArrayLike, x_c: ArrayLike, tau_prev: float = math.nan) -> float:
        """τ_c = side · exp(NN) (side · |τ_{k-1}| exp(NN) for a network of the step) on the
        nanosecond grid (side -1 behind the chief, +1 ahead); NaN
        if the network's output is not usable."""
        y = self.log_shift(x_d, x_c, tau_prev)
        if not (math.isfinite(y) and y <= MAX_LOG_SHIFT):
            return math.nan
        return quantise_shift(self.predictor.side * math.exp(y))

    def remember_progress(self, progress: float) -> None:
        """Set the last progress the tail's rule starts from (NaN: none) and clear its misses and
        holds: how a mission starts, and how a benchmark times an update as the mission's
        governor would make it (:func:`cikan_ros.timing.prime`)."""
        self._progress, self._tail_misses = float(progress), 0
        self._tail_holds, self._tail_wait = 0, 0
        self._search_holds, self._search_wait = 0, 0

    def initial(self, x_d: ArrayLike, x_c: ArrayLike, t: float) -> UpdateRecord:
        self.trust.reset()
        self.remember_progress(math.nan)
        return initial_update(self.anchor, x_d, x_c, t)

    def update(self, x_d: ArrayLike, x_c: ArrayLike, t: float, tau_prev: float) -> UpdateRecord:
        started = start_clock()
        pred = self.predictor
        k = update_index(t, pred.config.tsg.update_period_s)
        if tau_prev == 0.0:
            return make_record(started, 0.0, PATH_ZERO, 0, k, tau_prev)
        # the network's proposal, made when a path needs it (a searching update only to judge it)
        propose = functools.partial(self.proposal, x_d, x_c, tau_prev)
        pred = self.anchor(x_c, t)
        self._zero_failed = False
        if pred.config.learned.algorithm == "paper":
            tau, path, calls, cache = self._paper(pred, x_d, t, tau_prev, propose())
        else:
            tau, path, calls, cache = self._keep(pred, x_d, t, tau_prev, propose, k)
        if (path not in SEARCHED and tau != 0.0 and abs(tau) <= pred.config.tsg.zero_snap_s
                and not self._zero_failed):  # this update verified 0 itself, and it failed
            calls += 1
            if pred.verify(x_d, t, 0.0, cache or pred.cache(t)):
                tau, path = 0.0, PATH_VERIFY_ZERO
        self.trust.after_update(tau != tau_prev, path in SEARCHING_PATHS)
        if tau != tau_prev:
            self._progress = 1.0 - tau / tau_prev
        return make_record(started, tau, path, calls, k, tau_prev)

    @staticmethod
    def _paper(pred: Predictor, x_d: ArrayLike, t: float, tau_prev: float, tau_c: float
               ) -> tuple[float, str, int, ChiefCache]:
        """The paper's Algorithm 1 (without the zero test) with the anchored model ``pred``:
        (τ, path, Verify calls, chief cache)."""
        cache = pred.cache(t)  # chief states along the horizon, shared by this update's predictions
        if 0.0 <= pred.side * tau_c <= pred.side * tau_prev:  # τ_c between τ_prev and 0
            if pred.verify(x_d, t, tau_c, cache):
                return tau_c, PATH_NN, 1, cache
            tau, c = pred.bisect(x_d, t, tau_prev, tau_c, cache)
            return tau, PATH_NN_BISECT, c + 1, cache
        tau, c = pred.bisect(x_d, t, tau_prev, 0.0, cache)
        return tau, PATH_BISECT, c, cache

    def _keep(self, pred: Predictor, x_d: ArrayLike, t: float, tau_prev: float,
              propose: Callable[[], float], k: int) -> tuple[float, str, int, ChiefCache | None]:
        """The keep rule (without the zero test) with the anchored model ``pred``: (τ, path,
        Verify calls, chief cache or None). Its steps, as docs/learned_update_rule.md states
        them: robust Verify's tail (the conventional TSG's update near τ = 0), trust (an
        untrusted network's update is the conventional TSG's), stall, last approach, ladder,
        probe, audit, and the judgement of the update by the trust. The network runs only when a
        step needs its proposal (``propose``)."""
        if self._robust_tail(pred, tau_prev):
            return self._tail(pred, x_d, t, tau_prev, propose)
        trust = self.trust
        if trust.searching:
            return self._search(pred, x_d, t, tau_prev, propose)
        if trust.stall_due():
            return self._stall(pred, x_d, t, tau_prev)
        scheduled = k % pred.config.learned.probe_every == 0
        if scheduled and self._last_approach(pred, tau_prev):
            tau, calls = pred.optimal_shift(x_d, t, tau_prev)
            return tau, PATH_PROBE, calls, None
        step = self._ladder_step(pred, x_d, t, tau_prev, propose(), scheduled)
        if step is None:  # the ladder proposes no progress
            step = self._probe(pred, x_d, t, tau_prev, scheduled)
            if step is None:  # an unscheduled hold, the network trusted at the cap: no audit
                return tau_prev, PATH_KEEP, 0, None
        self._audit(pred, x_d, t, tau_prev, step, scheduled)
        return self._judge(pred, x_d, t, tau_prev, step)

    def _search(self, pred: Predictor, x_d: ArrayLike, t: float, tau_prev: float,
                propose: Callable[[], float]) -> tuple[float, str, int, ChiefCache | None]:
        """Trust, c = 0 (searching): the rule's search (:meth:`_searched`: π* as the conventional
        TSG finds it [search], or the hold-first search [search-hold, search-ladder]); the
        proposal τ_c is judged against its answer (:meth:`would_pay`, a shadow judgement), the network
        consulted only when the answer gives evidence (:meth:`judgeable`): in GEO, where the
        rule searches on most updates, the forward passes skipped were 10 % of the active
        updates' CPU (6 starts, same decisions)."""
        tau, calls, cache, path = self._searched(pred, x_d, t, tau_prev)
        if self.judgeable(tau_prev, tau):
            self.trust.shadow(bool(self.would_pay(propose(), tau_prev, tau)))
        return tau, path, calls, cache

    def _searched(self, pred: Predictor, x_d: ArrayLike, t: float, tau_prev: float
                  ) -> tuple[float, int, ChiefCache | None, str]:
        """The search of a searching or stalled update: (τ, Verify calls, chief cache or None,
        path). ``learned.search_rule`` "conventional", or |τ_prev| <= ``hold_first_above_s``:
        the conventional TSG's update [search]. "hold-first": the candidates of
        :func:`hold_first_candidates` verified in order, closest to 0 first, one compiled call;
        none passes: τ_prev [search-hold]; one passes: that shift, or with ``search_budget`` > 0
        the bisection between it and the candidate before it with at most that many calls
        [search-ladder]. Safe: every answer passed Verify or is τ_prev. Why
        (docs/learned_update_rule.md, "A search that holds first"): in GEO's first phase π* holds
        on two thirds of the updates, where the bisection spends ~19 failing calls, and a shift
        just above τ_prev fails early (39 us against a passing Verify's ~300 us)."""
        lc = pred.config.learned
        if lc.search_rule != "hold-first" or abs(tau_prev) <= lc.hold_first_above_s:
            tau, calls = pred.optimal_shift(x_d, t, tau_prev)
            return tau, calls, None, PATH_SEARCH
        if self._search_holds > 0:   # learned.search_backoff: the last search found nothing
            self._search_holds -= 1
            self._zero_failed = False   # nothing verified: the zero test as after any hold
            return tau_prev, 0, None, PATH_SEARCH_HOLD
        cache = pred.cache(t)
        prev_ns = to_ns(tau_prev)
        ns = hold_first_candidates(prev_ns, self._progress, pred.tol_ns, lc.hold_test, lc.search_depth,
                                   lc.search_ladder)
        tau, index, calls = pred.first_feasible_ns(x_d, t, ns, prev_ns, 0, cache)
        self._zero_failed = index != 0   # candidate 0 came first: failed, or never reached
        if index < 0:
            if lc.search_backoff:
                self._search_wait = min(max(2 * self._search_wait, 1), lc.search_backoff)
                self._search_holds = self._search_wait
            return tau_prev, calls, cache, PATH_SEARCH_HOLD
        self._search_wait = 0
        if index > 0 and lc.search_budget:
            tau, c = pred.bisect(x_d, t, tau, ns_to_seconds(int(ns[index - 1])), cache, lc.search_budget)
            calls += c
        return tau, calls, cache, PATH_SEARCH_LADDER

    def _stall(self, pred: Predictor, x_d: ArrayLike, t: float, tau_prev: float
               ) -> tuple[float, str, int, ChiefCache | None]:
        """The stall rule: τ_prev held for learned.stall_updates trusted updates in a row.

        Either π* = τ_prev (a stall: every network looks alike) or the feasible progress per
        update is below every step the rule tries (measured in GEO's approach-speed-bound tail:
        ~0.4 % of |τ| per update, against the audit's 10 %), which would hold τ for good. So
        search as a searching update does (:meth:`_searched`). Progress found is a miss (with
        stall_judge "audit": only progress beyond the audit's reach, as for the audit). A search
        that finds nothing backs off (true stalls are common on the paper's orbit, where the
        deputy rides the cone's edge)."""
        lc = pred.config.learned
        tau, calls, cache, _ = self._searched(pred, x_d, t, tau_prev)
        if tau == tau_prev:
            self.trust.stall_found_nothing()
        elif stall_miss(pred.side, tau_prev, tau, lc.audit_step if lc.stall_judge == "audit" else 0.0):
            self.trust.judge(True)
        return tau, PATH_STALL, calls, cache

    @staticmethod
    def _robust_tail(pred: Predictor, tau_prev: float) -> bool:
        """Robust Verify's tail, |τ_prev| <= learned.robust_tail_s: the update is the conventional
        TSG's search, whatever the trust. There the networks' relative error is large and the
        feasible progress small, and the rule lagged π* (time to τ = 0 +31 % to +41 %, CIKAN and
        ReLU on the paper's orbit and LEO), while the conventional update is cheap: its rollouts
        reach the terminal set within a few samples (docs/learned_update_rule.md, "Under robust
        Verify")."""
        return pred.robust and abs(tau_prev) <= pred.config.learned.robust_tail_s

    def _tail(self, pred: Predictor, x_d: ArrayLike, t: float, tau_prev: float,
              propose: Callable[[], float]) -> tuple[float, str, int, ChiefCache | None]:
        """Robust Verify's tail (:meth:`_robust_tail`). ``learned.tail_rule`` "network", with a
        network of the step (target log-ratio: :attr:`NumpyNet.relative`): the candidates
        τ_c (1 - s), s in ``learned.tail_ladder``, of its proposal τ_c = side |τ_prev| exp(NN),
        verified in order, the first that passes answered [nn] (the networks of the step resolve
        the tail's steps, 15-55 % of |τ| an update on the paper's orbit; docs/learned_update_rule.md,
        "The tail to the network of the step"); none passing, a network of ln|τ|, or a model made
        for another Verify or truth scale (:attr:`foreign`: its steps are not this tail's), the gallop.
        "gallop": the
        shift about the last update's progress q of the way to 0, τ_prev (1 - q), searched up or
        down by ``tail_growth`` and bracketed with at most ``tail_budget`` Verify calls
        (:meth:`Predictor.gallop`) [gallop]; none passing, τ_prev is held and the next gallop
        starts below the smallest q that failed. In the tail π* moves by a steady fraction of
        |τ| per update (0.5-0.6 from 0.1 s to 2 ms on the paper's orbit, then 0.15-0.2), where
        the conventional search spends log2(|τ_prev| / tol) calls to find it. The conventional
        search [tail] instead: with "search", before any progress is known (a mission's or a
        restarted node's first moves), when the last progress is below
        ``learned.tail_min_progress`` (a tail that creeps ~1 % an update and now and then jumps,
        as under the paper's controller, where a gallop from the creep misses the jumps), and
        after TAIL_MISSES gallops in a row found none (so a shrinking progress cannot hold τ for
        good). With ``learned.tail_backoff`` B > 0, a conventional search here that finds no
        progress holds τ_prev for the next 1, 2, 4, ... (at most B) updates [keep] before it
        searches again, progress found resetting it: where robust Verify's tube certifies no
        τ = 0 (GEO), the conventional TSG spends most of a mission's CPU on such searches."""
        lc = pred.config.learned
        if self._tail_holds > 0:   # learned.tail_backoff: the last search found nothing
            self._tail_holds -= 1
            return tau_prev, PATH_KEEP, 0, None
        if (lc.tail_rule == "search" or not self._progress >= lc.tail_min_progress
                or self._tail_misses >= TAIL_MISSES):
            self._tail_misses = 0
            tau, calls = pred.optimal_shift(x_d, t, tau_prev)
            if lc.tail_backoff:
                self._tail_wait = min(max(2 * self._tail_wait, 1), lc.tail_backoff) if tau == tau_prev else 0
                self._tail_holds = self._tail_wait
            return tau, PATH_TAIL, calls, None
        cache = pred.cache(t)
        calls = 0
        if lc.tail_rule == "network" and self.net.relative and self.foreign is None:
            cands = self._cands_ns
            n = ladder_kernel(propose(), tau_prev, int(pred.side), self._tail_rungs, pred.tol_ns / 1e9, 0.0,
                              cands[1:])
            if n:
                # |τ_prev| <= zero_snap_s: every answer here gets the zero test, so verify 0 first
                # (the same answer; one wrapper call fewer on most of the last approach's updates)
                zero_first = abs(tau_prev) <= pred.config.tsg.zero_snap_s and cands[1] != 0
                cands[0] = 0
                tau, index, calls = pred.first_feasible_ns(x_d, t, cands[:n + 1] if zero_first else cands[1:n + 1],
                                                           to_ns(tau_prev), 0, cache)
                self._zero_failed = zero_first and index != 0
                if zero_first and index == 0:
                    self._tail_misses = 0
                    return 0.0, PATH_VERIFY_ZERO, calls, cache
                if index >= 0:
                    self._tail_misses = 0
                    return tau, PATH_NN, calls, cache
        tau, q, q_fail, c = pred.gallop(x_d, t, tau_prev, self._progress, lc.tail_growth, lc.tail_budget, cache)
        calls += c
        self._zero_failed = self._zero_failed or q_fail == 1.0   # inf: nothing failed
        if q > 0.0:
            self._tail_misses = 0
        else:
            self._tail_misses += 1
            if math.isfinite(q_fail):
                self._progress = q_fail / lc.tail_growth
        return tau, PATH_GALLOP, calls, cache

    @staticmethod
    def _last_approach(pred: Predictor, tau_prev: float) -> bool:
        """Robust Verify's last approach, |τ_prev| <= tsg.zero_snap_s: the feasible shifts above
        τ_prev form a thin sliver that a budgeted probe misses (measured: τ stalled 3 m from the
        chief), so a scheduled update's probe there is the conventional TSG's search (<=
        log2(zero_snap/tol) + 1 calls), before the ladder; a safe answer either way (verified,
        or τ_prev)."""
        return pred.robust and abs(tau_prev) <= pred.config.tsg.zero_snap_s

    def _ladder_step(self, pred: Predictor, x_d: ArrayLike, t: float, tau_prev: float, tau_c: float,
                     scheduled: bool) -> KeepStep | None:
        """The ladder: the candidates C (:meth:`candidates`) verified in order, the first that
        passes answered [nn]; none passes: bisect_b(τ_prev, last candidate) with b = B_p when
        scheduled, else B [nn+bisect, or keep with b = 0]. None when C is empty."""
        lc = pred.config.learned
        n = ladder_kernel(tau_c, tau_prev, int(pred.side), self._rungs, lc.min_step_s, lc.min_progress,
                          self._cands_ns)
        if not n:
            return None
        cache = pred.cache(t)
        budget = lc.probe_budget if scheduled else lc.fallback_budget
        tau, index, calls = pred.first_feasible_ns(x_d, t, self._cands_ns[:n], to_ns(tau_prev), budget, cache)
        path = PATH_NN if index >= 0 else PATH_NN_BISECT if budget > 0 else PATH_KEEP
        # stuck: every proposal failed and the search below them found nothing
        return KeepStep(tau, path, calls, cache, stuck=index < 0 and tau == tau_prev)

    def _probe(self, pred: Predictor, x_d: ArrayLike, t: float, tau_prev: float, scheduled: bool
               ) -> KeepStep | None:
        """C is empty. Not scheduled (or B_p = 0): τ_prev [keep], no prediction; None when the
        network is trusted at the cap (nothing follows), else the held τ_prev for the
        probation's audit. Scheduled: the probe bisect_{B_p}(τ_prev, 0) [probe]; progress it
        finds where the network proposed none is a miss."""
        lc = pred.config.learned
        if not scheduled or lc.probe_budget == 0:
            return KeepStep(tau_prev, PATH_KEEP, 0, pred.cache(t)) if self.trust.probation else None
        cache = pred.cache(t)
        tau, calls = pred.bisect(x_d, t, tau_prev, 0.0, cache, lc.probe_budget)
        return KeepStep(tau, PATH_PROBE, calls, cache, miss=True if tau != tau_prev else None)

    def _audit(self, pred: Predictor, x_d: ArrayLike, t: float, tau_prev: float, step: KeepStep,
               scheduled: bool) -> None:
        """The audit, on scheduled updates, on every update on probation and when ``step`` is
        stuck (a stall, π* = τ_prev, or a network that overshoots): does the answer lag π*? One
        Verify audit_step of the way from it to 0; when it passes, the network left that much
        progress behind (a miss), and the audited shift, verified, is the answer [audit]. When
        it fails after a proposal's step ([nn]) beyond the audit's reach, a hit: evidence of a
        network that tracks π* (no lag after a smaller step, a stall say, or after a step the
        search found, is no evidence). Updates ``step`` in place."""
        lc = pred.config.learned
        if not ((scheduled or step.stuck or self.trust.probation) and lc.audit_step > 0.0
                and step.tau != 0.0):
            return
        audit = quantise_shift(step.tau * (1.0 - lc.audit_step))
        if audit == step.tau:
            return
        step.calls += 1
        if pred.verify(x_d, t, audit, step.cache):
            step.miss = True
            step.tau, step.path = audit, PATH_AUDIT
        elif step.path == PATH_NN and abs(step.tau) <= abs(tau_prev) * (1.0 - lc.audit_step):
            step.miss = False

    def _judge(self, pred: Predictor, x_d: ArrayLike, t: float, tau_prev: float, step: KeepStep
               ) -> tuple[float, str, int, ChiefCache | None]:
        """One judgement per update (a miss takes a credit, a hit adds one); when it costs the
        last credit, this update already answers π* [search], not the audit's step."""
        if step.miss is not None:
            self.trust.judge(step.miss)
            if self.trust.searching:
                tau, c = pred.optimal_shift(x_d, t, tau_prev)
                return tau, PATH_SEARCH, step.calls + c, None
        return step.tau, step.path, step.calls, step.cache

    def would_pay(self, tau_c: float, tau_prev: float, tau_star: float) -> bool | None:
        """Shadow judgement: would the keep rule on τ_c have answered within the audit's reach
        of τ* = π*, so that its audit would have found no lag? The ladder's answer is its first
        candidate no closer to 0 than τ* (those closer fail Verify), else τ_prev; it pays when
        moving it audit_step of the way to 0 passes τ*. None (no evidence) when π* moved τ by
        less than the audit's reach (holding τ_prev would pass too) or to 0 (the zero test's
        business). In magnitudes m = side · τ."""
        if not self.judgeable(tau_prev, tau_star):
            return None
        side = self.predictor.side
        keep = 1.0 - self.predictor.config.learned.audit_step
        m_prev, m_star = side * tau_prev, side * tau_star
        answer = next((side * c for c in self.candidates(tau_c, tau_prev) if side * c >= m_star), m_prev)
        return answer * keep < m_star

    def judgeable(self, tau_prev: float, tau_star: float) -> bool:
        """Can π* = τ* judge a proposal (:meth:`would_pay`)? Only when it moved τ_prev beyond
        the audit's reach, and not to 0."""
        side = self.predictor.side
        m_prev, m_star = side * tau_prev, side * tau_star
        return m_star != 0.0 and m_prev * (1.0 - self.predictor.config.learned.audit_step) >= m_star

    def candidates(self, tau_c: float, tau_prev: float) -> list[float]:
        """The keep rule's candidates c_i = τ_c (1 - s_i) (s), ladder order, those with
        0 <= |c_i| <= |τ_prev| - δ on τ_prev's side only, without repeats; empty when τ_c is NaN
        or proposes less progress than ρ |τ_prev| (|τ_c| > |τ_prev| (1 - ρ), ρ =
        learned.min_progress). In magnitudes m = side · τ, so one rule serves both sides."""
        lc = self.predictor.config.learned
        out = np.empty(len(lc.ladder), dtype=np.int64)
        n = ladder_kernel(float(tau_c), float(tau_prev), int(self.predictor.side), self._rungs, lc.min_step_s,
                          lc.min_progress, out)
        return [ns_to_seconds(int(v)) for v in out[:n]]


def hold_first_candidates(tau_prev_ns: int, progress: float, tol_ns: int, hold_test: float, depth: int,
                          ladder: tuple[float, ...]) -> NDArray:
    """The shifts (int64 ns, closest to 0 first, no repeats) the hold-first search verifies from
    τ_prev (ns, either side of 0): the bisection's first midpoints, fractions q = 1 (0 itself),
    1/2, ..., 2^-depth of the way from τ_prev to 0, where a jump of π* over an infeasible gap
    lands; the last update's progress times each ``ladder`` factor (only those with hold_test <
    q < 2^-depth, and only with a progress above hold_test: NaN, none); last the hold test, q =
    hold_test but at least ``tol_ns`` from τ_prev (0 when |τ_prev| <= tol_ns). A candidate within
    ``tol_ns`` of τ_prev is left out (the bisection's tolerance: no step worth a Verify)."""
    qs = [0.5 ** j for j in range(depth + 1)]
    if progress > hold_test:
        qs += [progress * f for f in ladder if hold_test < progress * f < 0.5 ** depth]
    out = {0 if q >= 1.0 else int(round(tau_prev_ns * (1.0 - q))) for q in qs}
    out = {c for c in out if abs(tau_prev_ns - c) >= tol_ns}   # a step below the tolerance: none
    hold_ns = int(round(tau_prev_ns * (1.0 - hold_test)))
    if abs(tau_prev_ns - hold_ns) < tol_ns:
        hold_ns = 0 if abs(tau_prev_ns) <= tol_ns else tau_prev_ns - int(math.copysign(tol_ns, tau_prev_ns))
    out.add(hold_ns)
    return np.array(sorted(out, key=abs), dtype=np.int64)


def nn_accept_rate(updates: Iterable[UpdateRecord]) -> float | None:
    """The network's acceptance: the share of the active updates (tau_{k-1} != 0, SPEC §9) whose
    answer is the network's proposal, passed by Verify (path "nn"). The one definition of the
    per-run metric, Table 2, the campaign summaries and the scenario index. None without an
    active update.

    An update where the network was not trusted (path "search", "stall", "tail", "search-hold" or
    "search-ladder"), held tau_{k-1} ("keep") or searched after its candidates failed counts as
    not accepted: what the figure
    says is how often the network, not the search, decided. A proposal that passed Verify and
    was then snapped to 0 by the zero test counts as not accepted (its path is "verify-zero");
    this happens at most once per mission."""
    paths = [r.path for r in updates if r.active]
    return paths.count(PATH_NN) / len(paths) if paths else None


def train_target_args(cfg: Config) -> str:
    """The arguments of ``make scenario-models`` that train the models this configuration flies:
    ``SCENARIO=`` the shipped scenario's name, or, for a scenario given as a file (whose path the
    configuration does not keep), the file's place; ``APPROACH=ahead`` from ahead;
    ``VERIFY=robust`` (and ``TRUTH=`` another truth than ``realistic``) under robust Verify."""
    name = cfg.scenario.name
    scenario = f"SCENARIO={name}" if name in scenario_names() else f"SCENARIO=<your {name} scenario file>"
    side = "" if cfg.side is Side.BEHIND else f" APPROACH={cfg.side.approach}"
    if not cfg.tsg.robust:
        return scenario + side
    t = cfg.truth.name
    truth = "" if t == "realistic" else f" TRUTH={t}" if t in truth_names() else f" TRUTH=<your {t} truth file>"
    return scenario + side + " VERIFY=robust" + truth


def foreign_reason(card: dict[str, Any], cfg: Config) -> str | None:
    """Why a model (its card) was made for another configuration than ``cfg``: another scenario
    or approach side, or labels of another Verify (:func:`~cikan_ros.learn.modelfile.label_mismatch`);
    None when it was made for this one."""
    trained = model_scenario(card)
    wanted = {"name": cfg.scenario.name, "approach": cfg.mission.approach}
    reasons = []
    if trained != wanted:
        reasons.append(f"trained for scenario {trained['name']!r}, approach {trained['approach']!r}, not "
                       f"scenario {wanted['name']!r}, approach {wanted['approach']!r}")
    labels = label_mismatch(card, cfg.flat())
    if labels is not None:
        reasons.append(labels)
    return "; ".join(reasons) or None


def load_learned_governor(name: str, predictor: Predictor) -> LearnedGovernor:
    """The learned governor of a shipped family (``cikan``, ``grbf``, ``rswaf``, ``relu``,
    ``gelu``: the scenario's model for the approach side and Verify mode,
    ``scenario.models_dir``/<name>[-ahead][-robust]; under robust Verify with
    ``learned.foreign_model`` and no robust model, the nominal one)
    or of a model directory/file. A model whose card names another scenario or side, or labels of
    another Verify (:func:`~cikan_ros.learn.modelfile.label_mismatch`: nominal labels flown under
    robust Verify, another truth scale or controller) is refused unless ``learned.foreign_model``
    (then :attr:`LearnedGovernor.foreign` says what it was trained for). Raises ModelFileError."""
    cfg = predictor.config
    family = name in FAMILIES
    if family:
        where = flown_model_dir(cfg, name)
        if not (where / CARD).is_file():
            raise ModelFileError(
                f"no {name} model{' of robust Verify' if cfg.tsg.robust else ''} for scenario "
                f"{cfg.scenario.name!r}, approach {cfg.mission.approach!r} "
                f"(looked in {where}); train one (make scenario-models {train_target_args(cfg)}) "
                f"or name a model directory")
        model = load_model(where)
    else:
        model = load_model(name)
    foreign = foreign_reason(model.card, cfg)
    if foreign is not None and not cfg.learned.foreign_model:
        raise ModelFileError(f"model {model.path} was {foreign}: set learned.foreign_model=true to fly it anyway")
    label = name if family else f"{model.arch.family}:{Path(model.path).name}"
    gov = LearnedGovernor.from_model(model, predictor, label)
    gov.foreign = foreign
    return gov
