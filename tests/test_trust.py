"""The keep rule's trust in its network (docs/learned_update_rule.md, "A network that does not
fit"): the credit's arithmetic (golden), the shadow judgement against pi* (golden, hand-worked
magnitudes), and whole missions flown by networks that do not fit (contract: safe, docked, and
no worse than the conventional TSG by more than the issue's bound on these starts)."""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from cikan_ros.config import load_config
from cikan_ros.governor import PATH_AUDIT, PATH_KEEP, PATH_SEARCH, PATH_STALL, ConventionalGovernor
from cikan_ros.learn.governor import RETRY_BACKOFF, Trust
from cikan_ros.mission import run_mission, sample_start
from cikan_ros.tsg import Predictor
from constant_network import constant_governor


def test_credit_arithmetic() -> None:
    """Start on probation (credit 1); a hit adds one up to the cap, a miss takes one; at 0 the
    rule searches, and need_hits consecutive shadow hits give one credit back."""
    t = Trust(cap=3, hits=2, start="network")
    assert (t.credit, t.searching, t.probation) == (1, False, True)
    t.judge(miss=False)
    t.judge(miss=False)
    t.judge(miss=False)
    assert (t.credit, t.probation) == (3, False)          # capped, audited on schedule only
    t.judge(miss=True)
    assert (t.credit, t.probation) == (2, True)
    t.judge(miss=True)
    t.judge(miss=True)
    assert t.searching
    t.shadow(True)
    t.shadow(False)                                       # a shadow miss resets the count
    t.shadow(True)
    assert t.searching
    t.shadow(True)
    assert (t.credit, t.searching) == (1, False)
    t.reset()
    assert t.credit == 1
    s = Trust(cap=3, hits=2, start="search")
    assert s.searching
    assert Trust(cap=0, hits=2, start="network").searching   # credit 0: never trusted


def test_retry_arithmetic() -> None:
    """learned.trust_retry R = 2: after R searching updates in a row the network is on
    probation again (credit 1) without shadow hits; a retry that loses its credit before the
    cap doubles the wait (2, 4, 8, 16, then 16 = 8R); a retry that reaches the cap resets it to
    R; shadow hits still give the credit back at once; R = 0 never retries."""
    t = Trust(cap=3, hits=3, retry=2)
    waits = []
    for _ in range(6):
        t.judge(miss=True)                                # probation's credit lost: searching
        assert t.searching
        n = 0
        while t.searching:
            t.after_update(moved=False, searched=True)
            n += 1
        waits.append(n)
        assert (t.credit, t.probation) == (1, True)
    assert waits == [2, 4, 8, 16, 16, 16]
    t.judge(miss=False)
    t.judge(miss=False)                                   # the cap: the retry paid
    assert t.credit == 3 and t.retry_wait == 2
    for _ in range(3):
        t.judge(miss=True)
    t.after_update(moved=False, searched=True)
    t.after_update(moved=False, searched=True)
    assert t.credit == 1                                  # back after R = 2 again
    t.judge(miss=True)                                    # that retry failed: the wait doubles
    assert t.retry_wait == 4
    for hit in (True, True, True):                        # earned back by shadow hits: no retry
        t.shadow(hit)
    assert t.credit == 1 and not t.retried
    t.judge(miss=True)                                    # a lost earned credit: the wait stays
    assert t.retry_wait == 4
    for _ in range(3):
        t.after_update(moved=False, searched=True)
    assert t.searching
    t.after_update(moved=False, searched=True)
    assert t.credit == 1
    never = Trust(cap=3, hits=3, retry=0)
    never.judge(miss=True)
    for _ in range(100):
        never.after_update(moved=False, searched=True)
    assert never.searching
    assert Trust(cap=0, hits=3, retry=2).searching        # credit 0 for good: nothing to retry
    zero = Trust(cap=0, hits=3, retry=2)
    zero.after_update(moved=False, searched=True)
    zero.after_update(moved=False, searched=True)
    assert zero.searching


_EVENTS = st.lists(st.sampled_from(["hit", "miss", "shadow-hit", "shadow-miss", "search", "hold", "move"]),
                   max_size=200)


@settings(max_examples=200, deadline=None)
@given(events=_EVENTS, cap=st.integers(0, 4), retry=st.integers(0, 5))
@example(events=["miss", "shadow-hit", "search", "search", "shadow-hit", "miss", "search"], cap=1, retry=3)
def test_retry_bounds_property(events: list[str], cap: int, retry: int) -> None:
    """Any sequence of judgements and updates: the credit stays in [0, cap]; the retry's wait
    stays in [R, 8R]; with R = 0 a searching governor gets its credit back only from shadow
    hits; with R > 0 (and a cap above 0) fewer searching updates than the current wait pass in a
    row."""
    t = Trust(cap=cap, hits=2, retry=retry)
    searching_run = 0
    for e in events:
        before = t.credit
        if e == "hit" and not t.searching:
            t.judge(miss=False)
        elif e == "miss" and not t.searching:
            t.judge(miss=True)
        elif e.startswith("shadow") and t.searching:
            t.shadow(e == "shadow-hit")
        elif e in ("search", "hold", "move"):
            wait = t.retry_wait
            t.after_update(moved=e == "move", searched=e == "search" or t.searching)
            searching_run += 1
            assert retry == 0 or cap == 0 or not t.searching or searching_run < wait
            if retry == 0 and before == 0:
                assert t.credit == 0
        if not t.searching:
            searching_run = 0
        assert 0 <= t.credit <= cap
        assert retry <= t.retry_wait <= RETRY_BACKOFF * retry


def test_stall_rule_arithmetic() -> None:
    """Holds count while the rule keeps tau_prev; N = 2 holds make a search due; a search that
    finds nothing doubles the wait (up to 8N = 16); a move, or a mission's start, resets it."""
    t = Trust(cap=3, hits=2, stall=2)
    t.after_update(moved=False, searched=False)
    assert not t.stall_due()
    t.after_update(moved=False, searched=False)
    assert t.stall_due()
    waits = []
    for _ in range(5):
        t.stall_found_nothing()
        t.after_update(moved=False, searched=True)       # the search itself: held back to 0
        waits.append(t.stall_wait)
    assert waits == [4, 8, 16, 16, 16] and t.held == 0
    t.after_update(moved=True, searched=False)
    assert (t.stall_wait, t.held) == (2, 0)
    t.stall_found_nothing()
    t.reset()
    assert t.stall_wait == 2
    assert not Trust(cap=3, hits=2, stall=0).stall_due()   # 0: the rule is off


def test_stall_judgement_golden() -> None:
    """stall_miss(side, tau_prev, tau, reach): behind, tau_prev = -10 s; a search answering
    -9.5 s moved 5 %: a miss when any progress counts (reach 0), none within the audit's 10 %;
    -8.9 s (11 %) is a miss either way; no move is never a miss. Ahead, the same negated."""
    from cikan_ros.learn.governor import stall_miss

    assert stall_miss(-1, -10.0, -9.5, 0.0) and not stall_miss(-1, -10.0, -9.5, 0.1)
    assert stall_miss(-1, -10.0, -8.9, 0.0) and stall_miss(-1, -10.0, -8.9, 0.1)
    assert not stall_miss(-1, -10.0, -10.0, 0.0)
    assert stall_miss(1, 10.0, 9.5, 0.0) and not stall_miss(1, 10.0, 9.5, 0.1)


@pytest.fixture(scope="module")
def predictor() -> Predictor:
    return Predictor.from_config(load_config())


def test_shadow_judgement_golden(predictor: Predictor) -> None:
    """would_pay, worked by hand for a constant proposal tau_c = -5 s (ladder 0.08, 0.03, 0,
    -0.05 -> candidates -4.6, -4.85, -5, -5.25 s), audit_step 0.1:

    - tau_prev = -10, pi* = -5: the first candidate no closer to 0 than -5 is -5; 0.9 * 5 = 4.5
      < 5, so the audit would find no lag: a hit.
    - tau_prev = -10, pi* = -2: the first candidate at or beyond 2 is -4.6; 0.9 * 4.6 = 4.14 > 2:
      the answer lags, a miss.
    - tau_prev = -10, pi* = -9.5: pi* moved 5 %, within the audit's reach: no evidence (None).
    - pi* = 0: the zero test's business, no evidence.
    - tau_prev = -10, pi* = -7: candidates all closer to 0 than -7 fail, the answer is tau_prev
      = -10, 0.9 * 10 = 9 > 7: a miss.
    """
    gov = constant_governor(predictor, 5.0)
    assert gov.candidates(-5.0, -10.0) == [-4.6, -4.85, -5.0, -5.25]
    assert gov.candidates(-5.0, -5.2) == [-4.6, -4.85, -5.0]      # |c| <= |tau_prev| - 1 ms only
    assert gov.candidates(-5.0, -5.0) == [-4.6, -4.85]
    assert gov.candidates(math.nan, -10.0) == [] and gov.candidates(-11.0, -10.0) == []
    assert gov.would_pay(-5.0, -10.0, -5.0) is True
    assert gov.would_pay(-5.0, -10.0, -2.0) is False
    assert gov.would_pay(-5.0, -10.0, -9.5) is None
    assert gov.would_pay(-5.0, -10.0, 0.0) is None
    assert gov.would_pay(-5.0, -10.0, -7.0) is False


def test_shadow_judgement_is_sign_agnostic(predictor: Predictor) -> None:
    """The same judgements ahead of the chief (every shift negated)."""
    ahead = Predictor.from_config(predictor.config.replace(**{"mission.approach": "ahead"}))
    gov = constant_governor(ahead, 5.0)
    for tau_prev, star, want in ((10.0, 5.0, True), (10.0, 2.0, False), (10.0, 9.5, None),
                                 (10.0, 7.0, False)):
        assert gov.would_pay(5.0, tau_prev, star) is want


def _ratio(a: list[float], b: list[float]) -> float:
    return float(np.mean(np.array(a) / np.array(b)))


@pytest.mark.parametrize("tau_abs", [1e-6, 1e6, 3.0])
def test_a_network_that_does_not_fit_costs_little(predictor: Predictor, tau_abs: float) -> None:
    """Constant networks (too aggressive: 1 us; too conservative: 1e6 s; a plausible but blind
    3 s) on Table 2 starts 1-3: every answer verified or held (0 violations), docked; the
    searching updates answer pi* exactly; mean Delta-V and time to tau = 0 within 10 % of the
    conventional TSG on the same starts (measured before the trust existed: up to +80 %)."""
    conv = ConventionalGovernor(predictor)
    gov = constant_governor(predictor, tau_abs)
    dv, dv0, t0, t00 = [], [], [], []
    for seed in (1, 2, 3):
        x0 = sample_start(predictor, seed)
        ref = run_mission(conv, x0, seed).metrics()
        res = run_mission(gov, x0, seed)
        m = res.metrics()
        assert m["violations"] == 0 and m["success"], m
        for u in res.updates:
            if u.path in (PATH_SEARCH, PATH_STALL):
                assert u.tau_s == predictor.optimal_shift(*_state(res, u, predictor), u.tau_prev)[0]
            if u.path == PATH_AUDIT:
                assert predictor.verify(*_state(res, u, predictor), u.tau_s)
        dv.append(m["delta_v_kmps"])
        dv0.append(ref["delta_v_kmps"])
        t0.append(m["t_tau_zero_s"])
        t00.append(ref["t_tau_zero_s"])
    assert _ratio(dv, dv0) <= 1.10, (dv, dv0)
    assert _ratio(t0, t00) <= 1.10, (t0, t00)


def _state(res, u, predictor: Predictor) -> tuple[np.ndarray, float]:
    from cikan_ros.units import through_si

    step = round(u.k * predictor.config.tsg.update_period_s / predictor.config.control.period_s)
    return through_si(res.x_d[step]), float(res.t[step])


@pytest.mark.parametrize("stall_updates", [0, 3])
def test_the_stall_rule_searches_after_held_updates(predictor: Predictor, stall_updates: int) -> None:
    """A network that never proposes progress (constant 1e6 s), with no audit and no probe: the
    keep rule alone holds tau_0 for good. With learned.stall_updates = 3, the 4th active update
    searches like the conventional TSG (its answer is pi* at that state, here progress: a miss,
    which takes the probation credit, so the rule searches from then on)."""
    cfg = predictor.config.replace(**{"learned.audit_step": 0.0, "learned.probe_budget": 0,
                                      "learned.stall_updates": stall_updates, "learned.trust_retry": 0,
                                      "mission.duration_s": 900.0})
    pred = Predictor.from_config(cfg)
    gov = constant_governor(pred, 1e6)
    res = run_mission(gov, sample_start(pred, 1), 1)
    active = [u for u in res.updates if u.active]
    assert len(active) >= 10
    if stall_updates == 0:
        assert {u.path for u in active} == {PATH_KEEP}
        assert all(u.tau_s == res.updates[0].tau_s for u in active)
        return
    assert [u.path for u in active[:4]] == [PATH_KEEP] * 3 + [PATH_STALL]
    stall = active[3]
    assert stall.tau_s == pred.optimal_shift(*_state(res, stall, pred), stall.tau_prev)[0] != stall.tau_prev
    assert {u.path for u in active[4:]} <= {PATH_SEARCH}


def test_a_searching_governor_retries_its_network(predictor: Predictor) -> None:
    """The mission above with learned.trust_retry = 2: the stall search's miss takes the
    probation credit; that update (it answered π*) and the search after it are R = 2 searching
    updates in a row, so the next is the network's again (held, path keep), not a search: the
    retry, without any shadow hit (with R = 0 every later update searches: the test above)."""
    cfg = predictor.config.replace(**{"learned.audit_step": 0.0, "learned.probe_budget": 0,
                                      "learned.stall_updates": 3, "learned.trust_retry": 2,
                                      "mission.duration_s": 900.0})
    pred = Predictor.from_config(cfg)
    gov = constant_governor(pred, 1e6)
    res = run_mission(gov, sample_start(pred, 1), 1)
    paths = [u.path for u in res.updates if u.active]
    assert paths[:6] == [PATH_KEEP] * 3 + [PATH_STALL, PATH_SEARCH, PATH_KEEP], paths


def test_robust_verify_retries_by_its_own_setting(predictor: Predictor) -> None:
    """learned.trust_retry is nominal Verify's; under robust Verify learned.robust_trust_retry
    (default 0) is the wait (contract)."""
    base = {"learned.trust_retry": 3, "learned.robust_trust_retry": 5}
    nominal = constant_governor(Predictor.from_config(predictor.config.replace(**base)), 1.0)
    robust = constant_governor(Predictor.from_config(predictor.config.replace(**base, **{"tsg.robust": True})), 1.0)
    assert (nominal.trust.retry, robust.trust.retry) == (3, 5)
    default = constant_governor(Predictor.from_config(predictor.config.replace(**{"tsg.robust": True})), 1.0)
    assert default.trust.retry == 0 and constant_governor(predictor, 1.0).trust.retry == 2


def test_a_searching_governor_consults_its_network_only_to_judge_it(predictor: Predictor) -> None:
    """Searching (credit 0: learned.trust_credit = 0 never trusts), every active update is the
    rule's search; the network is consulted exactly on the updates whose π* moved τ_prev beyond
    the audit's reach (LearnedGovernor.judgeable: a shadow judgement), never on the others."""
    pred = Predictor.from_config(predictor.config.replace(**{"learned.trust_credit": 0,
                                                             "mission.duration_s": 3600.0}))
    gov = constant_governor(pred, 3.0)
    consulted = []
    network = gov.proposal
    gov.proposal = lambda *args: consulted.append(args) or network(*args)   # type: ignore[method-assign]
    res = run_mission(gov, sample_start(pred, 2), 2)
    active = [u for u in res.updates if u.active and u.path == PATH_SEARCH]
    judged = [u for u in active if gov.judgeable(u.tau_prev, u.tau_s)]
    assert len(active) >= 10 and 0 < len(judged) < len(active)
    assert len(consulted) == len(judged)


@functools.lru_cache(maxsize=1)
def _robust_updates() -> tuple:
    """The update states of a conventional mission under robust Verify, realistic truth, start 1."""
    from cikan_ros.config import truth_overrides

    pred = Predictor.from_config(load_config(None, **truth_overrides("realistic"), **{"tsg.robust": True}))
    return tuple(run_mission(ConventionalGovernor(pred), sample_start(pred, 1), 1).update_states())


@pytest.mark.parametrize("tail_s", [0.1, 0.0])
def test_the_robust_tail_is_the_conventional_search(predictor: Predictor, tail_s: float) -> None:
    """With ``learned.tail_rule: search``, under robust Verify an update with |τ_prev| <=
    learned.robust_tail_s is the conventional
    TSG's π* on the anchored chief (path "tail"), scheduled or not, whatever the network proposes
    (here 1 µs: every proposal too aggressive) and however trusted; with 0 the keep rule decides
    there; under nominal Verify never."""
    from cikan_ros.config import truth_overrides
    from cikan_ros.governor import PATH_TAIL

    cfg = load_config(None, **truth_overrides("realistic"),
                      **{"tsg.robust": True, "learned.robust_tail_s": tail_s, "learned.tail_rule": "search"})
    pred = Predictor.from_config(cfg)
    tail = [s for s in _robust_updates() if 0.0 < abs(s.tau_prev) <= 0.1]
    assert len(tail) >= 4 and {s.k % cfg.learned.probe_every == 0 for s in tail} == {True, False}
    gov = constant_governor(pred, 1e-6)
    for s in tail[:6]:
        gov.trust.grant()
        rec = gov.update(s.x_d, s.x_c, s.t, s.tau_prev)
        if tail_s:
            star, calls = gov.anchor(s.x_c, s.t).optimal_shift(s.x_d, s.t, s.tau_prev)
            assert (rec.path, rec.tau_s, rec.verify_calls) == (PATH_TAIL, star, calls)
        else:
            assert rec.path != PATH_TAIL
    assert not constant_governor(predictor, 1e-6)._robust_tail(predictor, -0.05)   # nominal Verify


def test_the_robust_tail_gallops_from_the_last_progress() -> None:
    """``learned.tail_rule: gallop`` (the default): in robust Verify's tail the first update
    with no progress known is the conventional search [tail]; after a move, each update searches
    around the last progress q (Predictor.gallop with q, tail_growth, tail_budget on the anchored
    chief) [gallop], its answer that gallop's followed by the zero test, and q becomes the
    update's own progress 1 - τ/τ_prev; TAIL_MISSES gallops in a row without progress hand the
    next update to the conventional search again."""
    from cikan_ros.config import truth_overrides
    from cikan_ros.governor import PATH_GALLOP, PATH_TAIL, PATH_VERIFY_ZERO
    from cikan_ros.learn.governor import TAIL_MISSES

    cfg = load_config(None, **truth_overrides("realistic"), **{"tsg.robust": True})
    assert cfg.learned.tail_rule == "network"   # the default: a network of ln|tau| (below) gallops
    lc = cfg.learned
    pred = Predictor.from_config(cfg)
    tail = [s for s in _robust_updates() if 0.0 < abs(s.tau_prev) <= lc.robust_tail_s]
    gov = constant_governor(pred, 1e-6)
    paths = []
    for i, s in enumerate(tail[:8]):
        q = gov._progress
        rec = gov.update(s.x_d, s.x_c, s.t, s.tau_prev)
        paths.append(rec.path)
        anchored = gov.anchor(s.x_c, s.t)
        if i == 0:
            star, calls = anchored.optimal_shift(s.x_d, s.t, s.tau_prev)
            assert (rec.path, rec.tau_s, rec.verify_calls) == (PATH_TAIL, star, calls)
        elif rec.path != PATH_TAIL:
            tau, q_got, q_fail, calls = anchored.gallop(s.x_d, s.t, s.tau_prev, q, lc.tail_growth, lc.tail_budget)
            assert calls <= lc.tail_budget
            if rec.path == PATH_GALLOP:
                # the zero test (|τ| <= zero_snap_s) failed, or none; none either when the
                # gallop's own candidate 0 failed (q_fail = 1)
                zero_test = 0.0 < abs(tau) <= cfg.tsg.zero_snap_s and q_fail != 1.0
                assert (rec.tau_s, rec.verify_calls) == (tau, calls + zero_test)
            else:                                                       # it passed
                assert rec.path == PATH_VERIFY_ZERO and rec.tau_s == 0.0 and rec.verify_calls == calls + 1
                assert abs(tau) <= cfg.tsg.zero_snap_s
        if rec.tau_s != s.tau_prev:
            assert gov._progress == pytest.approx(1.0 - rec.tau_s / s.tau_prev, rel=0, abs=1e-15)
    assert PATH_GALLOP in paths
    # A last progress below learned.tail_min_progress (a creeping tail): the conventional search.
    s = tail[1]
    gov._progress, gov._tail_misses = 0.99 * lc.tail_min_progress, 0
    assert gov.update(s.x_d, s.x_c, s.t, s.tau_prev).path == PATH_TAIL
    # Without that floor, a gallop that cannot move (its q far below the tolerance's step) counts
    # as a miss, and TAIL_MISSES of them hand the next update to the conventional search.
    gov = constant_governor(Predictor.from_config(cfg.replace(**{"learned.tail_min_progress": 0.0})), 1e-6)
    gov._progress, gov._tail_misses = 1e-9, 0
    for _ in range(TAIL_MISSES):
        assert gov.update(s.x_d, s.x_c, s.t, s.tau_prev).path == PATH_GALLOP
    assert gov.update(s.x_d, s.x_c, s.t, s.tau_prev).path == PATH_TAIL


@pytest.mark.parametrize("growth", [2.0, 4.0])
def test_the_gallop_skips_only_a_zero_test_it_made_itself(growth: float) -> None:
    """A gallop whose own candidate 0 failed skips the keep rule's zero test (the same Verify,
    the same answer); every other gallop answer near 0 gets it. So a whole robust mission flies
    the same τ history as with the zero test after every gallop, start by start. With
    tail_growth 4 the gallop reaches 0 itself from a progress of 1/4 (fewer Verify calls on some
    start); with 2 (budget 3) a gallop can spend its budget at 0.75 of the way with 0 untried,
    whose zero test then passes (a flag that took "nothing failed" for "0 failed" skipped it and
    changed start 1010's mission under the networks of ln|τ*|)."""
    from cikan_ros.config import truth_overrides
    from cikan_ros.governor import PATH_GALLOP
    from cikan_ros.learn.governor import load_learned_governor

    cfg = load_config(None, **truth_overrides("realistic"),
                      **{"tsg.robust": True, "learned.tail_rule": "gallop", "learned.tail_growth": growth,
                         "learned.tail_budget": 3})
    pred = Predictor.from_config(cfg)
    saved = 0
    for seed in (1010, *range(1001, 1010)):   # until a start's gallop verified 0 itself (growth 4)
        runs = []
        for always in (False, True):
            gov = load_learned_governor("cikan", pred)   # the paper orbit's robust CIKAN
            if always:
                tail = gov._tail
                gov._tail = lambda *a: (lambda r: (setattr(gov, "_zero_failed", False), r)[1])(tail(*a))
            runs.append(run_mission(gov, sample_start(pred, seed), seed))
        skipped, forced = runs
        assert np.array_equal(skipped.tau, forced.tau), seed
        assert any(u.path == PATH_GALLOP for u in skipped.updates)
        calls = [sum(u.verify_calls for u in r.updates) for r in runs]
        assert calls[0] <= calls[1]
        saved += calls[1] - calls[0]
        if growth == 4.0 and saved:
            break
    assert saved > 0 if growth == 4.0 else saved == 0


def test_a_timed_update_starts_from_the_missions_progress() -> None:
    """The benchmark's states carry the mission's last progress before each update
    (BenchStates.progress: 1 - τ_{k-1} / τ_{k-2} of its last move, NaN before any), and
    cikan_ros.timing.prime sets a learned governor's tail rule to it before every timed update:
    a tail state timed after any other state, or repeated, gives the same decision."""
    from cikan_ros.config import truth_overrides
    from cikan_ros.governor import PATH_GALLOP
    from cikan_ros.learn.governor import load_learned_governor
    from cikan_ros.timing import collect_states, timed_update

    cfg = load_config(None, **truth_overrides("realistic"), **{"tsg.robust": True, "learned.tail_rule": "gallop"})
    states = collect_states(cfg, n_missions=2)
    assert len(states.progress) == len(states.updates)
    assert math.isnan(states.progress[0])
    for i in range(1, len(states.updates)):
        prev, s = states.updates[i - 1], states.updates[i]
        if s.t > prev.t and s.tau_prev != prev.tau_prev:   # the same mission, τ moved
            assert states.progress[i] == 1.0 - s.tau_prev / prev.tau_prev
    gov = load_learned_governor("cikan", Predictor.from_config(cfg))
    tail = [i for i, s in enumerate(states.updates)
            if 0.0 < abs(s.tau_prev) <= cfg.learned.robust_tail_s and states.progress[i] >= 0.05]
    assert tail
    i = tail[len(tail) // 2]
    args = (states.updates[i], states.priors[i], states.progress[i])
    first = timed_update(gov, *args)[0]
    assert first.path == PATH_GALLOP
    for j in (0, tail[0], len(states.updates) - 1):   # anything timed before it
        timed_update(gov, states.updates[j], states.priors[j], states.progress[j])
        again = timed_update(gov, *args)[0]
        assert (again.tau_s, again.path, again.verify_calls) == (first.tau_s, first.path, first.verify_calls)


def test_the_robust_tails_searches_back_off_while_they_find_nothing() -> None:
    """``learned.tail_backoff`` B: a conventional search in robust Verify's tail that finds no
    progress (π* = τ_prev, a state of a robust mission where that holds; the tail widened to
    take it in) holds τ_prev, path
    "keep" and no Verify call, for the next 1, 2, 4, ... (at most B) updates before it searches
    again; a search that finds progress resets the holds; B = 0 searches every time (the
    default, as before)."""
    from cikan_ros.config import truth_overrides
    from cikan_ros.governor import PATH_KEEP, PATH_TAIL

    # A tail as wide as the mission (robust_tail_s 1e3 s): its states include stalls
    base = {**truth_overrides("realistic"), "tsg.robust": True, "learned.tail_rule": "search",
            "learned.robust_tail_s": 1e3}
    pred = Predictor.from_config(load_config(None, **base))
    tail = [s for s in _robust_updates() if 0.0 < abs(s.tau_prev) <= 1e3]
    probe = constant_governor(pred, 1e-6)

    def star(s: Any) -> float:
        return probe.anchor(s.x_c, s.t).optimal_shift(s.x_d, s.t, s.tau_prev)[0]
    stall = next(s for s in tail if star(s) == s.tau_prev)
    move = next(s for s in tail if star(s) != s.tau_prev)
    expected = {0: "T" * 12, 4: "TKTKKTKKKKTK"}
    for backoff, want in expected.items():
        gov = constant_governor(Predictor.from_config(load_config(None, **base, **{"learned.tail_backoff": backoff})), 1e-6)
        got = ""
        for _ in range(12):
            rec = gov.update(stall.x_d, stall.x_c, stall.t, stall.tau_prev)
            assert rec.tau_s == stall.tau_prev
            assert rec.verify_calls == 0 if rec.path == PATH_KEEP else rec.path == PATH_TAIL
            got += "K" if rec.path == PATH_KEEP else "T"
        assert got == want, backoff
    # progress found resets the wait: after it, a stall holds for one update again
    gov = constant_governor(Predictor.from_config(load_config(None, **base, **{"learned.tail_backoff": 4})), 1e-6)
    for _ in range(5):   # T K T K K: the holds done
        gov.update(stall.x_d, stall.x_c, stall.t, stall.tau_prev)
    rec = gov.update(move.x_d, move.x_c, move.t, move.tau_prev)
    assert rec.path == PATH_TAIL and rec.tau_s != move.tau_prev
    paths = [gov.update(stall.x_d, stall.x_c, stall.t, stall.tau_prev).path for _ in range(3)]
    assert paths == [PATH_TAIL, PATH_KEEP, PATH_TAIL]


def test_hold_first_candidates_golden() -> None:
    """learned.search_rule "hold-first": the shifts verified, closest to 0 first. From τ_prev =
    -8 s with depth 2: 0 and the midpoints 1/2, 1/4 of the way (-4, -6 s); a last progress of
    0.01 with ladder factors (2, 1): q = 0.02, 0.01 (-7.84, -7.92 s); the hold test q = 1e-4
    (-7.9992 s). Ahead (+8 s) the mirror image, and with no progress known (NaN) no ladder. Near
    0: a hold test below the 10-us tolerance moves by the tolerance (-50 us: -40 us), steps
    within it are left out, and from within the tolerance only 0 is tried."""
    from cikan_ros.learn.governor import hold_first_candidates as cands

    tol = 10_000
    assert cands(-8_000_000_000, 0.01, tol, 1e-4, 2, (2.0, 1.0)).tolist() == [
        0, -4_000_000_000, -6_000_000_000, -7_840_000_000, -7_920_000_000, -7_999_200_000]
    assert cands(8_000_000_000, math.nan, tol, 1e-4, 2, (2.0, 1.0)).tolist() == [
        0, 4_000_000_000, 6_000_000_000, 7_999_200_000]
    # ladder rungs outside (hold_test, 2^-depth) are left out: 0.01 * 40 = 0.4 > 1/4
    assert cands(-8_000_000_000, 0.01, tol, 1e-4, 2, (40.0,)).tolist() == [0, -4_000_000_000, -6_000_000_000,
                                                                           -7_999_200_000]
    assert cands(-50_000, 0.01, tol, 1e-4, 2, (2.0, 1.0)).tolist() == [0, -25_000, -37_500, -40_000]
    assert cands(-5_000, 0.01, tol, 1e-4, 2, (2.0, 1.0)).tolist() == [0]


@given(tau_prev_ns=st.integers(-10**12, 10**12).filter(lambda v: v != 0),
       progress=st.one_of(st.just(math.nan), st.floats(0.0, 1.0)),
       hold=st.floats(1e-9, 0.5), depth=st.integers(0, 12),
       ladder=st.lists(st.floats(0.01, 100.0), max_size=6))
@settings(max_examples=300, deadline=None)
def test_hold_first_candidates_property(tau_prev_ns: int, progress: float, hold: float, depth: int,
                                        ladder: list[float]) -> None:
    """Every candidate lies between τ_prev and 0 (0 included), at least the tolerance from τ_prev
    or 0 itself, on τ_prev's side, in strictly increasing distance from 0; 0 comes first."""
    from cikan_ros.learn.governor import hold_first_candidates as cands

    tol = 10_000
    c = cands(tau_prev_ns, progress, tol, hold, depth, tuple(ladder)).tolist()
    assert c[0] == 0
    side = 1 if tau_prev_ns > 0 else -1
    m = [side * v for v in c]
    assert all(a < b for a, b in zip(m, m[1:]))
    assert all(0 <= v and (v == 0 or abs(tau_prev_ns) - v >= tol) for v in m)


@pytest.mark.parametrize("approach", ["behind", "ahead"])
def test_the_hold_first_search_verifies_its_candidates_in_order(approach: str) -> None:
    """learned.search_rule "hold-first", a network never trusted (trust_credit 0), the paper's
    orbit for an hour: every active update with |τ_prev| above hold_first_above_s (0 here) is
    the first candidate that passes [search-ladder], or, none passing, τ_prev [search-hold] with as
    many calls as candidates, each judged here by Verify on the anchored chief, candidate by
    candidate; after such a hold the next 1, 2, 4, ... (at most search_backoff) updates hold
    without a call, and progress found resets the wait. All three kinds occur, and the mission
    flies without a violation."""
    from cikan_ros.governor import PATH_SEARCH_HOLD, PATH_SEARCH_LADDER
    from cikan_ros.learn.governor import hold_first_candidates

    cfg = load_config(None, **{"learned.trust_credit": 0, "learned.search_rule": "hold-first",
                               "learned.hold_first_above_s": 0.0, "learned.search_backoff": 4,
                               "mission.duration_s": 3600.0, "mission.approach": approach})
    lc = cfg.learned
    pred = Predictor.from_config(cfg)
    gov = constant_governor(pred, 3.0)
    res = run_mission(gov, sample_start(pred, 3), 3)
    assert res.metrics()["violations"] == 0
    active = [u for u in res.updates if u.active]
    assert {u.path for u in active} <= {PATH_SEARCH_HOLD, PATH_SEARCH_LADDER}
    kinds = {(u.path, u.verify_calls > 0) for u in active}
    assert kinds == {(PATH_SEARCH_HOLD, True), (PATH_SEARCH_HOLD, False), (PATH_SEARCH_LADDER, True)}, kinds
    progress, wait, holds = math.nan, 0, 0
    records = {u.k: u for u in active}
    for s in res.update_states():
        u = records[s.k]
        if holds:
            assert (u.path, u.tau_s, u.verify_calls) == (PATH_SEARCH_HOLD, u.tau_prev, 0)
            holds -= 1
            continue
        anchored = gov.anchor(s.x_c, s.t)
        ns = hold_first_candidates(round(s.tau_prev * 1e9), progress, pred.tol_ns, lc.hold_test,
                                   lc.search_depth, lc.search_ladder)
        passed = [anchored.verify(s.x_d, s.t, c / 1e9) for c in ns]
        first = next((j for j, ok in enumerate(passed) if ok), None)
        if first is None:
            assert (u.path, u.tau_s, u.verify_calls) == (PATH_SEARCH_HOLD, u.tau_prev, len(ns))
            wait = min(max(2 * wait, 1), lc.search_backoff)
            holds = wait
        else:
            assert (u.path, u.tau_s, u.verify_calls) == (PATH_SEARCH_LADDER, ns[first] / 1e9, first + 1)
            wait = 0
        if u.tau_s != u.tau_prev:
            progress = 1.0 - u.tau_s / u.tau_prev


def test_the_stall_rule_searches_as_the_search_rule_says(predictor: Predictor) -> None:
    """With learned.search_rule "hold-first" the stall rule's search is the hold-first search:
    the network that never proposes progress (constant 1e6 s) holds τ_0 for three updates, and
    the fourth answers the first of hold_first_candidates (no progress known yet) that passes
    Verify on the anchored chief (τ_prev after as many calls when none does), path "stall"."""
    from cikan_ros.learn.governor import hold_first_candidates

    cfg = predictor.config.replace(**{"learned.audit_step": 0.0, "learned.probe_budget": 0,
                                      "learned.stall_updates": 3, "learned.trust_retry": 0,
                                      "learned.search_rule": "hold-first", "learned.hold_first_above_s": 0.0,
                                      "mission.duration_s": 900.0})
    pred = Predictor.from_config(cfg)
    gov = constant_governor(pred, 1e6)
    res = run_mission(gov, sample_start(pred, 1), 1)
    active = [u for u in res.updates if u.active]
    assert [u.path for u in active[:4]] == [PATH_KEEP] * 3 + [PATH_STALL]
    s = next(s for s in res.update_states() if s.k == active[3].k)
    lc = cfg.learned
    ns = hold_first_candidates(round(s.tau_prev * 1e9), math.nan, pred.tol_ns, lc.hold_test,
                               lc.search_depth, lc.search_ladder)
    anchored = gov.anchor(s.x_c, s.t)
    first = next((j for j, c in enumerate(ns) if anchored.verify(s.x_d, s.t, c / 1e9)), None)
    expected = (s.tau_prev, len(ns)) if first is None else (ns[first] / 1e9, first + 1)
    assert (active[3].tau_s, active[3].verify_calls) == expected


def test_decision_paths_are_distinct_from_the_graphs_no_decision_source() -> None:
    """Every decision path of the built-in governors is its own text, and none is the source the
    governor node publishes on a step with no decision (graph_spec.PATH_HOLD, "hold"): a bag
    reader tells the two apart by the text alone (a searching update that holds is "search-hold")."""
    import cikan_ros.governor as g
    from cikan_ros.ros.graph_spec import PATH_HOLD

    paths = [v for k, v in vars(g).items() if k.startswith("PATH_")]
    assert len(paths) == len(set(paths)) and PATH_HOLD not in paths
    assert set(g.SEARCHING_PATHS) <= set(paths)


@pytest.mark.parametrize("approach", ["behind", "ahead"])
def test_the_tail_network_rule_verifies_its_candidates_in_order(approach: str) -> None:
    """``learned.tail_rule: network`` with a network of the step (the paper orbit's robust
    CIKAN, target log-ratio): every tail update it answers [nn] is the first of its candidates
    τ_c (1 - s), s in ``learned.tail_ladder``, τ_c = side |τ_prev| exp(NN) (here from the
    batch forward of the features, not the governor's compiled call), that passes Verify on the
    anchored chief, candidate by candidate; its calls are the candidates tried plus the zero test
    (|τ| <= zero_snap_s). The network answers most of the tail, and τ reaches 0 without a
    violation."""
    from cikan_ros.config import truth_overrides
    from cikan_ros.governor import PATH_NN
    from cikan_ros.learn.features import features
    from cikan_ros.learn.governor import load_learned_governor
    from cikan_ros.tsg import quantise_shift

    cfg = load_config(None, **truth_overrides("realistic"), **{"tsg.robust": True, "learned.tail_rule": "network",
                                                                "mission.approach": approach,
                                                                "mission.duration_s": 4000.0})
    lc, tol = cfg.learned, cfg.tsg.tolerance_s
    pred = Predictor.from_config(cfg)
    gov = load_learned_governor("cikan", pred)
    assert gov.net.relative
    res = run_mission(gov, sample_start(pred, 1), 1)
    assert res.metrics()["violations"] == 0 and res.tau[-1] == 0.0   # tau = 0 reached within the hour
    records = {u.k: u for u in res.updates}
    tail = [s for s in res.update_states() if 0.0 < abs(s.tau_prev) <= lc.robust_tail_s]
    answered = [s for s in tail if records[s.k].path == PATH_NN]
    assert len(answered) > len(tail) // 2
    side = pred.side
    for s in answered:
        u = records[s.k]
        ln_tau = gov.net.log_shift(features(s.x_d, s.x_c, "vnb-prev", s.tau_prev)[None, :])[0]
        tau_c = quantise_shift(side * math.exp(ln_tau))
        cands: list[float] = []
        for step in lc.tail_ladder:
            c = quantise_shift(tau_c * (1.0 - step))
            if 0.0 <= side * c <= side * s.tau_prev - tol and (not cands or side * c > side * cands[-1]):
                cands.append(c)
        anchored = gov.anchor(s.x_c, s.t)
        first = next(j for j, c in enumerate(cands) if anchored.verify(s.x_d, s.t, c))
        assert u.tau_s == cands[first]
        assert u.verify_calls == first + 1 + (abs(u.tau_s) <= cfg.tsg.zero_snap_s)


@pytest.mark.parametrize("case", ["log-shift", "foreign"])
def test_the_tail_is_the_gallops_without_a_network_of_its_steps(case: str) -> None:
    """``learned.tail_rule: network`` asks a network of the step made for this Verify; a network
    of ln|τ| (target log-shift: here a constant one), or the robust CIKAN of the step flown at
    another truth scale (0.5, ``learned.foreign_model``: its steps are scale 1's), leaves the tail
    to the gallop (or the conventional search before any progress is known), never [nn]."""
    from cikan_ros.config import truth_overrides
    from cikan_ros.governor import PATH_GALLOP, PATH_NN, PATH_TAIL
    from cikan_ros.learn.governor import load_learned_governor

    extra = {"truth.scale": 0.5, "learned.foreign_model": True} if case == "foreign" else {}
    cfg = load_config(None, **{**truth_overrides("realistic"), "tsg.robust": True, "learned.tail_rule": "network",
                               "mission.duration_s": 4000.0, **extra})
    pred = Predictor.from_config(cfg)
    if case == "foreign":
        gov = load_learned_governor("cikan", pred)
        assert gov.net.relative and gov.foreign is not None
    else:
        gov = constant_governor(pred, 1e-3)
        assert not gov.net.relative
    res = run_mission(gov, sample_start(pred, 1), 1)
    tail = [u for u in res.updates if u.active and abs(u.tau_prev) <= cfg.learned.robust_tail_s]
    assert tail and {u.path for u in tail} <= {PATH_GALLOP, PATH_TAIL, "verify-zero"}
    assert PATH_NN not in {u.path for u in tail}
