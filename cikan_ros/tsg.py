"""Verify (the closed-loop prediction) and the conventional Time Shift Governor searches (SPEC §5).

Verify(x_d, t_k, tau): from the deputy state x_d at time t_k, track the virtual target
x_v(t) = x_c(t + tau) with the saturated FTRE law and ZOH over samples j = 0 .. N_p - 1; at each
sample check the constraints first (deputy minus the real chief), then the terminal set (deputy
minus the virtual target), then apply the control and step. True iff the terminal set is reached
before any violation within the horizon.

Feasibility is NOT monotone in tau near the boundary (predicted trajectories graze the LoS cone),
so the bisection keeps a verified lower end: its answer is always feasible and lies within the
tolerance of an infeasible shift. That deterministic answer is what this project calls pi*.
The whole search runs inside one compiled call.

Robust Verify (``tsg.robust``; derivation in docs/robustness.md) runs the same rollout from the
measured state and carries two scalar tube radii along it, rho_j (position, km) and sigma_j
(velocity, km/s): bounds on |truth - prediction| at sample j under the declared error bounds
(navigation, thruster, disturbance, unmodelled J2), from the closed-loop error dynamics of the
FTRE law. Each constraint is then checked on the whole ball around the predicted state: h1 as the
distance of the predicted position to the cone's surface, |p| sin(alpha - theta) >= rho_j; h3 with
|v| + sigma_j and |p| - rho_j; at the terminal set, on the ball the truth can reach afterwards
(the loop's own transient from there plus the tube's invariant set). The tube's kernels live in
:mod:`cikan_ros.robust`, beside the constants they use; the rollout here calls them.
With every bound 0 the tubes are 0 and robust Verify answers as nominal Verify, but for that
terminal ball: the transient it lets go must keep h1 and h3 too.

The kernels of the prediction (here and in orbit, dynamics, control, constraints, robust)
compile with numba's ``error_model="numpy"``: a float division by zero gives inf or NaN, which
no check accepts (a NaN state never reaches the terminal set), instead of a branch to raise
ZeroDivisionError before every division; the same bits, a Verify 5-6 % faster (measured).

The chief comes from its measured state (:class:`ChiefAnchor`): predictions start from the chief
state received at t_k, propagated as a Kepler orbit, re-anchored whenever the measurement departs
from the model by more than ``tsg.chief_anchor_tolerance_km``.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from typing import Sequence

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .config import Config, Side, ancillary_band_configs, control_config, prediction_gravity
from .constraints import (C_UMAX, constraint_params, h1_line_of_sight_kernel, h2_thrust_kernel,
                          h3_approach_velocity_kernel)
from .control import ftre_control_kernel, gain_table
from .dynamics import j2_coefficient, rk4_kernel
from .errors import NoFeasibleShiftError, StateError
from .orbit import (N_PARAMS, P_E, P_M0, P_MU, P_N, KeplerOrbit, check_states,
                    eccentric_anomaly_kernel, osculating_params_kernel, state_from_anomaly_kernel,
                    state_kernel, state_warm_kernel)
from .robust import (HANDOFF_FTRE, R_BETWEEN, R_GAMMA, R_L1, R_ON, R_SINA, R_TUBE, R_ZETA, ancillary_command_bound,
                     ancillary_docks, ancillary_start, ancillary_step, ancillary_terminal_ok, frame_rates,
                     interval_ok, robust_params, robust_terminal_ok, sample_excess, truth_acceleration, tube_next,
                     tube_ok, tube_start)
from .units import ns_to_seconds
from .units import seconds_to_ns as to_ns

def quantise_shift(tau: float) -> float:
    """tau rounded to a whole nanosecond, as every shift a governor verifies and returns."""
    return ns_to_seconds(to_ns(tau))


# Layout of the packed prediction parameters.
# T_J2R2: 3/2 J2 R^2 of the prediction's gravity (0: two-body, the paper's model).
T_SAMPLE, T_NSAMPLES, T_SUBSTEPS, T_TERM_POS, T_TERM_VEL, T_J2R2 = range(6)
#: Columns of a chief row under the J2 prediction model: state, a "computed" flag (the anomaly
#: column of the two-body rows), and the packed osculating orbit of the row (mean anomaly at
#: the row's own time), from which the virtual target is propagated by tau.
J2_ROW_ORBIT = slice(7, 7 + N_PARAMS)
J2_ROW_WIDTH = 7 + N_PARAMS


@nb.njit(cache=True, error_model="numpy")
def chief_row_kernel(orb: NDArray, t: float, row: NDArray) -> None:
    """Chief state x_c(t) and its eccentric anomaly into ``row`` (7,), solved from scratch (no warm
    start), so a row's bits do not depend on which update computed it first."""
    row[6] = eccentric_anomaly_kernel(orb[P_M0] + orb[P_N] * t, orb[P_E])
    state_from_anomaly_kernel(orb, row[6], row, False)


@nb.njit(cache=True, error_model="numpy")
def chief_row_j2_kernel(chief: NDArray, j: int, ts: float, sub: int, mu: float, j2r2: float) -> None:
    """J2 prediction model: chief row j (>= 1) integrated from row j - 1 (RK4 with J2, no
    thrust), with its osculating orbit packed beside it. Row 0 is the anchored chief state."""
    row = chief[j]
    prev = chief[j - 1]
    if prev[6] != prev[6]:
        chief_row_j2_kernel(chief, j - 1, ts, sub, mu, j2r2)
    zero = np.zeros(3)
    rk4_kernel(prev[:6], zero, ts, sub, mu, row[:6], j2r2)
    osculating_params_kernel(row, mu, row[7:7 + N_PARAMS])
    row[6] = 0.0


@nb.njit(cache=True, error_model="numpy")
def j2_rows_start_kernel(orb: NDArray, t: float, mu: float, rows: NDArray) -> None:
    """J2 prediction model: row 0 of ``rows`` (N_p, J2_ROW_WIDTH) is the anchored chief at t with
    its osculating orbit; rows 1, 2, ... computed before (a prefix: :func:`chief_row_j2_kernel`
    fills row j after row j - 1) are marked not computed. A buffer reused from an earlier update
    thus costs its rows' reset, not a fresh (N_p, J2_ROW_WIDTH) array."""
    state_kernel(orb, t, rows[0])
    osculating_params_kernel(rows[0], mu, rows[0, J2_ROW_ORBIT])
    rows[0, 6] = 0.0
    for j in range(1, rows.shape[0]):
        if rows[j, 6] != rows[j, 6]:
            break
        rows[j, 6] = math.nan


@nb.njit(cache=True, error_model="numpy")
def verify_kernel(orb: NDArray, table: NDArray, cp: NDArray, tp: NDArray, rp: NDArray,
                  x0: NDArray, t_k: float, tau: float, chief: NDArray, chief_t0: float) -> bool:
    """Verify(x0, t_k, tau) with packed orbit/gains/constraint/prediction/robustness parameters;
    with ``rp[R_ZETA]`` > 0 also at tau - zeta and tau + zeta (the paper's interval, sampled at
    its ends). See :func:`rollout_kernel`."""
    none = chief[:0]  # no trace (an empty view: no allocation)
    if not rollout_kernel(orb, table, cp, tp, rp, x0, t_k, tau, chief, chief_t0, none):
        return False
    zeta = rp[R_ZETA]
    if zeta > 0.0:
        return (rollout_kernel(orb, table, cp, tp, rp, x0, t_k, tau - zeta, chief, chief_t0, none)
                and rollout_kernel(orb, table, cp, tp, rp, x0, t_k, tau + zeta, chief, chief_t0, none))
    return True


@nb.njit(cache=True, error_model="numpy")
def rollout_kernel(orb: NDArray, table: NDArray, cp: NDArray, tp: NDArray, rp: NDArray,
                   x0: NDArray, t_k: float, tau: float, chief: NDArray, chief_t0: float,
                   trace: NDArray) -> bool:
    """One prediction: Verify(x0, t_k, tau) for a single shift.

    ``chief`` (>= N_p, 7) caches the chief states x_c(chief_t0 + j T_s) (chief_t0 = t_k up to
    rounding; see :class:`ChiefCache`) and their eccentric anomalies, which do not depend on tau:
    a row whose anomaly is NaN is computed on first use and reused by every later Verify.
    With ``rp[R_ON]`` the constraints and the terminal set are checked on the tube around the
    prediction (module docstring; the tube's kernels are in :mod:`cikan_ros.robust`).
    ``trace`` (N_p, TRACE_WIDTH), or an empty array for none, receives under robust Verify each
    checked sample's predicted deputy, rho, sigma, 0, the command applied from it (km/s^2) and the
    predicted chief, and at the accepting sample the virtual target, the terminal ball's radii,
    the loop the truth flies on with (:data:`~cikan_ros.robust.HANDOFF_FTRE` 1, or under the
    ancillary tube :data:`~cikan_ros.robust.HANDOFF_TRACK` 2: the tracking law holding x_v) and
    in columns 18-21 what the terminal test started from (the prediction's distance and speed
    from x_v, rho and sigma there: :func:`~cikan_ros.robust.terminal_ball_after`; under the l1
    bound, columns 22-28: the ancillary tube's recursions R1, S1, R2, S2, the sample and the
    navigation bounds at sample 0): what ``cikan
    coverage`` compares the truth with, and what the ancillary tube's controller tracks.
    Under the ancillary tube (``rp[R_TUBE]``) the prediction flies at gamma u_max and the tube is
    :func:`~cikan_ros.robust.ancillary_step`'s, which refuses a shift whose tracking law could
    saturate.
    """
    ts = tp[T_SAMPLE]
    n = int(tp[T_NSAMPLES])
    sub = int(tp[T_SUBSTEPS])
    j2r2 = tp[T_J2R2]
    tpos2 = tp[T_TERM_POS] ** 2
    tvel2 = tp[T_TERM_VEL] ** 2
    mu = orb[P_MU]
    e = orb[P_E]
    dm = orb[P_N] * ts  # mean-anomaly advance per sample
    u_max = cp[C_UMAX]
    robust = rp[R_ON] != 0.0
    ancillary = rp[R_TUBE] != 0.0
    u_pred = rp[R_GAMMA] * u_max if ancillary else u_max  # the prediction's thrust limit
    r2 = s2 = 0.0  # the ancillary tube's second recursion
    b0p = b0v = 0.0
    between = ancillary and rp[R_BETWEEN] != 0.0
    # the previous sample for the between-samples check: cone and apex excess, range, largest
    # speed, rho, then its interval's acceleration bound and the cone's turn rates
    prev = np.zeros(8)
    x = x0.copy()
    xv = np.empty(6)
    xv_next = np.empty(6)
    nu_next = 0.0
    u = np.empty(3)
    ev = sev = cev = 0.0  # the virtual target's eccentric anomaly, its sine and cosine
    rho = sig = big_r = big_s = 0.0  # tube radii and their state parts
    linear = False
    for j in range(n):
        t = t_k + j * ts
        xc = chief[j]
        if xc[6] != xc[6]:  # NaN: not computed yet
            if j2r2 != 0.0:
                chief_row_j2_kernel(chief, j, ts, sub, mu, j2r2)
            else:
                chief_row_kernel(orb, chief_t0 + j * ts, xc)
        if robust:
            rng = math.sqrt((x[0] - xc[0]) ** 2 + (x[1] - xc[1]) ** 2 + (x[2] - xc[2]) ** 2)
            if j == 0 and ancillary:
                rho, sig, big_r, big_s, r2, s2 = ancillary_start(rp, rng)
                b0p, b0v = rho, sig  # the navigation bounds at sample 0 (the l1 bound's transients)
            elif j == 0:  # the measured state
                rho, sig, big_r, big_s = tube_start(rp, rng)
            if trace.shape[0] > 0:
                trace[j, :6] = x
                trace[j, 6] = rho
                trace[j, 7] = sig
                trace[j, 8] = 0.0
                trace[j, 12:18] = xc[:6]
            if not tube_ok(x, xc, cp, rp, rho, sig):
                return False
            if between:  # the truth from the previous sample to this one (robust.interval_ok)
                cone, apex = sample_excess(x, xc, cp, rp[R_SINA], rho)
                vmax = math.sqrt((x[3] - xc[3]) ** 2 + (x[4] - xc[4]) ** 2 + (x[5] - xc[5]) ** 2) + sig
                if j > 0 and not interval_ok(cp, ts, prev[0], prev[1], prev[2], prev[3], cone, apex, rng,
                                             vmax, prev[4], rho, prev[5], prev[6], prev[7]):
                    return False
                prev[0], prev[1], prev[2], prev[3], prev[4] = cone, apex, rng, vmax, rho
        else:
            if h1_line_of_sight_kernel(x, xc, cp) > 0.0:
                return False
            if h3_approach_velocity_kernel(x, xc, cp) > 0.0:
                return False
        if j2r2 != 0.0:  # the controller's virtual target: the chief's own orbit, tau away
            if j == 0:
                ev = eccentric_anomaly_kernel(xc[7 + P_M0] + xc[7 + P_N] * tau, xc[7 + P_E])
                nu_v = state_from_anomaly_kernel(xc[7:7 + N_PARAMS], ev, xv)
                sev, cev = math.sin(ev), math.cos(ev)
            else:  # Newton from the previous sample's anomaly, advanced by one sample
                e = xc[7 + P_E]
                nu_v, ev, sev, cev = state_warm_kernel(xc[7:7 + N_PARAMS], tau, ev, sev, cev,
                                                       xc[7 + P_N] * ts / (1.0 - e * cev), xv)
        elif j == 0:
            ev = eccentric_anomaly_kernel(orb[P_M0] + orb[P_N] * (t + tau), e)
            nu_v = state_from_anomaly_kernel(orb, ev, xv)
            sev, cev = math.sin(ev), math.cos(ev)
        else:  # solved during the previous sample's RK4 step (below)
            xv, xv_next = xv_next, xv
            nu_v = nu_next
        dp2 = 0.0
        dv2 = 0.0
        for i in range(3):
            dp2 += (x[i] - xv[i]) ** 2
            dv2 += (x[3 + i] - xv[3 + i]) ** 2
        if dp2 <= tpos2 and dv2 <= tvel2:
            if not robust:
                return True
            if ancillary:
                ok, ball_p, ball_v, handoff = ancillary_terminal_ok(xv, xc, cp, rp, math.sqrt(dp2),
                                                                    math.sqrt(dv2), rho, sig, ts,
                                                                    big_r, big_s, r2, s2, j, b0p, b0v)
                if ok and tau == 0.0 and rp[R_L1] != 0.0:  # docking: the ball must settle inside the test
                    ok = ancillary_docks(rp, handoff, ts)
            else:
                ok, ball_p, ball_v = robust_terminal_ok(xv, xc, cp, rp, math.sqrt(dp2), math.sqrt(dv2),
                                                        big_r, big_s, linear, ts)
                handoff = HANDOFF_FTRE
            if ok:
                if trace.shape[0] > 0:
                    trace[j, :6] = xv
                    trace[j, 6] = ball_p
                    trace[j, 7] = ball_v
                    trace[j, 8] = handoff
                    trace[j, 18] = math.sqrt(dp2)
                    trace[j, 19] = math.sqrt(dv2)
                    trace[j, 20] = rho
                    trace[j, 21] = sig
                    # the l1 bound's continued handoff (robust.continued_ball_after): the plan's
                    # recursions, this sample and the navigation bounds at sample 0
                    trace[j, 22] = big_r
                    trace[j, 23] = big_s
                    trace[j, 24] = r2
                    trace[j, 25] = s2
                    trace[j, 26] = j
                    trace[j, 27] = b0p
                    trace[j, 28] = b0v
                return True
        a_n = ftre_control_kernel(table, nu_v, x, xv, u_pred, u)  # |u| before saturation
        # h2 holds by saturation up to rounding; checked so a changed control law cannot skip it.
        if h2_thrust_kernel(u, cp) > 1e-12 * u_max:
            return False
        if robust and trace.shape[0] > 0:
            trace[j, 9:12] = u
        if between:  # this interval's acceleration and cone turn rates, for the next sample's check
            u_bound = ancillary_command_bound(rp, ts, x, xc, u, rng, rho, sig, big_r, big_s)
            prev[5] = truth_acceleration(rp, u_bound, rng + rho + prev[3] * ts + 0.5 * u_max * ts * ts,
                                         math.sqrt(xc[0] * xc[0] + xc[1] * xc[1] + xc[2] * xc[2]))
            prev[6], prev[7] = frame_rates(xc, rp, ts)
        if ancillary:
            rho, sig, big_r, big_s, r2, s2, ok = ancillary_step(rp, u_max, ts, x, xc, u, rng, rho, sig,
                                                                big_r, big_s, r2, s2, j, b0p, b0v)
            if not ok:
                return False
        elif robust:  # the tube at sample j + 1 (cikan_ros.robust, docs/robustness.md)
            rho, sig, big_r, big_s, linear = tube_next(rp, u_max, ts, x, xc, u, a_n, rng, rho, sig,
                                                       big_r, big_s, linear)
        if j2r2 == 0.0 and j + 1 < n:
            # The next sample's virtual target, written here so that the processor overlaps its
            # Kepler solve with the RK4 step (independent chains; the same operations, the same
            # bits): a Verify 8-10 % faster (measured).
            nu_next, ev, sev, cev = state_warm_kernel(orb, (t_k + (j + 1) * ts) + tau, ev, sev, cev,
                                                      dm / (1.0 - e * cev), xv_next)
        rk4_kernel(x, u, ts, sub, mu, x, j2r2)
    return False


#: Columns of a rollout trace (:func:`rollout_kernel`).
TRACE_WIDTH = 29


class ChiefCache:
    """Chief states x_c(t + j T_s), j = 0 .. N_p - 1, for the Verify calls at one update time t
    (they do not depend on tau), filled lazily by Verify. ``rows`` (N_p, 7): state and eccentric
    anomaly, NaN anomaly = not computed yet; row j is the chief at ``t0 + j T_s``."""

    def __init__(self, t: float, rows: NDArray, t0: float) -> None:
        self.t = t
        self.rows = rows
        self.t0 = t0


class J2RowBuffer:
    """The J2 prediction model's chief rows (:meth:`Predictor.cache`), one (N_p, J2_ROW_WIDTH)
    buffer reused by the caches of a predictor and its re-anchored copies.

    Under a J2 truth the governors re-anchor on every update, and a fresh buffer per update
    (~0.7 MB for the paper orbit's 4,329 samples, every row marked not computed) cost ~3 us of
    the ~70 us a trusted learned update took (measured). The buffer is handed out again only
    when the cache that holds it is gone (a weak reference: a cache in use is never
    overwritten); else a new one is made. The rows are the same bits either way: row 0 from the
    anchored orbit, row j integrated from row j - 1.
    """

    def __init__(self, n_samples: int) -> None:
        self.n = n_samples
        self.rows: NDArray | None = None
        self._holder: weakref.ref[ChiefCache] | None = None

    def take(self) -> NDArray:
        """A buffer no live cache holds: the one kept (its rows as the last cache left them),
        or a new one with every row marked not computed."""
        if self.rows is not None and (self._holder is None or self._holder() is None):
            return self.rows
        rows = np.empty((self.n, J2_ROW_WIDTH))
        rows[:, 6] = math.nan  # not computed yet
        self.rows = rows
        return rows

    def hold(self, cache: "ChiefCache") -> None:
        """``cache`` now holds the buffer (until it is garbage)."""
        self._holder = weakref.ref(cache)

    def __getstate__(self) -> dict:
        return {"n": self.n}   # a predictor sent to a worker starts without a buffer

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["n"])  # type: ignore[misc]


#: The rows of a :class:`ChiefTable` before its first window: every re-anchored predictor makes
#: a table, on every update under a J2 truth, where its rows are never used.
_NO_ROWS = np.empty((0, 7))
_NO_ROWS.setflags(write=False)


class ChiefTable:
    """Chief states on the absolute sample grid t = i T_s, shared by the updates of a process.

    Updates fall on that grid (t_k = k P_upd, P_upd a multiple of T_s), and the horizons of
    consecutive updates overlap by all but P_upd / T_s samples, so a learned update that runs one
    Verify would otherwise spend ~30 % of it on chief states (measured). Rows are computed from
    scratch at t = i T_s (:func:`chief_row_kernel`), so they are the same bits whichever update
    fills them; the table keeps a window of indices [i0, i0 + capacity) and moves it forward
    (or restarts) when an update falls outside.
    """

    def __init__(self, sample_period_s: float, n_samples: int) -> None:
        self.ts = sample_period_s
        self.n = n_samples
        self.i0 = 0
        self.rows = _NO_ROWS   # no window yet (:meth:`view` makes one; never written)

    def index(self, t: float) -> int | None:
        """Grid index i with i T_s == t exactly, or None when t is off the grid."""
        i = round(t / self.ts)
        return i if i * self.ts == t else None

    def view(self, i: int) -> NDArray:
        """Rows of indices [i, i + N_p) (a view into the table)."""
        lo = i - self.i0
        if lo < 0 or lo + self.n > len(self.rows):
            # New window [i, i + 2 N_p), keeping the rows it shares with the old one.
            rows = np.full((2 * self.n, 7), math.nan)
            a, b = max(self.i0, i), min(self.i0 + len(self.rows), i + len(rows))
            if a < b:
                rows[a - i: b - i] = self.rows[a - self.i0: b - self.i0]
            self.rows, self.i0, lo = rows, i, 0
        return self.rows[lo: lo + self.n]


@nb.njit(cache=True, error_model="numpy")
def bisect_kernel(orb: NDArray, table: NDArray, cp: NDArray, tp: NDArray, rp: NDArray, x0: NDArray, t_k: float,
                  lo_ns: int, hi_ns: int, tol_ns: int, chief: NDArray, chief_t0: float,
                  max_calls: int) -> tuple[int, int, int]:
    """Bisection between lo feasible (not re-verified) and hi infeasible (integer ns), on either
    side of 0: lo < hi behind the chief (tau <= 0), lo > hi ahead of it (tau >= 0). "lo" is the
    verified end, the one farther from 0.

    Returns (lo, hi, Verify calls) at the end: the answer lo is feasible and within ``tol_ns`` of
    the infeasible hi, or, when ``max_calls`` (>= 0; -1: no limit) Verify calls ran out first,
    the verified end reached so far (the bracket is then wider than the tolerance).
    Shifts are whole nanoseconds (the resolution of ROS time stamps), so a verified shift crosses
    the ROS boundary exactly: tau_s = tau_ns / 1e9 on both sides. The midpoint rounds toward lo,
    so the ahead bisection is the behind one mirrored, nanosecond for nanosecond.
    """
    calls = 0
    while abs(hi_ns - lo_ns) > tol_ns and calls != max_calls:
        if hi_ns > lo_ns:
            mid = lo_ns + (hi_ns - lo_ns) // 2
        else:
            mid = lo_ns - (lo_ns - hi_ns) // 2
        calls += 1
        if verify_kernel(orb, table, cp, tp, rp, x0, t_k, mid / 1e9, chief, chief_t0):
            lo_ns = mid
        else:
            hi_ns = mid
    return lo_ns, hi_ns, calls


@nb.njit(cache=True, error_model="numpy")
def first_feasible_kernel(orb: NDArray, table: NDArray, cp: NDArray, tp: NDArray, rp: NDArray, x0: NDArray,
                          t_k: float, cands_ns: NDArray, lo_ns: int, budget: int, tol_ns: int,
                          chief: NDArray, chief_t0: float) -> tuple[int, int, int]:
    """Verify the candidates ``cands_ns`` (integer ns, in the order given) until one passes; if
    none does, bisect on [lo, last candidate] with at most ``budget`` calls (0: none).

    Returns (tau_ns, index of the candidate that passed or -1, Verify calls); with -1, tau_ns
    is the bisection's verified lower end (``lo_ns`` itself when nothing passed). One compiled
    call for a learned update's whole search."""
    n = cands_ns.shape[0]
    for i in range(n):
        if verify_kernel(orb, table, cp, tp, rp, x0, t_k, cands_ns[i] / 1e9, chief, chief_t0):
            return cands_ns[i], i, i + 1
    if budget == 0 or n == 0:
        return lo_ns, -1, n
    tau, _, calls = bisect_kernel(orb, table, cp, tp, rp, x0, t_k, lo_ns, cands_ns[n - 1], tol_ns,
                                  chief, chief_t0, budget)
    return tau, -1, n + calls


@nb.njit(cache=True, error_model="numpy", inline="always")
def _progress_shift_ns(tau_prev_ns: int, q: float) -> int:
    """The shift a fraction q of the way from tau_prev to 0 (q = 1: 0), on the nanosecond grid."""
    return int(round(tau_prev_ns * (1.0 - q))) if q < 1.0 else 0


@nb.njit(cache=True, error_model="numpy")
def gallop_kernel(orb: NDArray, table: NDArray, cp: NDArray, tp: NDArray, rp: NDArray, x0: NDArray,
                  t_k: float, tau_prev_ns: int, q0: float, growth: float, budget: int, tol_ns: int,
                  chief: NDArray, chief_t0: float) -> tuple[int, float, float, int]:
    """Search for progress of about q0 (a fraction of |tau_prev| toward 0) with at most ``budget``
    Verify calls: candidates tau_prev (1 - q). From q0, up (q growth^i, capped at 1: 0 itself)
    while they pass, or down (q0 / growth^i) until one passes; then the bracket [largest q that
    passed, smallest that failed] is split at its geometric mean while calls remain. A step
    smaller than ``tol_ns`` is not tried.

    Returns (tau_ns, q of the answer (0: none passed, tau_ns = tau_prev_ns), the smallest q that
    failed (inf: none), Verify calls). Every answer but tau_prev passed Verify."""
    best = c_fail = tau_prev_ns
    q_pass = 0.0
    q_fail = math.inf
    calls = 0
    q = min(q0, 1.0)
    while calls < budget:
        c = _progress_shift_ns(tau_prev_ns, q)
        if abs(tau_prev_ns - c) < tol_ns or c == best or c == c_fail:
            break
        calls += 1
        if verify_kernel(orb, table, cp, tp, rp, x0, t_k, c / 1e9, chief, chief_t0):
            best, q_pass = c, q
        else:
            q_fail, c_fail = q, c
        if q_fail == math.inf:  # nothing failed yet: up, to 0 at most
            if q >= 1.0:
                break
            q = min(q * growth, 1.0)
        elif q_pass == 0.0:  # nothing passed yet: down
            q = q / growth
        else:  # bracketed
            q = math.sqrt(q_pass * q_fail)
    return best, q_pass, q_fail, calls


@nb.njit(cache=True, error_model="numpy")
def conventional_update_kernel(orb: NDArray, table: NDArray, cp: NDArray, tp: NDArray, rp: NDArray, x0: NDArray,
                               t_k: float, tau_prev_ns: int, tol_ns: int, chief: NDArray,
                               chief_t0: float) -> tuple[int, int]:
    """pi* between tau_prev (!= 0, ns, either sign) and 0: zero test first, then bisection.
    (tau_ns, calls)."""
    if verify_kernel(orb, table, cp, tp, rp, x0, t_k, 0.0, chief, chief_t0):
        return 0, 1
    tau, _, calls = bisect_kernel(orb, table, cp, tp, rp, x0, t_k, tau_prev_ns, 0, tol_ns, chief, chief_t0, -1)
    return tau, calls + 1


@nb.njit(cache=True, error_model="numpy")
def initial_search_kernel(orb: NDArray, table: NDArray, cp: NDArray, tp: NDArray, rp: NDArray, x0: NDArray,
                          t0: float, window_ns: int, grid_ns: int, tol_ns: int, chief: NDArray,
                          chief_t0: float, side: int) -> tuple[int, int, bool]:
    """First-instant search (SPEC §5), times in integer ns. Returns (tau_ns, Verify calls, found).

    The grid is tau = side * m * grid, m = 0 .. window / grid (side -1: [-window, 0], behind the
    chief; +1: [0, window], ahead of it). tau_near = the grid point nearest to the deputy's
    position; walk the grid from
    it toward 0 while feasible (or away from 0 until feasible; if none is, from tau_near toward 0
    until feasible and on while feasible), then bisect between the two adjacent grid points, the
    feasible one being the verified lower end.
    """
    n_grid = window_ns // grid_ns
    xc = np.empty(6)
    best = 0
    best_d2 = math.inf
    for m in range(n_grid + 1):  # tau = side * m * grid, m = 0 .. n_grid
        state_kernel(orb, t0 + side * m * grid_ns / 1e9, xc)
        d2 = (xc[0] - x0[0]) ** 2 + (xc[1] - x0[1]) ** 2 + (xc[2] - x0[2]) ** 2
        if d2 < best_d2:
            best_d2 = d2
            best = m
    calls = 1
    m = best
    if verify_kernel(orb, table, cp, tp, rp, x0, t0, side * m * grid_ns / 1e9, chief, chief_t0):
        while m > 0:  # walk toward 0 while feasible
            calls += 1
            if not verify_kernel(orb, table, cp, tp, rp, x0, t0, side * (m - 1) * grid_ns / 1e9, chief, chief_t0):
                break
            m -= 1
        if m == 0:
            return 0, calls, True
    else:
        found = False
        while m < n_grid:  # walk away from 0 until feasible
            m += 1
            calls += 1
            if verify_kernel(orb, table, cp, tp, rp, x0, t0, side * m * grid_ns / 1e9, chief, chief_t0):
                found = True
                break
        if not found:
            # Then toward 0 from tau_near (SPEC §5 stops above; robust Verify's feasible shifts
            # may lie only there): the first feasible point, then on toward 0 while feasible.
            m = best
            while m > 0:
                m -= 1
                calls += 1
                if verify_kernel(orb, table, cp, tp, rp, x0, t0, side * m * grid_ns / 1e9, chief, chief_t0):
                    found = True
                    break
            if not found:
                return 0, calls, False
            while m > 0:
                calls += 1
                if not verify_kernel(orb, table, cp, tp, rp, x0, t0, side * (m - 1) * grid_ns / 1e9,
                                     chief, chief_t0):
                    break
                m -= 1
            if m == 0:
                return 0, calls, True
    tau, _, c = bisect_kernel(orb, table, cp, tp, rp, x0, t0, side * m * grid_ns, side * (m - 1) * grid_ns, tol_ns,
                             chief, chief_t0, -1)
    return tau, calls + c, True


@dataclass(frozen=True)
class Predictor:
    """The packed model of one configuration: chief orbit, gain table, constraints, prediction.

    Shared by the governors, the offline mission and the data generator (one Verify for all).
    """

    config: Config
    orbit: KeplerOrbit
    gains: NDArray      # (J+1, 3, 6) gain table
    cparams: NDArray    # packed constraint parameters
    tparams: NDArray    # packed prediction parameters
    rparams: NDArray    # packed robustness parameters (cikan_ros.robust)
    #: The ancillary tube's gain bands (``tsg.ancillary_bands_km``): (least measured range, km;
    #: packed robustness parameters of that band's tracking gain), ascending from (0, rparams).
    #: Empty: one gain. A rollout takes the band of its measured range at sample 0 (:meth:`band`).
    rbands: tuple[tuple[float, NDArray], ...] = ()

    @classmethod
    def from_config(cls, cfg: Config) -> "Predictor":
        orbit = KeplerOrbit.from_config(cfg.orbit)
        horizon = cfg.tsg.horizon_s if cfg.tsg.horizon_s > 0 else orbit.period
        n_samples = math.ceil(horizon / cfg.tsg.sample_period_s - 1e-9)
        tp = np.array([cfg.tsg.sample_period_s, n_samples, cfg.tsg.rk4_substeps,
                       cfg.tsg.terminal_pos_km, cfg.tsg.terminal_vel_kmps,
                       j2_coefficient(prediction_gravity(cfg))], dtype=float)
        rp = robust_params(cfg, orbit)
        bands: tuple[tuple[float, NDArray], ...] = ()
        if cfg.tsg.robust and cfg.tsg.tube == "ancillary" and cfg.tsg.ancillary_bands_km:
            bands = tuple((km, rp if km == 0.0 else robust_params(band, orbit))
                          for km, band in ancillary_band_configs(cfg))
        return cls(cfg, orbit, gain_table(orbit, control_config(cfg)),
                   constraint_params(cfg.constraints, cfg.control.u_max_kmps2, cfg.side), tp, rp, bands)

    def nominal(self) -> "Predictor":
        """This model with nominal Verify (robustness off, and so the nominal controller and
        prediction model), for the same chief orbit: what decides which starts a campaign
        flies, so nominal and robust Verify fly the same starts."""
        if not self.robust:
            return self
        return Predictor.from_config(self.config.replace(**{"tsg.robust": False})).with_orbit(self.orbit)

    def with_orbit(self, orbit: KeplerOrbit) -> "Predictor":
        """This model with another chief orbit (a re-anchored chief): same gains, constraints,
        prediction and robustness parameters, a chief table of its own."""
        new = object.__new__(Predictor)  # dataclasses.replace, without its per-call overhead
        new.__dict__.update(self.__dict__)
        object.__setattr__(new, "orbit", orbit)
        new.__post_init__()
        return new

    @property
    def side(self) -> Side:
        """The approach side, the sign of the shifts: BEHIND (-1, tau <= 0) or AHEAD (+1,
        tau >= 0); the configuration's (the port in ``cparams`` was packed from it)."""
        return self.config.side

    @property
    def robust(self) -> bool:
        """Is Verify robust (``tsg.robust``; the kernels read the flag ``R_ON`` that
        :func:`~cikan_ros.robust.robust_params` packed from it)? Every Python-side question
        about robustness asks this."""
        return self.config.tsg.robust

    @property
    def ancillary(self) -> bool:
        """Does the truth track Verify's accepted prediction (``tsg.tube`` ancillary under robust
        Verify; :mod:`cikan_ros.ancillary`)?"""
        return self.robust and self.config.tsg.tube == "ancillary"

    @property
    def tol_ns(self) -> int:
        """Bisection tolerance in integer nanoseconds."""
        return to_ns(self.config.tsg.tolerance_s)

    @property
    def n_samples(self) -> int:
        """N_p, the number of prediction samples in the horizon."""
        return int(self.tparams[T_NSAMPLES])

    def _state(self, x_d: ArrayLike, t: float) -> tuple[NDArray, float]:
        x = np.ascontiguousarray(x_d, dtype=float)
        # Fast path (a verify call is ~10 us of kernel when it fails early): one dot product says
        # the state is finite and away from the origin; anything else gets the detailed check.
        ok = x.shape == (6,)
        if ok:
            a, b, c, d, e, f = x.tolist()  # Python floats: no overflow warnings
            r2 = a * a + b * b + c * c
            ok = math.isfinite(r2 + d * d + e * e + f * f) and r2 >= 1.0
        if not ok:
            check_states(x, "deputy state x_d")
            if x.shape != (6,):
                raise StateError(f"deputy state x_d must have shape (6,), got {x.shape}")
        if not math.isfinite(t):
            raise StateError(f"time t must be finite, got {t!r}")
        return x, float(t)

    def _shift(self, tau: float, name: str) -> float:
        if not (math.isfinite(tau) and self.side * tau >= 0.0):
            bound = "<= 0 s (the deputy approaches from behind)" if self.side < 0 else \
                ">= 0 s (the deputy approaches from ahead)"
            raise StateError(f"time shift {name} must be finite and {bound}, got {tau!r}")
        return float(tau)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_table", ChiefTable(float(self.tparams[T_SAMPLE]), self.n_samples))
        if "_j2_rows" not in self.__dict__:  # re-anchored copies (:meth:`with_orbit`) share it
            object.__setattr__(self, "_j2_rows", J2RowBuffer(self.n_samples))

    def band(self, x_d: ArrayLike, t: float) -> int:
        """The ancillary tube's gain band (index into :attr:`rbands`, 0 without bands) of a
        rollout from the measured deputy x_d (km, km/s, ECI) at t (s): the last whose least range
        the measured range to the predicted chief at t reaches."""
        if not self.rbands:
            return 0
        x = np.asarray(x_d, dtype=float)
        rng = float(np.linalg.norm(x[:3] - self.orbit.state(t)[:3]))
        return max(i for i, (km, _) in enumerate(self.rbands) if rng >= km)

    def band_params(self, band: int) -> NDArray:
        """The packed robustness parameters of gain band ``band`` (:meth:`band`)."""
        return self.rbands[band][1] if self.rbands else self.rparams

    def _rp(self, x: NDArray, t: float) -> NDArray:
        return self.band_params(self.band(x, t))

    def cache(self, t: float) -> ChiefCache:
        """Chief states for the Verify/bisect calls at update time t: a view into the process's
        :class:`ChiefTable` when t lies on the sample grid, else a private array."""
        t = float(t)
        if self.tparams[T_J2R2] != 0.0:  # rows integrated from the anchored chief at t
            buf: J2RowBuffer = self._j2_rows  # type: ignore[attr-defined]
            rows = buf.take()
            j2_rows_start_kernel(self.orbit.params, t, self.orbit.mu, rows)
            cache = ChiefCache(t, rows, t)
            buf.hold(cache)
            return cache
        table: ChiefTable = self._table  # type: ignore[attr-defined]
        i = table.index(t)
        if i is None:
            return ChiefCache(t, np.full((self.n_samples, 7), math.nan), t)
        return ChiefCache(t, table.view(i), i * table.ts)

    def _cache(self, t: float, cache: ChiefCache | None) -> ChiefCache:
        if cache is None:
            return self.cache(t)
        if cache.t != t:
            raise ValueError(f"chief cache was made for t = {cache.t}, used at t = {t}")
        return cache

    def verify(self, x_d: ArrayLike, t: float, tau: float, cache: ChiefCache | None = None) -> bool:
        """Verify(x_d, t, tau): does tracking x_c(. + tau) from x_d at t stay feasible to the terminal set?

        Pass the same ``cache`` (from :meth:`cache`) to several calls at one t to reuse chief states.
        """
        x, t = self._state(x_d, t)
        c = self._cache(t, cache)
        return bool(verify_kernel(self.orbit.params, self.gains, self.cparams, self.tparams, self._rp(x, t), x, t,
                                  self._shift(tau, "tau"), c.rows, c.t0))

    def rollout_trace(self, x_d: ArrayLike, t: float, tau: float) -> tuple[bool, NDArray]:
        """One rollout of Verify(x_d, t, tau) (without the zeta interval) and its trace (N_p, 29)
        under robust Verify: per checked sample the predicted deputy (km, km/s, ECI), rho (km),
        sigma (km/s), 0, the command (km/s^2) and the predicted chief; at the accepting sample the
        virtual target, the terminal ball's radii, the handoff and the terminal test's inputs;
        rows not reached stay NaN (:func:`rollout_kernel`)."""
        x, t = self._state(x_d, t)
        c = self.cache(t)
        trace = np.full((self.n_samples, TRACE_WIDTH), math.nan)
        ok = rollout_kernel(self.orbit.params, self.gains, self.cparams, self.tparams, self._rp(x, t), x, t,
                            self._shift(tau, "tau"), c.rows, c.t0, trace)
        return bool(ok), trace

    def bisect(self, x_d: ArrayLike, t: float, lo: float, hi: float,
               cache: ChiefCache | None = None, budget: int | None = None) -> tuple[float, int]:
        """Bisection between a feasible ``lo`` (not re-verified) and an infeasible ``hi`` (s),
        ``hi`` between ``lo`` and 0 (either side of the chief).

        Returns (tau, Verify calls): tau is feasible and within the tolerance of an infeasible shift,
        or with a ``budget`` of Verify calls that ran out, the verified end reached (between lo and hi).
        """
        lo_s, _, calls = self.bisect_bracket(x_d, t, lo, hi, cache, budget)
        return lo_s, calls

    def first_feasible(self, x_d: ArrayLike, t: float, candidates: Sequence[float], lo: float,
                       budget: int, cache: ChiefCache | None = None) -> tuple[float, int, int]:
        """The first of ``candidates`` (s, each between lo and 0, on the nanosecond grid) that
        passes Verify, else the verified end of a bisection between lo and the last candidate
        with at most ``budget`` calls (lo itself with 0): (tau, index of the candidate or -1,
        Verify calls)."""
        lo = self._shift(lo, "lo")
        ns = [to_ns(self._shift(c, "candidate")) for c in candidates]
        lo_ns = to_ns(lo)
        if ns and max(self.side * n for n in ns) > self.side * lo_ns:
            raise StateError(f"candidates must lie between lo = {lo} s and 0")
        return self.first_feasible_ns(x_d, t, np.array(ns, dtype=np.int64), lo_ns, budget, cache)

    def first_feasible_ns(self, x_d: ArrayLike, t: float, cands_ns: NDArray, lo_ns: int, budget: int,
                          cache: ChiefCache | None = None) -> tuple[float, int, int]:
        """:meth:`first_feasible` for candidates already in integer ns (int64 array), each between
        lo and 0: not checked again (the keep rule builds them so, ``ladder_kernel``); an update
        saves the ~15 us the checks cost in Python."""
        x, t = self._state(x_d, t)
        c = self._cache(t, cache)
        tau_ns, index, calls = first_feasible_kernel(
            self.orbit.params, self.gains, self.cparams, self.tparams, self._rp(x, t), x, t, cands_ns,
            int(lo_ns), int(budget), self.tol_ns, c.rows, c.t0)
        return ns_to_seconds(tau_ns), int(index), int(calls)

    def bisect_bracket(self, x_d: ArrayLike, t: float, lo: float, hi: float,
                       cache: ChiefCache | None = None, budget: int | None = None
                       ) -> tuple[float, float, int]:
        """Like :meth:`bisect`, returning the final bracket (feasible lo, infeasible hi, calls)."""
        x, t = self._state(x_d, t)
        lo, hi = self._shift(lo, "lo"), self._shift(hi, "hi")
        if self.side * lo < self.side * hi:
            raise StateError(f"bisection bracket is empty: hi = {hi} is farther from 0 than lo = {lo}")
        c = self._cache(t, cache)
        lo_ns, hi_ns, calls = bisect_kernel(self.orbit.params, self.gains, self.cparams, self.tparams,
                                            self._rp(x, t), x, t, to_ns(lo), to_ns(hi), self.tol_ns, c.rows, c.t0,
                                            -1 if budget is None else int(budget))
        return ns_to_seconds(lo_ns), ns_to_seconds(hi_ns), int(calls)

    def gallop(self, x_d: ArrayLike, t: float, tau_prev: float, q0: float, growth: float, budget: int,
               cache: ChiefCache | None = None) -> tuple[float, float, float, int]:
        """Progress of about ``q0`` of |tau_prev| toward 0, searched with at most ``budget`` Verify
        calls (:func:`gallop_kernel`): (tau, q of the answer (0: tau_prev held), smallest q that
        failed (inf: none), calls)."""
        x, t = self._state(x_d, t)
        tau_prev = self._shift(tau_prev, "tau_prev")
        if not (0.0 < q0 and growth > 1.0 and budget >= 0):
            raise ValueError(f"gallop needs q0 > 0, growth > 1 and budget >= 0, got {q0}, {growth}, {budget}")
        if tau_prev == 0.0:
            return 0.0, 0.0, math.inf, 0
        c = self._cache(t, cache)
        tau, q, q_fail, calls = gallop_kernel(self.orbit.params, self.gains, self.cparams, self.tparams,
                                              self._rp(x, t), x, t, to_ns(tau_prev), float(q0), float(growth),
                                              int(budget), self.tol_ns, c.rows, c.t0)
        return ns_to_seconds(tau), float(q), float(q_fail), int(calls)

    def optimal_shift(self, x_d: ArrayLike, t: float, tau_prev: float) -> tuple[float, int]:
        """pi*(x_d, t) between tau_prev and 0: (tau, Verify calls). tau_prev = 0 gives 0 with no prediction."""
        x, t = self._state(x_d, t)
        tau_prev = self._shift(tau_prev, "tau_prev")
        if tau_prev == 0.0:
            return 0.0, 0
        c = self.cache(t)
        tau, calls = conventional_update_kernel(self.orbit.params, self.gains, self.cparams,
                                                self.tparams, self._rp(x, t), x, t, to_ns(tau_prev), self.tol_ns,
                                                c.rows, c.t0)
        return ns_to_seconds(tau), int(calls)

    def initial_shift(self, x_d: ArrayLike, t: float) -> tuple[float, int]:
        """First-instant search over [-window, 0] (behind) or [0, window] (ahead); raises
        NoFeasibleShiftError if none is feasible."""
        x, t = self._state(x_d, t)
        cfg = self.config.tsg
        c = self.cache(t)
        tau, calls, found = initial_search_kernel(self.orbit.params, self.gains, self.cparams,
                                                  self.tparams, self._rp(x, t), x, t, to_ns(cfg.initial_window_s),
                                                  to_ns(cfg.initial_grid_s), self.tol_ns, c.rows, c.t0,
                                                  int(self.side))
        if not found:
            truth = self.config.truth
            under = (f" under robust Verify with the bounds of truth {truth.name!r} x {truth.scale:g}"
                     if self.robust else "")
            window = f"[-{cfg.initial_window_s:g}, 0]" if self.side < 0 else f"[0, {cfg.initial_window_s:g}]"
            raise NoFeasibleShiftError(
                f"no feasible time shift in {window} s for this initial "
                f"condition (deputy at {np.array2string(x[:3], precision=3)} km, t = {t:g} s)"
                f"{under}: the start is rejected")
        return ns_to_seconds(tau), int(calls)


@nb.njit(cache=True, error_model="numpy")
def anchor_offset_kernel(orb: NDArray, t: float, x_c: NDArray, model: NDArray) -> tuple[float, float]:
    """Largest position (km) and velocity (km/s) component of x_c - x_model(t), the model chief
    of ``orb`` at t written into ``model`` (6,); NaN when x_c is not finite. One compiled call:
    every update anchors, and the numpy version of these lines cost ~15 us a call."""
    state_kernel(orb, t, model)
    dp = 0.0
    dv = 0.0
    for i in range(3):
        a = abs(x_c[i] - model[i])
        b = abs(x_c[3 + i] - model[3 + i])
        if a != a or b != b:
            return math.nan, math.nan
        dp = max(dp, a)
        dv = max(dv, b)
    return dp, dv


class ChiefAnchor:
    """The chief of the prediction model, anchored on the chief state a governor or controller
    receives (SPEC §2 takes it from the configured elements; a real chief drifts from them).

    ``anchor(x_c, t)`` returns the :class:`Predictor` whose chief passes through the measured
    x_c at t: the current one while the measurement stays within ``tsg.chief_anchor_tolerance_km``
    of its chief (velocity: that tolerance per sample period), else a new one whose Kepler orbit
    is the osculating orbit of x_c at t. Under the nominal truth the measured chief is the
    configured one to rounding, so no update pays for a new chief table; each user (governor,
    controller) holds its own anchor, so the offline loop and the ROS nodes anchor alike.
    """

    def __init__(self, predictor: Predictor) -> None:
        self.base = predictor
        self.current = predictor
        self.re_anchors = 0
        tol = predictor.config.tsg.chief_anchor_tolerance_km
        self._tol = (tol, tol / predictor.config.tsg.sample_period_s)
        self._model = np.empty(6)

    def reset(self) -> None:
        """Back to the configured chief (a mission's start: runs do not depend on earlier ones)."""
        self.current = self.base
        self.re_anchors = 0

    def __call__(self, x_c: ArrayLike, t: float) -> Predictor:
        x = np.asarray(x_c, dtype=float)
        if x.shape != (6,):
            check_states(x, "chief state x_c")
            raise StateError(f"chief state x_c must have shape (6,), got {x.shape}")
        dp, dv = anchor_offset_kernel(self.current.orbit.params, float(t), x, self._model)
        if dp <= self._tol[0] and dv <= self._tol[1]:
            return self.current
        if not math.isfinite(dp + dv):
            check_states(x, "chief state x_c")
        self.current = self.base.with_orbit(KeplerOrbit.from_state(x, float(t), self.base.orbit.mu))
        self.re_anchors += 1
        return self.current
