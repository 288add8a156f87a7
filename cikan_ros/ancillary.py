"""The ancillary tube's controller (``tsg.tube`` ancillary; docs/robustness.md, "The ancillary
tube"): the truth tracks the prediction robust Verify accepted instead of flying its own
saturated FTRE loop.

When a shift takes effect, the accepted rollout (:meth:`Predictor.rollout_trace`, from the
measured state at that update) becomes the :class:`Plan`: the predicted deputy x_p,j and its
command u_p,j (flown at gamma u_max) at the samples j before the terminal sample. At control step
k the command is u_p,j - K_a(nu_v) (x_hat - x_p,j), j = k - k_0, with K_a the FTRE gain of the
LQ weight ``tsg.ancillary_r_diag`` (saturated at u_max only as a last guard: robust Verify
refused every shift whose tube could make it saturate). From the terminal sample on the plan
is done and the loop robust Verify's terminal test handed the truth to flies: the FTRE law
toward the virtual target, or, where that loop would saturate on the terminal ball, the tracking
law holding it, -K_a(nu_v) (x_hat - x_v) (:func:`cikan_ros.robust.ancillary_terminal_ok`). A
held shift keeps its plan: no re-verification.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .config import ancillary_band_configs, ancillary_control_config, handoff_control_config
from .control import gain_table, interpolate_gain, saturate
from .errors import StateError
from .robust import HANDOFF_FTRE, HANDOFF_TRACK, terminal_ball_after
from .tsg import Predictor


@dataclass(frozen=True)
class Plan:
    """An accepted prediction to track: from control step ``k0`` on, x_p (J, 6) km, km/s (ECI)
    and u_p (J, 3) km/s^2 for the samples before the terminal one (J of them), the shift
    ``tau`` (s) it was verified for."""

    k0: int
    tau: float
    x_p: NDArray
    u_p: NDArray
    #: After the terminal sample the truth holds x_v with the tracking law (robust Verify's
    #: handoff, :data:`~cikan_ros.robust.HANDOFF_TRACK`), else the FTRE law flies.
    holds_target: bool = False
    #: The rollout's terminal row (:data:`~cikan_ros.tsg.TRACE_WIDTH`,): x_v, the ball, the
    #: handoff, the predicted chief and the terminal test's inputs (None: not recorded).
    terminal: NDArray | None = None
    #: The gain band robust Verify verified the plan with (:meth:`Predictor.band`): the tracking
    #: gain K_a the plan is flown with.
    band: int = 0

    @classmethod
    def accepted(cls, predictor: Predictor, k: int, t: float, tau: float, x_d: NDArray) -> "Plan":
        """The plan of shift tau accepted at step k (time t, s) from the measured deputy x_d:
        robust Verify's rollout, which must pass (StateError otherwise)."""
        ok, trace = predictor.rollout_trace(x_d, t, tau)
        if not ok:
            raise StateError(f"the shift {tau} s taking effect at t = {t} s does not pass robust Verify: no plan")
        term = int(np.flatnonzero(trace[:, 8] >= HANDOFF_FTRE)[0])
        return cls(k, float(tau), trace[:term, :6].copy(), trace[:term, 9:12].copy(),
                   bool(trace[term, 8] == HANDOFF_TRACK), trace[term].copy(), predictor.band(x_d, t))

    def certified_ball(self, predictor: Predictor, k: int) -> tuple[float, float] | None:
        """The ball (km, km/s) about x_v that robust Verify's terminal test certifies for the
        truth at control step k (:func:`~cikan_ros.robust.terminal_ball_after`), or None before
        the terminal sample or without a recorded terminal row."""
        n = k - self.k0 - len(self.x_p)
        if self.terminal is None or n < 0:
            return None
        out = terminal_balls(predictor, self.terminal, n, self.band)
        return float(out[n, 0]), float(out[n, 1])

    def sample(self, k: int) -> int | None:
        """The plan's sample j at control step k, or None once the plan is done (terminal)."""
        j = k - self.k0
        return j if 0 <= j < len(self.x_p) else None


def terminal_balls(predictor: Predictor, row: NDArray, n: int, band: int = 0) -> NDArray:
    """(n + 1, 2): the ball (km, km/s) about x_v that robust Verify's terminal test certifies
    0 .. n samples after the terminal sample of a rollout verified in gain band ``band``
    (:meth:`Predictor.band`), from its terminal trace row (:data:`~cikan_ros.tsg.TRACE_WIDTH`,;
    :func:`~cikan_ros.robust.terminal_ball_after`)."""
    out = np.empty((n + 1, 2))
    terminal_ball_after(row[:6], row[12:18], predictor.band_params(band), row[18], row[19], row[20], row[21],
                        row[6], row[7], row[8], predictor.config.control.period_s, n, out,
                        row[22], row[23], row[24], row[25], int(row[26]), row[27], row[28])
    return out


class AncillaryLaw:
    """u = sat_{u_max}(u_p,j - K_a(nu_v) (x_hat - x_p,j)) along a :class:`Plan`."""

    def __init__(self, predictor: Predictor) -> None:
        cfg = predictor.config
        #: K_a of each gain band (:attr:`Predictor.rbands`; one without bands).
        self.band_gains = [gain_table(predictor.orbit, ancillary_control_config(band))
                           for _, band in ancillary_band_configs(cfg)]
        #: The FTRE law the truth is handed to at a plan's terminal sample (robust Verify's
        #: :data:`~cikan_ros.robust.HANDOFF_FTRE`).
        self.handoff_gains = gain_table(predictor.orbit, handoff_control_config(cfg))
        self.u_max = cfg.control.u_max_kmps2
        #: Commands the last guard saturated (robust Verify's headroom check says: none).
        self.guard_saturations = 0

    def command(self, plan: Plan, j: int, nu_v: float, x_d: NDArray) -> NDArray:
        """The tracking command (km/s^2, ECI) at the plan's sample j from the measured deputy."""
        return self.track(plan.u_p[j], plan.x_p[j], nu_v, x_d, plan.band)

    def hold(self, plan: Plan, nu_v: float, x_d: NDArray, x_v: NDArray) -> NDArray:
        """The tracking law holding the virtual target after the plan handed the truth to it:
        -K_a(nu_v) (x_hat - x_v) (km/s^2, ECI), K_a of the plan's gain band."""
        return self.track(np.zeros(3), np.asarray(x_v, dtype=float), nu_v, x_d, plan.band)

    def track(self, u_ff: NDArray, x_ref: NDArray, nu_v: float, x_d: NDArray, band: int = 0) -> NDArray:
        """u_ff - K_a(nu_v) (x_hat - x_ref), K_a of gain band ``band``, saturated at u_max only
        as a guard (counted)."""
        k_a = interpolate_gain(self.band_gains[band], nu_v)
        u = u_ff - k_a @ (np.asarray(x_d, dtype=float) - x_ref)
        self.guard_saturations += bool(math.sqrt(float(u @ u)) > self.u_max)
        return saturate(u, self.u_max)
