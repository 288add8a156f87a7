"""Robust Verify's error tube: what the declared error bounds can do to the closed loop.

The derivation is in docs/robustness.md; in short, with e_j = truth - prediction at sample j of a
Verify rollout, the FTRE closed loop (unsaturated, frozen at the virtual target's anomaly) gives

    e_{j+1} = Phi e_j - B_d K delta_j + B_d eta_j,     Phi = A_d - B_d K,   e_0 = -delta_0

with delta_j the navigation error of the state the controller sees (|delta_p| <= b_p(r),
|delta_v| <= b_v(r), r the range) and eta_j the unknown acceleration: thruster magnitude and
pointing errors (|eta_u| <= eps_u |u|), the process disturbance (<= d_max) and the unmodelled J2
difference between deputy and chief (<= k_g r). Every block X Phi^m Y of the transition matrix
decays like lam^m (lam = the largest closed-loop eigenvalue modulus over the gain table), so with
C_XY = max_m |X Phi^m Y|_2 / lam^m the position and velocity errors obey the scalar recursions

    rho_{j+1}   = lam rho_j   + C_pp b_p + C_pv b_v + C_pe eta_j
    sigma_{j+1} = lam sigma_j + C_vp b_p + C_vv b_v + C_ve eta_j

from rho_0 = C0_pp b_p + C0_pv b_v (sigma_0 likewise): the tube radii that robust Verify carries
along its rollout. Here "p" rows are the position block, "v" the velocity block; the forcing
columns are B_d K restricted to position or velocity errors (navigation) and B_d
(accelerations). E_XY = max_m |X Phi^m Y| (the nominal loop, M = I, not divided by lam^m) bounds
how far the prediction's own transient carries it from the virtual target after the terminal set
(robust Verify's terminal ball, docs/robustness.md).

This module computes the constants and packs them with the declared bounds
(:func:`robust_params`, layout ``R_*``), and holds the compiled kernels Verify's rollout
(:func:`cikan_ros.tsg.rollout_kernel`) calls when ``R_ON`` is set: the tube's start, its step
from one sample to the next, the tightened h1 and h3 checks on the ball around the prediction,
and the robust terminal test.
"""

from __future__ import annotations

import functools
import math

import numba as nb
import numpy as np
from numpy.typing import NDArray

from .config import (Config, ControlConfig, TruthConfig, ancillary_control_config, control_config,
                     handoff_control_config, prediction_gravity)
from .constraints import (C_APEX, C_COS_ALPHA, C_GAMMA1, C_GAMMA2, C_GAMMA3, C_PORT, C_UMAX, los_terms_kernel,
                          rel_norms_kernel)
from .control import B_INPUT, gain_table, zoh_discretise
from .dynamics import J2_EARTH, R_EARTH_KM, linearisation
from .errors import ConfigError
from .orbit import KeplerOrbit, elements_to_state

# Layout of the packed robustness parameters (``Predictor.rparams``).
(R_ON, R_LAM, R_C0PP, R_C0PV, R_C0VP, R_C0VV, R_DPP, R_DPV, R_CPE, R_DVP, R_DVV, R_CVE, R_KP, R_KV,
 R_NPF, R_NPG, R_NVF, R_NVG, R_EPSU, R_DMAX, R_KG, R_SINA, R_ZETA, R_GRAD, R_GPP, R_GPV, R_GVP,
 R_GVV, R_NRATE, R_HPP, R_HPV, R_HVP, R_HVV, R_EPP, R_EPV, R_EVP, R_EVV, R_NJUMP, R_CNPP, R_CNPV,
 R_CNVP, R_CNVV) = range(42)
# The ancillary tube (``tsg.tube`` ancillary, :func:`ancillary_step`): its flag, the prediction's
# thrust fraction gamma, and the constants of the tracking loop A_d - B_d M K_a (RA_ + the
# name of the constant in :func:`tube_constants`, in capitals).
R_TUBE, R_GAMMA = 42, 43
ANCILLARY_KEYS = ("lam", "kp", "kv", "cpe", "cve") + tuple(
    f"{c}{row}{col}" for c in ("c0", "d", "g", "h", "cn") for row in "pv" for col in "pv")
(RA_LAM, RA_KP, RA_KV, RA_CPE, RA_CVE, RA_C0PP, RA_C0PV, RA_C0VP, RA_C0VV, RA_DPP, RA_DPV, RA_DVP,
 RA_DVV, RA_GPP, RA_GPV, RA_GVP, RA_GVV, RA_HPP, RA_HPV, RA_HVP, RA_HVV, RA_CNPP, RA_CNPV, RA_CNVP,
 RA_CNVV) = range(44, 44 + len(ANCILLARY_KEYS))
#: The ancillary tube's check of the truth between samples (``tsg.ancillary_between``,
#: :func:`interval_ok`): on when 1.
R_BETWEEN = 44 + len(ANCILLARY_KEYS)
#: The l1 bounds of the ancillary tube (``tsg.ancillary_bound`` l1; docs/robustness.md, "The l1 bound"):
#: on when 1, then the l1 norms of the loops' impulse responses, L_XY = sum_m |X Phi^m Y|
#: (:func:`tube_constants`, keys "l" + the constant's name), of the FTRE handoff loop (RL_) and
#: of the tracking loop (RLA_).
R_L1 = R_BETWEEN + 1
L1_KEYS = tuple(f"l{c}{row}{col}" for c in ("d", "cn") for row in "pv" for col in "pv") + ("lcpe", "lcve")
(RL_DPP, RL_DPV, RL_DVP, RL_DVV, RL_CNPP, RL_CNPV, RL_CNVP, RL_CNVV, RL_CPE, RL_CVE) = range(
    R_L1 + 1, R_L1 + 1 + len(L1_KEYS))
(RLA_DPP, RLA_DPV, RLA_DVP, RLA_DVV, RLA_CNPP, RLA_CNPV, RLA_CNVP, RLA_CNVV, RLA_CPE, RLA_CVE) = range(
    RL_CVE + 1, RL_CVE + 1 + len(L1_KEYS))
#: The tracking loop's transient envelope under ``tsg.ancillary_bound`` l1: sup |X Phi^m Y| over
#: the orbit and the thruster maps for m = 0 .. N_ENV - 1 (blocks pp, pv, vp, vv, N_ENV each from
#: RA_ENV); beyond, C0 lam^m (:func:`transient_bound`).
N_ENV = 64
RA_ENV = RLA_CVE + 1
#: Under the l1 bound, the docking test (mission.dock_distance_km, mission.dock_speed_kmps) a
#: shift of 0 must be certified to reach (:func:`ancillary_docks`).
R_DOCK_P = RA_ENV + 4 * N_ENV
R_DOCK_V = R_DOCK_P + 1
N_RPARAMS = R_DOCK_V + 1

#: Powers of the closed-loop matrix scanned for the constants C: at least this many, and at least
#: POWER_SPAN / (1 - lam) (a slow loop's transient peaks later: lam = 0.993 near m = 145).
N_POWERS = 200
POWER_SPAN = 20.0
#: ... and at most this many (lam = 0.999: a tube 1000 times its forcing, of no use to Verify).
MAX_POWERS = 20000
#: True anomalies (deg) between which the closed loop is analysed for the constants that take
#: powers (lam, C0, D, C_n, E); the grid's step enters the bound (:func:`_with_grid_term`).
ANALYSIS_STEP_DEG = 7.5
#: The pointing-error axes of the extreme thruster maps: the coordinate axes for the constants
#: that take powers (over 15 axes they spread by less than 1e-4), and for the DC gains G and H,
#: which cost one solve per loop, the 13 directions of the cube's axes and diagonals on every
#: cell of the gain table.
POWER_AXES = ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
DC_AXES = POWER_AXES + tuple(np.array(a) / np.linalg.norm(a) for a in (
    (1, 1, 0), (1, -1, 0), (1, 0, 1), (1, 0, -1), (0, 1, 1), (0, 1, -1),
    (1, 1, 1), (1, 1, -1), (1, -1, 1), (-1, 1, 1)))


#: The relative margin on lam for the pointing axes between DC_AXES: over 200 random axes on
#: the gain table's grid the spectral radius exceeds the 13 axes' by at most 1.7e-5 (the paper's
#: robust controller; 5.8e-6 for its tracking loop), six times below it.
LAM_AXIS_MARGIN = 1e-4


def thrust_matrices(bias: float, pointing_rad: float, axes: tuple = POWER_AXES) -> list[NDArray]:
    """Extreme thruster maps M = (1 + b) R(theta) of the declared set |b| <= bias, theta <=
    pointing: b = -bias, 0, +bias times no rotation or a rotation by the full angle about each
    of ``axes`` (ECI unit vectors)."""
    from .truth import rotation

    rots = [np.eye(3)] + ([rotation(np.asarray(a, dtype=float), pointing_rad) for a in axes]
                          if pointing_rad > 0 else [])
    gains = sorted({1.0 - bias, 1.0, 1.0 + bias})
    return [g * r for g in gains for r in rots]


class UnstableLoopError(ConfigError):
    """The declared thruster errors destabilise the FTRE loop: no error tube exists."""


def _with_grid_term(values: NDArray) -> float:
    """The sup over the orbit of a quantity sampled at anomalies evenly spaced around it
    (``values``, (n,), each the worst over the thruster maps there): the largest sample plus the
    grid's step times the steepest change between neighbouring samples, a Lipschitz term for
    the anomalies between them (over an interval of step s, a function with slope <= L exceeds
    its larger end by at most L s / 2; L is taken as twice the steepest neighbouring slope)."""
    slopes = np.abs(np.diff(np.append(values, values[0])))  # per step, around the orbit
    steep = np.maximum(slopes, np.maximum(np.roll(slopes, 1), np.roll(slopes, -1)))
    return float(np.max(np.maximum(values, np.roll(values, -1)) + steep))


@functools.lru_cache(maxsize=16)
def frozen_loops(orbit: KeplerOrbit, cfg: ControlConfig) -> tuple[NDArray, NDArray, NDArray]:
    """The frozen-time loop at every cell of the gain table: (A_d (n, 6, 6), B_d (n, 6, 3) of the
    dynamics linearised about the chief at the cell's true anomaly, the gains K (n, 3, 6))."""
    table = gain_table(orbit, cfg)
    n_cells = table.shape[0] - 1
    a_ds, b_ds = zip(*(zoh_discretise(linearisation(elements_to_state(
        orbit.a, orbit.e, orbit.i, orbit.raan, orbit.argp, 2.0 * math.pi * j / n_cells, orbit.mu)[:3],
        orbit.mu), B_INPUT, cfg.period_s) for j in range(n_cells)))
    return np.asarray(a_ds), np.asarray(b_ds), table[:n_cells]


def closed_loops(orbit: KeplerOrbit, cfg: ControlConfig, maps: list[NDArray],
                 cells: slice = slice(None)) -> tuple[NDArray, NDArray]:
    """Phi_M = A_d - B_d M K and B_d M K (cells, maps, 6, 6) at the gain table's ``cells``
    (:func:`frozen_loops`) for each thruster map M of ``maps``."""
    a_all, b_all, k_all = frozen_loops(orbit, cfg)
    bmk = np.einsum("cij,mjk,ckl->cmil", b_all[cells], np.asarray(maps), k_all[cells])
    return a_all[cells, None] - bmk, bmk


def loop_radius(orbit: KeplerOrbit, cfg: ControlConfig, bias: float = 0.0,
                pointing_rad: float = 0.0) -> tuple[float, NDArray, NDArray]:
    """lam before the check: the spectral radius of Phi_M = A_d - B_d M K over every cell of the
    gain table and the extreme maps about DC_AXES, with the grid's term and LAM_AXIS_MARGIN (the
    axes between DC_AXES: over 200 random axes the radius exceeds theirs by at most 1.7e-5);
    also Phi_M and B_d M K (cells, maps, 6, 6) for the DC gains."""
    phi_all, bmk_all = closed_loops(orbit, cfg, thrust_matrices(bias, pointing_rad, DC_AXES))
    radius = np.max(np.abs(np.linalg.eigvals(phi_all)), axis=(1, 2))
    return _with_grid_term(radius) * (1.0 + LAM_AXIS_MARGIN), phi_all, bmk_all


@functools.lru_cache(maxsize=16)
def tube_constants(orbit: KeplerOrbit, cfg: ControlConfig, bias: float = 0.0,
                   pointing_rad: float = 0.0) -> dict[str, float]:
    """lam, the C, G, D, H and E constants and the gain norms |K_p|, |K_v| of the FTRE closed loop
    Phi_M = A_d - B_d M K flown with the thruster map M (:func:`thrust_matrices`), each the worst
    over M (E: over the nominal M = I only, the prediction's loop) and over the chief orbit's true
    anomaly (frozen-time analysis every ANALYSIS_STEP_DEG with the grid's Lipschitz term,
    :func:`_with_grid_term`; lam, G and H on the gain table's grid and DC_AXES: :func:`loop_radius`).
    Raises UnstableLoopError when some M makes the loop unstable."""
    _, b_all, k_all = frozen_loops(orbit, cfg)
    stride = max(1, round(ANALYSIS_STEP_DEG / cfg.grid_deg))
    keys = ("lam", "kp", "kv") + tuple(f"{c}{row}{col}" for c in ("c0", "g", "d", "h", "e", "cn")
                                        for row in "pv" for col in "pv") + ("cpe", "cve") + L1_KEYS
    out = {k: 0.0 for k in keys}
    blocks = (("p", slice(0, 3)), ("v", slice(3, 6)))
    lam, phi_all, bmk_all = loop_radius(orbit, cfg, bias, pointing_rad)
    if not lam < 1.0 - 1e-6:
        raise UnstableLoopError(
            f"thruster errors of {bias:.1%} in magnitude and {math.degrees(pointing_rad):.2f} deg in "
            f"pointing destabilise the FTRE loop with control weight R = {cfg.r_diag[0]:g} I (spectral "
            f"radius {lam:.4f} >= 1 over the orbit): no error tube exists; a larger "
            "control.robust_r_diag widens the loop's gain margin (cikan tube prints it)")
    out["lam"] = lam
    out["kp"] = float(np.max(norms(k_all[:, :, :3])))
    out["kv"] = float(np.max(norms(k_all[:, :, 3:])))

    # The DC gains G = (I - Phi)^-1 B M K and H (blocks of I - G): no powers, so on every cell of
    # the gain table and every axis of DC_AXES, no grid term needed.
    dc_all = np.linalg.solve(np.eye(6) - phi_all, bmk_all)
    seen_all = np.eye(6) - dc_all
    for row, rs in blocks:
        for col, cs in blocks:
            out[f"g{row}{col}"] = float(np.max(norms(dc_all[..., rs, cs])))
            out[f"h{row}{col}"] = float(np.max(norms(seen_all[..., rs, cs])))

    # The constants that take powers, per analysed anomaly (worst over the maps there), then the
    # sup over the orbit with the grid's term: every analysed loop at once, (S, 6, 6) with
    # S = anomalies x maps, powered in step.
    maps = thrust_matrices(bias, pointing_rad)
    cells = slice(0, len(b_all), stride)
    phi, bmk = (m.reshape(-1, 6, 6) for m in closed_loops(orbit, cfg, maps, cells))
    n_anomalies = len(phi) // len(maps)
    b_d = np.repeat(b_all[cells], len(maps), axis=0)
    nominal = np.tile([bool(np.array_equal(m, np.eye(3))) for m in maps], n_anomalies)
    n_powers = min(MAX_POWERS, max(N_POWERS, math.ceil(POWER_SPAN / (1.0 - lam))))
    # DC response to a constant navigation error: sum_l Phi^l B M K = (I - Phi)^-1 B M K, and
    # what is left of it after m steps: D_m = sum_{l > m} Phi^l B M K = Phi^(m+1) (DC).
    dc = np.linalg.solve(np.eye(6) - phi, bmk)
    best = {k: np.zeros(len(phi)) for k in keys if k[0] in "cde" or k in L1_KEYS}
    power = np.broadcast_to(np.eye(6), phi.shape).copy()
    env = {f"{row}{col}": np.zeros((N_ENV, len(phi))) for row in "pv" for col in "pv"}
    for m in range(n_powers + 1):
        s = lam ** -m
        nxt = phi @ power
        pb, pn, pd = power @ b_d, power @ bmk, nxt @ dc
        for row, rs in blocks:
            for col, cs in blocks:
                c0 = norms(power[:, rs, cs])
                if m < N_ENV:
                    env[f"{row}{col}"][m] = c0
                np.maximum(best[f"c0{row}{col}"], c0 * s, out=best[f"c0{row}{col}"])
                # the prediction's own loop (M = I): how far its transient can carry it
                np.maximum(best[f"e{row}{col}"], np.where(nominal, c0, 0.0), out=best[f"e{row}{col}"])
                nd, nn = norms(pd[:, rs, cs]), norms(pn[:, rs, cs])
                np.maximum(best[f"d{row}{col}"], nd * s, out=best[f"d{row}{col}"])
                # the loop's response to the navigation error itself (not its changes), for an
                # error that may jump anywhere in its bound at every sample (truth.nav_model filter)
                np.maximum(best[f"cn{row}{col}"], nn * s, out=best[f"cn{row}{col}"])
                best[f"ld{row}{col}"] += nd  # the l1 norms of the impulse responses
                best[f"lcn{row}{col}"] += nn
            ne = norms(pb[:, rs])
            np.maximum(best[f"c{row}e"], ne * s, out=best[f"c{row}e"])
            best[f"lc{row}e"] += ne
        power = nxt
    # The l1 sums' tail beyond the last power: |X Phi^m Y| <= C lam^m, summed over m > n_powers.
    tail = lam ** (n_powers + 1) / (1.0 - lam)
    for k in L1_KEYS:
        best[k] += best[k[1:]] * tail
    # per analysed anomaly, the worst over its maps
    per_anomaly = {k: v.reshape(n_anomalies, len(maps)).max(axis=1) for k, v in best.items()}
    for k, values in per_anomaly.items():
        out[k] = _with_grid_term(values)
    # the transient envelope sup |X Phi^m Y| per power m (rows of "env" + block: tuples of N_ENV)
    for k, per_m in env.items():
        worst = per_m.reshape(N_ENV, n_anomalies, len(maps)).max(axis=2)
        out[f"env{k}"] = tuple(min(_with_grid_term(v), out[f"c0{k}"] * lam ** m) for m, v in enumerate(worst))
    return out


def norms(mats: NDArray) -> NDArray:
    """Spectral norms of a stack of matrices (..., r, c). For 3 x 3 blocks (every block of the
    tube constants) in closed form, without a LAPACK call per matrix: the largest eigenvalue of
    the Gram matrix X^T X by the trigonometric solution of its characteristic cubic (O. K.
    Smith, "Eigenvalues of a symmetric 3 x 3 matrix", Comm. ACM 4, 1961), raised by 1e-9 of the
    Gram's trace to cover its rounding (an upper bound; tested against numpy's SVD)."""
    mats = np.asarray(mats, dtype=float)
    if mats.shape[-2:] != (3, 3):
        return np.linalg.norm(mats, 2, axis=(-2, -1))
    g = np.swapaxes(mats, -1, -2) @ mats
    tr = g[..., 0, 0] + g[..., 1, 1] + g[..., 2, 2]
    q = tr / 3.0
    p1 = g[..., 0, 1] ** 2 + g[..., 0, 2] ** 2 + g[..., 1, 2] ** 2
    p2 = (g[..., 0, 0] - q) ** 2 + (g[..., 1, 1] - q) ** 2 + (g[..., 2, 2] - q) ** 2 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    safe = np.where(p > 0.0, p, 1.0)
    b = (g - q[..., None, None] * np.eye(3)) / safe[..., None, None]
    det = (b[..., 0, 0] * (b[..., 1, 1] * b[..., 2, 2] - b[..., 1, 2] * b[..., 2, 1])
           - b[..., 0, 1] * (b[..., 1, 0] * b[..., 2, 2] - b[..., 1, 2] * b[..., 2, 0])
           + b[..., 0, 2] * (b[..., 1, 0] * b[..., 2, 1] - b[..., 1, 1] * b[..., 2, 0]))
    r = np.clip(det / 2.0, -1.0, 1.0)
    top = np.where(p > 0.0, q + 2.0 * p * np.cos(np.arccos(r) / 3.0), q)
    return np.sqrt(np.maximum(top, 0.0) + 1e-9 * tr)


def j2_gradient_bound(r_min_km: float, mu: float) -> float:
    """An upper bound (1/s^2) of |d a_J2 / d r|_2 for |r| >= r_min: the J2 part of the gravity
    gradient has its largest norm, 12 J2 mu R^2 / r^5, over the poles (tested in test_robust);
    the bound takes 15 for margin."""
    return 15.0 * J2_EARTH * mu * R_EARTH_KM ** 2 / r_min_km ** 5


def robust_params(cfg: Config, orbit: KeplerOrbit) -> NDArray:
    """The packed robustness parameters (layout ``R_*``): zeros (with the cone's sin alpha and
    zeta) when ``tsg.robust`` is off, else the tube constants and the declared bounds."""
    rp = np.zeros(N_RPARAMS)
    rp[R_SINA] = math.sin(math.radians(cfg.constraints.los_half_angle_deg))
    rp[R_ZETA] = cfg.tsg.robust_zeta_s
    if not cfg.tsg.robust:
        return rp
    truth: TruthConfig = cfg.truth
    bias = truth.bound("thrust_bias_max")
    point = math.radians(truth.bound("thrust_pointing_max_deg"))
    # Under the ancillary tube the FTRE constants are those of the law the truth is handed to at
    # the terminal sample (its only use there: ancillary_ftre_handoff).
    ftre = handoff_control_config(cfg) if cfg.tsg.tube == "ancillary" else control_config(cfg)
    tc = tube_constants(orbit, ftre, bias, point)
    rp[R_ON] = 1.0
    rp[R_LAM] = tc["lam"]
    for name, idx in (("c0pp", R_C0PP), ("c0pv", R_C0PV), ("c0vp", R_C0VP), ("c0vv", R_C0VV),
                      ("dpp", R_DPP), ("dpv", R_DPV), ("cpe", R_CPE), ("dvp", R_DVP),
                      ("dvv", R_DVV), ("cve", R_CVE), ("kp", R_KP), ("kv", R_KV),
                      ("gpp", R_GPP), ("gpv", R_GPV), ("gvp", R_GVP), ("gvv", R_GVV),
                      ("hpp", R_HPP), ("hpv", R_HPV), ("hvp", R_HVP), ("hvv", R_HVV),
                      ("epp", R_EPP), ("epv", R_EPV), ("evp", R_EVP), ("evv", R_EVV)):
        rp[idx] = tc[name]
    if truth.nav_model == "realistic":  # a smooth filter output: moves by nav_rate_per_s
        rp[R_NRATE] = truth.nav_rate_per_s
    else:
        # An error that jumps at its measurement updates (filter) may move by its whole
        # diameter within a sample, and where the updates fall against Verify's samples is not
        # known: the tube bounds the loop's response to the error itself, C_n b per sample, with
        # no offset taken out (tube_step_jump), and nav_terms' change bound is the diameter, 2 b.
        rp[R_NJUMP] = 1.0
        rp[R_NRATE] = math.inf
        for name, idx in (("cnpp", R_CNPP), ("cnpv", R_CNPV), ("cnvp", R_CNVP), ("cnvv", R_CNVV)):
            rp[idx] = tc[name]
    rp[R_NPF] = truth.bound("nav_pos_floor_km")
    rp[R_NPG] = truth.bound("nav_pos_range_fraction")
    rp[R_NVF] = truth.bound("nav_vel_floor_kmps")
    rp[R_NVG] = truth.bound("nav_vel_range_fraction_per_s")
    rp[R_EPSU] = bias + (1.0 + bias) * 2.0 * math.sin(point / 2.0)
    rp[R_DMAX] = truth.bound("disturbance_max_kmps2")
    # The gravity gradient's norm at radius r is 2 mu / r^3 (two-body) times at most 1 + 6 J2
    # (R / r)^2 < 1.01 (J2): the kernel divides this by the smallest radius in the tube, cubed.
    rp[R_GRAD] = 2.0 * 1.01 * orbit.mu
    if truth.effective_gravity == "j2" and prediction_gravity(cfg) == "two-body":
        # The J2 difference between deputy and chief is left out of the prediction: bounded
        # by the J2 gradient at the lowest radius times the range (the deputy and the chief
        # stay above the chief's perigee less the start's spread).
        r_min = orbit.a * (1.0 - orbit.e) - 200.0
        rp[R_KG] = j2_gradient_bound(r_min, orbit.mu)
    if cfg.tsg.tube == "ancillary":
        if rp[R_KG] != 0.0:
            raise ConfigError("tsg.tube ancillary tracks the prediction in inertial space: the prediction "
                              "model must fly the truth's gravity (tsg.prediction_gravity auto or j2)")
        ta = tube_constants(orbit, ancillary_control_config(cfg), bias, point)
        rp[R_TUBE] = 1.0
        rp[R_GAMMA] = cfg.tsg.ancillary_gamma
        for i, name in enumerate(ANCILLARY_KEYS):
            rp[RA_LAM + i] = ta[name]
        rp[R_BETWEEN] = 1.0 if cfg.tsg.ancillary_between else 0.0
        if cfg.tsg.ancillary_bound == "l1":
            rp[R_L1] = 1.0
            for i, name in enumerate(L1_KEYS):
                rp[RL_DPP + i] = tc[name]
                rp[RLA_DPP + i] = ta[name]
            for i, block in enumerate(("pp", "pv", "vp", "vv")):
                rp[RA_ENV + i * N_ENV:RA_ENV + (i + 1) * N_ENV] = ta[f"env{block}"]
            rp[R_DOCK_P] = cfg.mission.dock_distance_km
            rp[R_DOCK_V] = cfg.mission.dock_speed_kmps
    rp.setflags(write=False)
    return rp


# -- kernels: robust Verify's checks and tube, called along the rollout (cikan_ros.tsg) ----------

@nb.njit(cache=True, error_model="numpy")
def robust_h1_ok(x: NDArray, xc: NDArray, cp: NDArray, sin_a: float, rho: float) -> bool:
    """Every position within rho (km) of x lies in the LoS cone or inside the apex radius:
    the distance of p = x - x_c to the cone's surface, |p| sin(alpha - theta), is >= rho
    (theta: angle between p and the port's axis, -v_c behind, +v_c ahead); positions within
    apex - rho need no check."""
    dot, pn, vn = los_terms_kernel(x, xc, cp[C_PORT])
    if pn <= cp[C_APEX] - rho:
        return True
    if pn == 0.0:
        return False
    c = -dot / (vn * pn)          # cos(theta)
    s = math.sqrt(max(0.0, 1.0 - c * c))
    return pn * (sin_a * c - cp[C_COS_ALPHA] * s) >= rho


@nb.njit(cache=True, error_model="numpy")
def robust_h3_ok(x: NDArray, xc: NDArray, cp: NDArray, rho: float, sig: float) -> bool:
    """h3 holds for every state within rho (km) and sigma (km/s) of x (h3 is active wherever
    |p| <= gamma1 may hold: |p| - rho <= gamma1)."""
    pn, vn = rel_norms_kernel(x, xc)
    lo = max(0.0, pn - rho)
    if lo > cp[C_GAMMA1]:
        return True
    return vn + sig - cp[C_GAMMA2] * lo - cp[C_GAMMA3] <= 0.0


@nb.njit(cache=True, error_model="numpy")
def nav_terms(rp: NDArray, rng: float, vrel: float, ts: float) -> tuple[float, float, float, float]:
    """Navigation error bounds b_p (km), b_v (km/s) at range rng (km) and the bounds of their
    change over one sample, Delta_p, Delta_v (the error's rate bound plus the change of the
    bound with the range, at most (vrel) ts)."""
    bp = rp[R_NPF] + rp[R_NPG] * rng
    bv = rp[R_NVF] + rp[R_NVG] * rng
    k = min(2.0, rp[R_NRATE] * ts)
    return bp, bv, k * bp + rp[R_NPG] * vrel * ts, k * bv + rp[R_NVG] * vrel * ts


@nb.njit(cache=True, error_model="numpy")
def loop_takes_over(rp: NDArray, big_r: float, big_s: float) -> tuple[float, float]:
    """The bounds (km, km/s) of a transient R, S held through a saturated phase, once the linear
    loop takes it over: C0 (R, S), the loop's gain from an initial error (:func:`tube_constants`)."""
    return (rp[R_C0PP] * big_r + rp[R_C0PV] * big_s, rp[R_C0VP] * big_r + rp[R_C0VV] * big_s)


@nb.njit(cache=True, error_model="numpy")
def tube_step_jump(rp: NDArray, u_max: float, ts: float, rng: float, vrel: float, rho: float,
                   sig: float, big_r: float, big_s: float, linear: bool, a_n: float, un: float,
                   grad: float) -> tuple[float, float, float, float, bool]:
    """:func:`tube_step` for a navigation error that may jump anywhere in its bound at every
    sample (``truth.nav_model`` filter): no offset is taken out (a jumping error has no steady
    part to cancel), R, S bound the whole error, and the loop's response to the error itself
    drives them: R' = lam R + C_n (b_p, b_v) + C_e eta (C_n_XY = max_m |X Phi^m B M K Y| /
    lam^m); saturated, the error and its jump turn the thrust."""
    rr = rng + rho
    bp, bv, dp, dv = nav_terms(rp, rr, vrel + sig, ts)
    m = rp[R_KP] * (big_r + bp) + rp[R_KV] * (big_s + bv)
    eta = rp[R_EPSU] * un + rp[R_DMAX] + rp[R_KG] * rr
    if a_n - m < u_max:
        if not linear:  # R, S held the saturated phase's error: the loop now takes it over
            big_r, big_s = loop_takes_over(rp, big_r, big_s)
        lam = rp[R_LAM]
        big_r = lam * big_r + rp[R_CNPP] * bp + rp[R_CNPV] * bv + rp[R_CPE] * eta
        big_s = lam * big_s + rp[R_CNVP] * bp + rp[R_CNVV] * bv + rp[R_CVE] * eta
        du = 2.0 * u_max + eta + grad * rho
        big_r = min(big_r, rho + ts * sig + 0.5 * ts * ts * du)
        big_s = min(big_s, sig + ts * du)
        return big_r, big_s, big_r, big_s, True
    du = u_max * (rp[R_KP] * (bp + dp) + rp[R_KV] * (bv + dv)) / (a_n - m) + eta + grad * rho
    big_r = big_r + ts * big_s + 0.5 * ts * ts * du
    big_s = big_s + ts * du
    return big_r, big_s, big_r, big_s, False


@nb.njit(cache=True, error_model="numpy")
def tube_step(rp: NDArray, u_max: float, ts: float, rng: float, vrel: float, rho: float,
              sig: float, big_r: float, big_s: float, linear: bool, a_n: float, un: float,
              grad: float) -> tuple[float, float, float, float, bool]:
    """The tube from sample j to j + 1: (rho, sigma, R, S, linear) after the step.

    rho, sigma bound the position (km) and velocity (km/s) error at j; rng, vrel are the
    predicted range (km) and relative speed (km/s), a_n the unsaturated and un the saturated
    command magnitude (km/s^2), grad the gravity gradient's bound in the tube (1/s^2);
    m = |K_p| (rho + b_p) + |K_v| (sigma + b_v) bounds how far the command of a state in the
    tube may differ from the prediction's.
    - Not every state of the tube saturates (a_n - m < u_max): the closed loop flown with the
      thruster map M, Phi_M = A - B M K (lam and the constants are the worst over M). The error is
      the navigation error's DC response G (b_p, b_v) plus a transient R, S that decays like
      lam^m: R' = lam R + D (Delta_p, Delta_v) + C_e eta, entered through the C0 constants; and
      never more than the open double integrator with |Delta u| <= 2 u_max allows.
    - Every state saturates: the feedback acts only across the thrust
      direction, with the gain u_max / |a| <= 1 (the projection onto the thrust ball), and not
      along it; the error is then propagated as an open double integrator (that feedback taken
      as no help) under the unknown accelerations, the command error the navigation error
      causes, (|K_p| b_p + |K_v| b_v) u_max / max(a_n - m, u_max), and the gravity gradient's
      bound g rho.
    docs/robustness.md states which of these steps are bounds and which approximations.
    A navigation error that jumps (``truth.nav_model`` filter): :func:`tube_step_jump`.
    """
    if rp[R_NJUMP] != 0.0:
        return tube_step_jump(rp, u_max, ts, rng, vrel, rho, sig, big_r, big_s, linear, a_n, un, grad)
    rr = rng + rho
    bp, bv, dp, dv = nav_terms(rp, rr, vrel + sig, ts)
    # The truth's command differs from the prediction's by K (e + delta): the transient R, S,
    # what of the navigation error does not cancel against its own offset ((I - G) delta), and
    # the error's last change.
    m = rp[R_KP] * (big_r + rp[R_HPP] * bp + rp[R_HPV] * bv + dp) \
        + rp[R_KV] * (big_s + rp[R_HVP] * bp + rp[R_HVV] * bv + dv)
    # The thruster error of the predicted command (the part proportional to the tube's own
    # command error is in the loop Phi_M = A - B M K of the tube constants).
    eta = rp[R_EPSU] * un + rp[R_DMAX] + rp[R_KG] * rr
    offset_p = rp[R_GPP] * bp + rp[R_GPV] * bv
    offset_v = rp[R_GVP] * bp + rp[R_GVV] * bv
    if a_n - m < u_max:
        if not linear:  # R, S held the transient of the saturated phase: it now decays
            big_r, big_s = loop_takes_over(rp, big_r, big_s)
        lam = rp[R_LAM]
        big_r = lam * big_r + rp[R_DPP] * dp + rp[R_DPV] * dv + rp[R_CPE] * eta
        big_s = lam * big_s + rp[R_DVP] * dp + rp[R_DVV] * dv + rp[R_CVE] * eta
        # Whatever the loop does, the commands differ by at most 2 u_max: the open double
        # integrator bounds the error too, and is the smaller bound while the tube is wide.
        du = 2.0 * u_max + eta + grad * rho
        cap_p = rho + ts * sig + 0.5 * ts * ts * du
        cap_v = sig + ts * du
        # the transient part is at most the whole error plus the offset's response
        big_r = min(big_r, cap_p + offset_p)
        big_s = min(big_s, cap_v + offset_v)
        return min(big_r + offset_p, cap_p), min(big_s + offset_v, cap_v), big_r, big_s, True
    # Saturated: a constant navigation error only displaces the target the deputy flies to
    # (the offset G b, as in the linear loop); its change per sample turns the thrust.
    du = u_max * (rp[R_KP] * dp + rp[R_KV] * dv) / (a_n - m) + eta + grad * rho
    big_r = big_r + ts * big_s + 0.5 * ts * ts * du
    big_s = big_s + ts * du
    return big_r + offset_p, big_s + offset_v, big_r, big_s, False


@nb.njit(cache=True, error_model="numpy")
def robust_terminal_ok(xv: NDArray, xc: NDArray, cp: NDArray, rp: NDArray, dp: float, dv: float,
                       big_r: float, big_s: float, linear: bool, ts: float) -> tuple[bool, float, float]:
    """The robust terminal test, once the prediction is in the nominal terminal set (dp, dv
    from the virtual target x_v). The prediction does not stop there: the FTRE loop carries it
    on along its transient, by at most P = E_pp dp + E_pv dv in position and V = E_vp dp + E_vv dv
    in velocity from x_v (E_XY = max_m |X Phi^m Y|, the nominal loop; a low-gain loop with
    0.1 m/s left coasts for metres), as long as that transient's command, at most
    |K_p| P + |K_v| V, stays below u_max (else: not yet, the rollout goes on). The tube's
    transient R, S (``big_r``, ``big_s``; held as the saturated phase's when not ``linear``)
    then decays toward the fixed point R_inf, S_inf of its recursion, with the forcing and the
    navigation offset G b bounded over the ball (the disturbance-invariant set of the tracking
    loop), so the truth stays within P + max(R, R_inf) + G_p b and V + max(S, S_inf) + G_v b of
    x_v, and that whole ball must satisfy h1 and h3 (docs/robustness.md, "terminal set")."""
    big_p = rp[R_EPP] * dp + rp[R_EPV] * dv
    big_v = rp[R_EVP] * dp + rp[R_EVV] * dv
    un = rp[R_KP] * big_p + rp[R_KV] * big_v
    if un >= cp[C_UMAX]:
        return False, 0.0, 0.0
    if not linear:  # the saturated phase's transient, as the loop takes it over (tube_step)
        big_r, big_s = loop_takes_over(rp, big_r, big_s)
    # The tube's radii bound the range and the relative speed of every future truth state; the
    # offset's and the forcing's bounds there make R_inf and the offsets bounds as well.
    rng = math.sqrt((xv[0] - xc[0]) ** 2 + (xv[1] - xc[1]) ** 2 + (xv[2] - xc[2]) ** 2)
    vel = math.sqrt((xv[3] - xc[3]) ** 2 + (xv[4] - xc[4]) ** 2 + (xv[5] - xc[5]) ** 2)
    gain = 1.0 / (1.0 - rp[R_LAM])
    rho = big_r
    sig = big_s
    for _ in range(50):  # the radii enter their own range and speed bounds: to the fixed point
        rr = rng + big_p + rho
        bp, bv, d_p, d_v = nav_terms(rp, rr, vel + big_v + sig, ts)
        eta = rp[R_EPSU] * un + rp[R_DMAX] + rp[R_KG] * rr
        if rp[R_NJUMP] != 0.0:  # a jumping error: its response, no offset (tube_step_jump)
            inf_r = gain * (rp[R_CNPP] * bp + rp[R_CNPV] * bv + rp[R_CPE] * eta)
            inf_s = gain * (rp[R_CNVP] * bp + rp[R_CNVV] * bv + rp[R_CVE] * eta)
            l1_r = rp[RL_CNPP] * bp + rp[RL_CNPV] * bv + rp[RL_CPE] * eta
            l1_s = rp[RL_CNVP] * bp + rp[RL_CNVV] * bv + rp[RL_CVE] * eta
            if rp[R_L1] != 0.0:  # the l1 norm's bound of the same forcing (docs/robustness.md, "The l1 bound")
                new_r = l1_fixed_point(big_r, inf_r, l1_r)
                new_s = l1_fixed_point(big_s, inf_s, l1_s)
            else:
                new_r, new_s = max(big_r, inf_r), max(big_s, inf_s)
        else:
            inf_r = gain * (rp[R_DPP] * d_p + rp[R_DPV] * d_v + rp[R_CPE] * eta)
            inf_s = gain * (rp[R_DVP] * d_p + rp[R_DVV] * d_v + rp[R_CVE] * eta)
            l1_r = rp[RL_DPP] * d_p + rp[RL_DPV] * d_v + rp[RL_CPE] * eta
            l1_s = rp[RL_DVP] * d_p + rp[RL_DVV] * d_v + rp[RL_CVE] * eta
            if rp[R_L1] != 0.0:
                new_r, new_s = l1_fixed_point(big_r, inf_r, l1_r), l1_fixed_point(big_s, inf_s, l1_s)
            else:
                new_r, new_s = max(big_r, inf_r), max(big_s, inf_s)
            new_r = new_r + rp[R_GPP] * bp + rp[R_GPV] * bv
            new_s = new_s + rp[R_GVP] * bp + rp[R_GVV] * bv
        settled = new_r - rho <= 1e-12 and new_s - sig <= 1e-15  # 1 nm, 1 pm/s
        rho, sig = new_r, new_s
        if settled:
            break
    else:
        return False, 0.0, 0.0  # no fixed point: the navigation error grows faster than the ball
    ok = (robust_h1_ok(xv, xc, cp, rp[R_SINA], big_p + rho)
          and robust_h3_ok(xv, xc, cp, big_p + rho, big_v + sig))
    return ok, big_p + rho, big_v + sig

@nb.njit(cache=True, error_model="numpy")
def tube_start(rp: NDArray, rng: float) -> tuple[float, float, float, float]:
    """The tube at sample 0, the measured state at range rng (km): off the truth by the
    navigation error delta (|delta_p| <= b_p, |delta_v| <= b_v), whose transient is
    -(I - G) delta. Returns (rho, sigma, R, S) in km and km/s."""
    rho = rp[R_NPF] + rp[R_NPG] * rng
    sig = rp[R_NVF] + rp[R_NVG] * rng
    if rp[R_NJUMP] != 0.0:  # the whole error -delta_0 (tube_step_jump; the first step's C0 takes it over)
        return rho, sig, rho, sig
    big_r = rp[R_HPP] * rho + rp[R_HPV] * sig
    big_s = rp[R_HVP] * rho + rp[R_HVV] * sig
    return rho, sig, big_r, big_s


@nb.njit(cache=True, error_model="numpy")
def tube_ok(x: NDArray, xc: NDArray, cp: NDArray, rp: NDArray, rho: float, sig: float) -> bool:
    """h1 and h3 hold on the whole tube around the predicted deputy x (chief xc, both (6,)):
    every state within rho (km) and sigma (km/s) of x."""
    if not robust_h1_ok(x, xc, cp, rp[R_SINA], rho):
        return False
    return robust_h3_ok(x, xc, cp, rho, sig)


@nb.njit(cache=True, error_model="numpy")
def tube_next(rp: NDArray, u_max: float, ts: float, x: NDArray, xc: NDArray, u: NDArray, a_n: float,
              rng: float, rho: float, sig: float, big_r: float, big_s: float, linear: bool
              ) -> tuple[float, float, float, float, bool]:
    """The tube at sample j + 1 around the predicted deputy x (range rng, km) of chief xc, with
    the saturated command u and its unsaturated magnitude a_n (km/s^2): :func:`tube_step` with
    the relative speed, |u| and the gravity gradient's bound at the lowest radius the tube
    reaches (not below 6000 km)."""
    vrel = math.sqrt((x[3] - xc[3]) ** 2 + (x[4] - xc[4]) ** 2 + (x[5] - xc[5]) ** 2)
    r_low = math.sqrt(xc[0] * xc[0] + xc[1] * xc[1] + xc[2] * xc[2]) - rng - rho
    return tube_step(rp, u_max, ts, rng, vrel, rho, sig, big_r, big_s, linear, a_n,
                     math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]),
                     rp[R_GRAD] / max(r_low, 6000.0) ** 3)


def gain_margin(orbit: KeplerOrbit, cfg: ControlConfig, tol: float = 1e-4) -> float:
    """The largest thrust magnitude error (fraction, no pointing error) the FTRE loop stays
    stable under, by bisection on :func:`loop_radius` (lam < 1, as :func:`tube_constants` asks)."""
    lo, hi = 0.0, 8.0
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if loop_radius(orbit, cfg, mid, 0.0)[0] < 1.0 - 1e-6:
            lo = mid
        else:
            hi = mid
    return lo


# -- the ancillary tube (``tsg.tube`` ancillary; docs/robustness.md, "The ancillary tube") --------
#
# The truth does not fly its own saturated FTRE loop: it tracks the accepted prediction (x_p,j,
# u_p,j, flown at gamma u_max) with u = u_p,j - K_a (x_hat - x_p,j), K_a the FTRE gain of the
# LQ weight ``tsg.ancillary_r_diag``. While that command stays within u_max the error
# e = x_truth - x_p obeys exactly e' = Phi_M e - B M K_a delta + B [(M - I) u_p + d], with
# Phi_M = A - B M K_a: the linear error system the recursions bound. Two recursions bound it,
# each sound alone, and the smaller is used: the transient z = e + G delta_(j-1) driven by the
# navigation error's changes (R1, S1: the D constants, as :func:`tube_step`), and the whole error
# driven by the navigation error itself (R2, S2: the C_n constants, as :func:`tube_step_jump`).
# The R are C-weighted (R_j >= |z_j| and R_(j+1) = lam R_j + forcing), so they start from C0
# times the error at sample 0.


@nb.njit(cache=True, error_model="numpy", inline="always")
def transient_bound(rp: NDArray, m: int, xp: float, xv: float) -> tuple[float, float]:
    """Bounds of |P Phi^m e_0| and |V Phi^m e_0| (km, km/s) for |e_0,p| <= xp, |e_0,v| <= xv,
    Phi the tracking loop (``tsg.ancillary_bound`` l1): its envelope sup |X Phi^m Y| for m <
    N_ENV, else C0 lam^m."""
    return transient_at(rp, m, rp[RA_LAM] ** m if m >= N_ENV else 1.0, xp, xv)


@nb.njit(cache=True, error_model="numpy", inline="always")
def transient_at(rp: NDArray, m: int, pw: float, xp: float, xv: float) -> tuple[float, float]:
    """:func:`transient_bound` with lam^m given (``pw``; read only for m >= N_ENV)."""
    if m < N_ENV:
        return (rp[RA_ENV + m] * xp + rp[RA_ENV + N_ENV + m] * xv,
                rp[RA_ENV + 2 * N_ENV + m] * xp + rp[RA_ENV + 3 * N_ENV + m] * xv)
    return pw * (rp[RA_C0PP] * xp + rp[RA_C0PV] * xv), pw * (rp[RA_C0VP] * xp + rp[RA_C0VV] * xv)


@nb.njit(cache=True, error_model="numpy", inline="always")
def start_transients(rp: NDArray, b0p: float, b0v: float) -> tuple[float, float, float, float]:
    """The initial errors of the ancillary tube's two recursions from the navigation bounds at
    sample 0 (:func:`ancillary_start`): the transient -(I - G) delta_0 (H b_0) and -delta_0."""
    return (rp[RA_HPP] * b0p + rp[RA_HPV] * b0v, rp[RA_HVP] * b0p + rp[RA_HVV] * b0v, b0p, b0v)


@nb.njit(cache=True, error_model="numpy")
def ancillary_start(rp: NDArray, rng: float) -> tuple[float, float, float, float, float, float]:
    """The ancillary tube at sample 0, the measured state at range rng (km): e_0 = -delta_0, so
    (rho, sigma) = (b_p, b_v) and the two recursions' C-weighted states (R1, S1, R2, S2) are C0
    times the transient -(I - G) delta_0 and C0 times delta_0. The bounds are taken at the
    largest true range the measured one allows, r <= (rng + floor) / (1 - fraction)."""
    true_rng = (rng + rp[R_NPF]) / max(1.0 - rp[R_NPG], 1e-9)
    bp = rp[R_NPF] + rp[R_NPG] * true_rng
    bv = rp[R_NVF] + rp[R_NVG] * true_rng
    zp = rp[RA_HPP] * bp + rp[RA_HPV] * bv
    zv = rp[RA_HVP] * bp + rp[RA_HVV] * bv
    if rp[R_L1] != 0.0:  # the transients' envelope at m = 0 (transient_bound), not C0
        r1, s1 = transient_bound(rp, 0, zp, zv)
        r2, s2 = transient_bound(rp, 0, bp, bv)
        return bp, bv, r1, s1, r2, s2
    r1 = rp[RA_C0PP] * zp + rp[RA_C0PV] * zv
    s1 = rp[RA_C0VP] * zp + rp[RA_C0VV] * zv
    r2 = rp[RA_C0PP] * bp + rp[RA_C0PV] * bv
    s2 = rp[RA_C0VP] * bp + rp[RA_C0VV] * bv
    return bp, bv, r1, s1, r2, s2


@nb.njit(cache=True, error_model="numpy")
def ancillary_step(rp: NDArray, u_max: float, ts: float, x: NDArray, xc: NDArray, u: NDArray,
                   rng: float, rho: float, sig: float, r1: float, s1: float, r2: float, s2: float,
                   j: int = 0, b0p: float = 0.0, b0v: float = 0.0
                   ) -> tuple[float, float, float, float, float, float, bool]:
    """The ancillary tube from sample j to j + 1 around the prediction x (range rng, km; chief
    xc) with the prediction's command u (km/s^2): (rho, sigma, R1, S1, R2, S2, headroom).

    Headroom: the truth's command u_p - K_a (e + delta) stays within u_max when |u_p| +
    |K_a,p| Dp + |K_a,v| Dv <= u_max, Dp and Dv the bounds of e + delta's position and velocity:
    min(R1 + H b + G Delta, rho + b) (e + delta = z + (I - G) delta_j + G (delta_j - delta_(j-1))).
    Without headroom the linear error system does not hold and the shift is refused (False).
    Under ``tsg.ancillary_bound`` l1 the forcing's constant part and the initial transients
    (from the navigation bounds b0p, b0v at sample 0) are bounded apart (:func:`l1_floor_step`)."""
    vrel = math.sqrt((x[3] - xc[3]) ** 2 + (x[4] - xc[4]) ** 2 + (x[5] - xc[5]) ** 2)
    rr = rng + rho
    bp, bv, dp, dv = nav_terms(rp, rr, vrel + sig, ts)
    un = math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    if command_bound_of(rp, un, bp, bv, dp, dv, rho, sig, r1, s1) > u_max:
        return rho, sig, r1, s1, r2, s2, False
    eta = rp[R_EPSU] * un + rp[R_DMAX] + rp[R_KG] * rr
    lam = rp[RA_LAM]
    if rp[R_L1] != 0.0:
        r1, s1, r2, s2 = l1_floor_step(rp, ts, lam, j, r1, s1, r2, s2, bp, bv, dp, dv, eta, b0p, b0v)
    else:
        r1 = lam * r1 + rp[RA_DPP] * dp + rp[RA_DPV] * dv + rp[RA_CPE] * eta
        s1 = lam * s1 + rp[RA_DVP] * dp + rp[RA_DVV] * dv + rp[RA_CVE] * eta
        r2 = lam * r2 + rp[RA_CNPP] * bp + rp[RA_CNPV] * bv + rp[RA_CPE] * eta
        s2 = lam * s2 + rp[RA_CNVP] * bp + rp[RA_CNVV] * bv + rp[RA_CVE] * eta
    rho = min(r1 + rp[RA_GPP] * bp + rp[RA_GPV] * bv, r2)
    sig = min(s1 + rp[RA_GVP] * bp + rp[RA_GVV] * bv, s2)
    return rho, sig, r1, s1, r2, s2, True


@nb.njit(cache=True, error_model="numpy", inline="always")
def l1_floor(lam: float, j: int, c_forcing: float, l_forcing: float) -> float:
    """The bound at sample j of a loop's response to a forcing bounded by a constant from sample 0
    on: the lam-weighted recursion's (1 - lam^j) / (1 - lam) C F or the l1 norm's L F (the whole
    sum, >= its first j terms), the smaller."""
    return min(l_forcing, (1.0 - lam ** j) / (1.0 - lam) * c_forcing)


@nb.njit(cache=True, error_model="numpy", inline="always")
def floor_forcings(rp: NDArray, ts: float) -> tuple[float, float, float, float, float, float, float, float,
                                                    float, float, float, float]:
    """The constant part of the ancillary tube's forcing (:func:`l1_floor_step`): the navigation
    error's change factor k (its change bound is k b + the range's part), the floors b_p0 (km),
    b_v0 (km/s) and d_max (km/s^2), then the bounds C F and L F of their responses, per sample and
    summed, for recursion 1 (position, velocity: c1p, c1v, l1p, l1v; forcing k (b_p0, b_v0) and
    d_max through D and C_e) and recursion 2 (c2p, c2v, l2p, l2v; (b_p0, b_v0) and d_max through C_n
    and C_e)."""
    k = min(2.0, rp[R_NRATE] * ts)
    p0, v0, d0 = rp[R_NPF], rp[R_NVF], rp[R_DMAX]
    c1p = rp[RA_DPP] * k * p0 + rp[RA_DPV] * k * v0 + rp[RA_CPE] * d0
    c1v = rp[RA_DVP] * k * p0 + rp[RA_DVV] * k * v0 + rp[RA_CVE] * d0
    l1p = rp[RLA_DPP] * k * p0 + rp[RLA_DPV] * k * v0 + rp[RLA_CPE] * d0
    l1v = rp[RLA_DVP] * k * p0 + rp[RLA_DVV] * k * v0 + rp[RLA_CVE] * d0
    c2p = rp[RA_CNPP] * p0 + rp[RA_CNPV] * v0 + rp[RA_CPE] * d0
    c2v = rp[RA_CNVP] * p0 + rp[RA_CNVV] * v0 + rp[RA_CVE] * d0
    l2p = rp[RLA_CNPP] * p0 + rp[RLA_CNPV] * v0 + rp[RLA_CPE] * d0
    l2v = rp[RLA_CNVP] * p0 + rp[RLA_CNVV] * v0 + rp[RLA_CVE] * d0
    return k, p0, v0, d0, c1p, c1v, l1p, l1v, c2p, c2v, l2p, l2v


@nb.njit(cache=True, error_model="numpy", inline="always")
def rest_forcing(rp: NDArray, k: float, p0: float, v0: float, d0: float, bp: float, bv: float, dp: float,
                 dv: float, eta: float) -> tuple[float, float, float, float]:
    """The ancillary tube's per-sample forcing less its constant part (:func:`floor_forcings`: k,
    the floors p0, v0, d0), for recursion 1 (D (Delta - k b_0) + C_e (eta - d0)) and recursion 2
    (C_n (b - b_0) + C_e (eta - d0)), position and velocity: (f1p, f1v, f2p, f2v)."""
    dp_, dv_, bp_, bv_, eta_ = dp - k * p0, dv - k * v0, bp - p0, bv - v0, eta - d0
    return (rp[RA_DPP] * dp_ + rp[RA_DPV] * dv_ + rp[RA_CPE] * eta_,
            rp[RA_DVP] * dp_ + rp[RA_DVV] * dv_ + rp[RA_CVE] * eta_,
            rp[RA_CNPP] * bp_ + rp[RA_CNPV] * bv_ + rp[RA_CPE] * eta_,
            rp[RA_CNVP] * bp_ + rp[RA_CNVV] * bv_ + rp[RA_CVE] * eta_)


@nb.njit(cache=True, error_model="numpy")
def l1_floor_step(rp: NDArray, ts: float, lam: float, j: int, r1: float, s1: float, r2: float, s2: float,
                  bp: float, bv: float, dp: float, dv: float, eta: float, b0p: float, b0v: float
                  ) -> tuple[float, float, float, float]:
    """The ancillary tube's recursions from sample j to j + 1 under ``tsg.ancillary_bound`` l1
    (docs/robustness.md, "The l1 bound"). The forcing's bound is split into its constant part
    (the navigation floors b_p0, b_v0 and their change bound k b_0, the disturbance d_max) and the
    rest (range and command terms); the error is linear in the forcing, so its bound is the sum of
    the two responses' bounds. The rest drives the lam-weighted recursion as before; the constant
    part's response at sample j is bounded by :func:`l1_floor` F_j. The R carry both: R_(j+1) =
    lam R_j + C F_rest + (F_(j+1) - lam F_j), which is lam R_j + C F_const until the l1 bound is
    the smaller, so R_j - F_j follows the rest's recursion. The initial errors' responses are
    taken apart the same way: their envelope T_j (:func:`transient_bound`, exact per power where
    C0 lam^j is loose), so R_j = V_j + F_j + T_j with V_j the forcing's rest from V_0 = 0."""
    k, p0, v0, d0, c1p, c1v, l1p, l1v, c2p, c2v, l2p, l2v = floor_forcings(rp, ts)
    f1p, f1v, f2p, f2v = rest_forcing(rp, k, p0, v0, d0, bp, bv, dp, dv, eta)
    z1p, z1v, z2p, z2v = start_transients(rp, b0p, b0v)
    pw = lam ** j  # one power a step: lam^(j+1) = lam^j lam, the sums' factors (1 - lam^j) / (1 - lam)
    pw1 = pw * lam
    g0, g1 = (1.0 - pw) / (1.0 - lam), (1.0 - pw1) / (1.0 - lam)
    t1p, t1v = transient_at(rp, j, pw, z1p, z1v)
    u1p, u1v = transient_at(rp, j + 1, pw1, z1p, z1v)
    t2p, t2v = transient_at(rp, j, pw, z2p, z2v)
    u2p, u2v = transient_at(rp, j + 1, pw1, z2p, z2v)
    r1 = lam * r1 + f1p + min(l1p, g1 * c1p) - lam * min(l1p, g0 * c1p) + u1p - lam * t1p
    s1 = lam * s1 + f1v + min(l1v, g1 * c1v) - lam * min(l1v, g0 * c1v) + u1v - lam * t1v
    r2 = lam * r2 + f2p + min(l2p, g1 * c2p) - lam * min(l2p, g0 * c2p) + u2p - lam * t2p
    s2 = lam * s2 + f2v + min(l2v, g1 * c2v) - lam * min(l2v, g0 * c2v) + u2v - lam * t2v
    return r1, s1, r2, s2


@nb.njit(cache=True, error_model="numpy", inline="always")
def l1_fixed_point(r0: float, c_inf: float, l_inf: float) -> float:
    """The sup over m of a bound lam^m R_0 + min((1 - lam^m) R_inf, L F) (the handed-over
    transient, then the lam-weighted fixed point R_inf = C F / (1 - lam) or the l1 norm's L F,
    the smaller at each m): R_0 + q max(R_inf - R_0, 0), q = min(1, L F / R_inf) (the sup of a
    piecewise-linear function of lam^m, at lam^m = 1 - q). max(R_0, R_inf) when q = 1."""
    q = min(1.0, l_inf / c_inf) if c_inf > 0.0 else 1.0
    return r0 + q * max(c_inf - r0, 0.0)


@nb.njit(cache=True, error_model="numpy")
def ancillary_command_bound(rp: NDArray, ts: float, x: NDArray, xc: NDArray, u: NDArray, rng: float,
                            rho: float, sig: float, r1: float, s1: float) -> float:
    """The bound (km/s^2) of the truth's command u_p - K_a (e + delta) at sample j of the ancillary
    tube (:func:`ancillary_step`): |u_p| + |K_a,p| Dp + |K_a,v| Dv."""
    vrel = math.sqrt((x[3] - xc[3]) ** 2 + (x[4] - xc[4]) ** 2 + (x[5] - xc[5]) ** 2)
    bp, bv, dp, dv = nav_terms(rp, rng + rho, vrel + sig, ts)
    return command_bound_of(rp, math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]), bp, bv, dp, dv,
                            rho, sig, r1, s1)


@nb.njit(cache=True, error_model="numpy", inline="always")
def command_bound_of(rp: NDArray, un: float, bp: float, bv: float, dp: float, dv: float, rho: float,
                     sig: float, r1: float, s1: float) -> float:
    """:func:`ancillary_command_bound` from the command's norm un and the navigation terms
    (:func:`nav_terms`) already at hand: Dp and Dv, the bounds of e + delta, are
    min(R1 + H b + G Delta, rho + b)."""
    dev_p = min(r1 + rp[RA_HPP] * bp + rp[RA_HPV] * bv + rp[RA_GPP] * dp + rp[RA_GPV] * dv,
                rho + bp)
    dev_v = min(s1 + rp[RA_HVP] * bp + rp[RA_HVV] * bv + rp[RA_GVP] * dp + rp[RA_GVV] * dv,
                sig + bv)
    return un + rp[RA_KP] * dev_p + rp[RA_KV] * dev_v


#: How the truth flies on from the terminal sample of an ancillary-tube rollout (the code robust
#: Verify's trace carries in its column 8, :func:`ancillary_terminal_ok`): the FTRE law toward x_v,
#: or the tracking law holding x_v with K_a.
HANDOFF_FTRE, HANDOFF_TRACK = 1.0, 2.0


@nb.njit(cache=True, error_model="numpy")
def ancillary_terminal_ok(xv: NDArray, xc: NDArray, cp: NDArray, rp: NDArray, dp: float, dv: float,
                          rho: float, sig: float, ts: float, r1: float = 0.0, s1: float = 0.0, r2: float = 0.0,
                          s2: float = 0.0, j: int = 0, b0p: float = 0.0, b0v: float = 0.0
                          ) -> tuple[bool, float, float, float]:
    """The robust terminal test of the ancillary tube: (ok, ball radii, handoff). From the
    terminal sample on the plan is done and the truth, within (rho, sigma) of the prediction
    there, which is within (dp, dv) of the virtual target x_v, is handed to one of two loops:

    - the FTRE law toward x_v (:data:`HANDOFF_FTRE`; :func:`ancillary_ftre_handoff`), when its
      terminal ball keeps the FTRE command below u_max: the stiffer loop, whose small ball lets
      tau = 0 fit inside the cone's apex radius (docking);
    - else the tracking law holding x_v, u = -K_a (x_hat - x_v) (:data:`HANDOFF_TRACK`;
      :func:`ancillary_track_handoff`), the loop the plan was tracked with, which does not
      saturate on a ball of kilometres: far from the chief, where the FTRE loop would.

    Under ``tsg.ancillary_bound`` l1 the tracking handoff continues the plan's recursions (r1, s1,
    r2, s2 at sample j: :func:`ancillary_track_continued`).
    """
    ok, ball_p, ball_v = ancillary_ftre_handoff(xv, xc, cp, rp, dp, dv, rho, sig, ts)
    if ok:
        return True, ball_p, ball_v, HANDOFF_FTRE
    if rp[R_L1] != 0.0:
        ok, ball_p, ball_v = ancillary_track_continued(xv, xc, cp, rp, dp, dv, r1, s1, r2, s2, j, b0p, b0v, ts)
    else:
        ok, ball_p, ball_v = ancillary_track_handoff(xv, xc, cp, rp, dp, dv, rho, sig, ts)
    return ok, ball_p, ball_v, HANDOFF_TRACK


@nb.njit(cache=True, error_model="numpy")
def ancillary_ftre_handoff(xv: NDArray, xc: NDArray, cp: NDArray, rp: NDArray, dp: float, dv: float,
                           rho: float, sig: float, ts: float) -> tuple[bool, float, float]:
    """The handoff to the FTRE law toward x_v: the truth's error from the prediction, within
    (rho, sigma), is handed to the FTRE loop as a transient z = e + G_K delta
    (:func:`robust_terminal_ok`, not linear: C0 takes it over); the truth's command, at most
    |K_p| (ball_p + b_p) + |K_v| (ball_v + b_v), must stay below u_max."""
    rng = math.sqrt((xv[0] - xc[0]) ** 2 + (xv[1] - xc[1]) ** 2 + (xv[2] - xc[2]) ** 2)
    vel = math.sqrt((xv[3] - xc[3]) ** 2 + (xv[4] - xc[4]) ** 2 + (xv[5] - xc[5]) ** 2)
    bp, bv, _, _ = nav_terms(rp, rng + rho, vel + sig, ts)
    big_r = rho + rp[R_GPP] * bp + rp[R_GPV] * bv
    big_s = sig + rp[R_GVP] * bp + rp[R_GVV] * bv
    ok, ball_p, ball_v = robust_terminal_ok(xv, xc, cp, rp, dp, dv, big_r, big_s, False, ts)
    if not ok:
        return False, 0.0, 0.0
    bp, bv, _, _ = nav_terms(rp, rng + ball_p, vel + ball_v, ts)
    u_bound = rp[R_KP] * (ball_p + bp) + rp[R_KV] * (ball_v + bv)
    if u_bound >= cp[C_UMAX]:
        return False, 0.0, 0.0
    if rp[R_BETWEEN] != 0.0 and not ball_between_ok(xv, xc, cp, rp, ball_p, ball_v, u_bound, ts):
        return False, 0.0, 0.0
    return True, ball_p, ball_v


@nb.njit(cache=True, error_model="numpy", inline="always")
def track_ball_ok(xv: NDArray, xc: NDArray, cp: NDArray, rp: NDArray, rng: float, vel: float, ball_p: float,
                  ball_v: float, ts: float) -> tuple[bool, float, float]:
    """The tracking handoff's ball (ball_p km, ball_v km/s about x_v, at range rng and relative
    speed vel): the command |K_a,p| (ball_p + b_p) + |K_a,v| (ball_v + b_v) below u_max (the law
    never saturates, so the linear error system holds), h1 and h3 on the ball, and between
    samples when ``tsg.ancillary_between``."""
    bp, bv, _, _ = nav_terms(rp, rng + ball_p, vel + ball_v, ts)
    u_bound = rp[RA_KP] * (ball_p + bp) + rp[RA_KV] * (ball_v + bv)
    if u_bound >= cp[C_UMAX]:
        return False, 0.0, 0.0
    ok = robust_h1_ok(xv, xc, cp, rp[R_SINA], ball_p) and robust_h3_ok(xv, xc, cp, ball_p, ball_v)
    if ok and rp[R_BETWEEN] != 0.0:
        ok = ball_between_ok(xv, xc, cp, rp, ball_p, ball_v, u_bound, ts)
    return ok, ball_p, ball_v


@nb.njit(cache=True, error_model="numpy")
def ancillary_track_handoff(xv: NDArray, xc: NDArray, cp: NDArray, rp: NDArray, dp: float, dv: float,
                            rho: float, sig: float, ts: float) -> tuple[bool, float, float]:
    """The handoff to the tracking law holding the virtual target, u = -K_a (x_hat - x_v): x_v
    flies the prediction's gravity (the truth's), so the error e = x - x_v obeys
    e' = Phi_M e - B M K_a delta + B d (Phi_M = A - B M K_a, the plan's tracking loop with the
    actual thrusters) from |e_p| <= rho + dp, |e_v| <= sigma + dv. Bounded as the ancillary tube's
    second recursion bounds it (driven by the navigation error itself, no smoothness assumed):
    R' = lam R + C_n b + C_e eta from R_0 = C0 e_0, so |e| <= max(R_0, R_inf) with R_inf =
    (C_n b + C_e eta) / (1 - lam), b and eta at the ball's own largest range and command (its
    fixed point, 1 nm); eta = eps_u |u| + d_max + k_g r over-counts the thruster error, which the
    loop's M already holds. The command |K_a,p| (ball_p + b_p) + |K_a,v| (ball_v + b_v) must stay
    below u_max (the law never saturates, so the linear error system holds), and the ball must
    satisfy h1 and h3 (checked at the terminal sample's geometry, as the FTRE ball)."""
    rng = math.sqrt((xv[0] - xc[0]) ** 2 + (xv[1] - xc[1]) ** 2 + (xv[2] - xc[2]) ** 2)
    vel = math.sqrt((xv[3] - xc[3]) ** 2 + (xv[4] - xc[4]) ** 2 + (xv[5] - xc[5]) ** 2)
    e_p, e_v = rho + dp, sig + dv
    r0 = rp[RA_C0PP] * e_p + rp[RA_C0PV] * e_v
    s0 = rp[RA_C0VP] * e_p + rp[RA_C0VV] * e_v
    gain = 1.0 / (1.0 - rp[RA_LAM])
    ball_p, ball_v = r0, s0
    for _ in range(100):  # the ball enters its own range, speed and command bounds: to the fixed point
        bp, bv, _, _ = nav_terms(rp, rng + ball_p, vel + ball_v, ts)
        un = rp[RA_KP] * (ball_p + bp) + rp[RA_KV] * (ball_v + bv)
        eta = rp[R_EPSU] * un + rp[R_DMAX] + rp[R_KG] * (rng + ball_p)
        inf_p = gain * (rp[RA_CNPP] * bp + rp[RA_CNPV] * bv + rp[RA_CPE] * eta)
        inf_v = gain * (rp[RA_CNVP] * bp + rp[RA_CNVV] * bv + rp[RA_CVE] * eta)
        if rp[R_L1] != 0.0:  # the l1 norm's bound of the same forcing (docs/robustness.md, "The l1 bound")
            new_p = l1_fixed_point(r0, inf_p, rp[RLA_CNPP] * bp + rp[RLA_CNPV] * bv + rp[RLA_CPE] * eta)
            new_v = l1_fixed_point(s0, inf_v, rp[RLA_CNVP] * bp + rp[RLA_CNVV] * bv + rp[RLA_CVE] * eta)
        else:
            new_p, new_v = max(r0, inf_p), max(s0, inf_v)
        settled = new_p - ball_p <= 1e-12 and new_v - ball_v <= 1e-15
        ball_p, ball_v = new_p, new_v
        if settled:
            break
    else:
        return False, 0.0, 0.0  # no fixed point: the navigation error grows faster than the ball
    return track_ball_ok(xv, xc, cp, rp, rng, vel, ball_p, ball_v, ts)


@nb.njit(cache=True, error_model="numpy", inline="always")
def plan_rests(rp: NDArray, ts: float, r1: float, s1: float, r2: float, s2: float, j: int, b0p: float,
               b0v: float) -> tuple[float, float, float, float]:
    """The rests V1, S1's, V2, S2's of the ancillary tube's recursions at sample j under the l1
    bound (:func:`l1_floor_step`): each state less its constant part's bound F_j and its initial
    transient's T_j."""
    lam = rp[RA_LAM]
    k, p0, v0, d0, c1p, c1v, l1p, l1v, c2p, c2v, l2p, l2v = floor_forcings(rp, ts)
    z1p, z1v, z2p, z2v = start_transients(rp, b0p, b0v)
    t1p, t1v = transient_bound(rp, j, z1p, z1v)
    t2p, t2v = transient_bound(rp, j, z2p, z2v)
    return (r1 - l1_floor(lam, j, c1p, l1p) - t1p, s1 - l1_floor(lam, j, c1v, l1v) - t1v,
            r2 - l1_floor(lam, j, c2p, l2p) - t2p, s2 - l1_floor(lam, j, c2v, l2v) - t2v)


@nb.njit(cache=True, error_model="numpy")
def ancillary_track_continued(xv: NDArray, xc: NDArray, cp: NDArray, rp: NDArray, dp: float, dv: float,
                              r1: float, s1: float, r2: float, s2: float, j: int, b0p: float, b0v: float,
                              ts: float) -> tuple[bool, float, float]:
    """The handoff to the tracking law holding x_v under ``tsg.ancillary_bound`` l1
    (docs/robustness.md, "The l1 bound"). That law is the loop the plan was tracked with, and x_v
    flies the truth's gravity with no command, so e = x - x_v = (x - x_p) + (x_p - x_v) obeys the
    plan's error system with u_p = 0 from the terminal sample j on: the plan's recursions go on
    from their states there (R1, S1, R2, S2: C-weighted, no re-weighting by C0), and the loop's
    response to the offset x_p - x_v (|.| <= dp, dv) adds lam^m C0 (dp, dv). Each recursion's
    state is its constant part's bound F_j (:func:`l1_floor`) plus the rest V_j, which goes from
    V_j toward its fixed point V_inf (the rest of the forcing at the ball's largest range, over
    1 - lam); the constant part stays below L F. So |e_p| <= C0 (dp, dv) + min(max(V1, V1_inf) +
    L F1 + G b, max(V2, V2_inf) + L F2), the same in velocity, with b at the ball's own range (the
    fixed point, 1 nm). The command |K_a,p| (ball_p + b_p) + |K_a,v| (ball_v + b_v) must stay below
    u_max, and the ball must satisfy h1, h3 and the between-samples check, as
    :func:`ancillary_track_handoff`."""
    rng = math.sqrt((xv[0] - xc[0]) ** 2 + (xv[1] - xc[1]) ** 2 + (xv[2] - xc[2]) ** 2)
    vel = math.sqrt((xv[3] - xc[3]) ** 2 + (xv[4] - xc[4]) ** 2 + (xv[5] - xc[5]) ** 2)
    lam = rp[RA_LAM]
    gain = 1.0 / (1.0 - lam)
    k, p0, v0, d0, c1p, c1v, l1p, l1v, c2p, c2v, l2p, l2v = floor_forcings(rp, ts)
    # the rests' states at j, and the sups over all later samples of the constant parts (L F) and
    # of the transients
    v1p, v1v, v2p, v2v = plan_rests(rp, ts, r1, s1, r2, s2, j, b0p, b0v)
    z1p, z1v, z2p, z2v = start_transients(rp, b0p, b0v)
    t1p = t1v = t2p = t2v = 0.0
    for m in range(j, max(j + 1, N_ENV + 1)):
        a1p, a1v = transient_bound(rp, m, z1p, z1v)
        a2p, a2v = transient_bound(rp, m, z2p, z2v)
        t1p, t1v, t2p, t2v = max(t1p, a1p), max(t1v, a1v), max(t2p, a2p), max(t2v, a2v)
    f1p, f1v = min(l1p, gain * c1p) + t1p, min(l1v, gain * c1v) + t1v
    f2p, f2v = min(l2p, gain * c2p) + t2p, min(l2v, gain * c2v) + t2v
    off_p = rp[RA_C0PP] * dp + rp[RA_C0PV] * dv
    off_v = rp[RA_C0VP] * dp + rp[RA_C0VV] * dv
    ball_p, ball_v = off_p + min(max(v1p, 0.0) + f1p, max(v2p, 0.0) + f2p), \
        off_v + min(max(v1v, 0.0) + f1v, max(v2v, 0.0) + f2v)
    for _ in range(100):  # the ball enters its own range and speed bounds: to the fixed point
        rr = rng + ball_p
        bp, bv, d_p, d_v = nav_terms(rp, rr, vel + ball_v, ts)
        # u_p = 0: no thruster error outside the loop's M; d_max is in the constant part
        f1p, f1v, f2p, f2v = rest_forcing(rp, k, p0, v0, d0, bp, bv, d_p, d_v, d0 + rp[R_KG] * rr)
        i1p, i1v, i2p, i2v = gain * f1p, gain * f1v, gain * f2p, gain * f2v
        new_p = off_p + min(max(v1p, i1p) + f1p + rp[RA_GPP] * bp + rp[RA_GPV] * bv, max(v2p, i2p) + f2p)
        new_v = off_v + min(max(v1v, i1v) + f1v + rp[RA_GVP] * bp + rp[RA_GVV] * bv, max(v2v, i2v) + f2v)
        settled = new_p - ball_p <= 1e-12 and new_v - ball_v <= 1e-15
        ball_p, ball_v = max(ball_p, new_p), max(ball_v, new_v)
        if settled:
            break
    else:
        return False, 0.0, 0.0  # no fixed point: the navigation error grows faster than the ball
    return track_ball_ok(xv, xc, cp, rp, rng, vel, ball_p, ball_v, ts)


# -- between samples (``tsg.ancillary_between``; docs/robustness.md, "Between samples, derived") --
#
# The constraints are checked on the tube at the samples; the truth moves on for Ts between them
# under a command held constant. Over one interval its relative position p = x_d - x_c obeys
# |p''| <= acc (thrust through the thruster map, the disturbance, the gravity difference), so it
# lies within acc s (Ts - s) / 2 <= acc Ts^2 / 8 of the chord between its two sample positions.
# The cone turns with the chief's velocity: in a frame that carries the cone's axis (angular
# velocity w = v_c x a_c / |v_c|^2, the axis transported without twist), q = R^T p obeys
# |q''| <= |p''| + 2 |w| |p'| + (|w|^2 + |w'|) |p|: the same chord bound with that Q. The depth
# of a point in the cone (its distance to the surface, :func:`sample_excess`) is concave, so a
# chord whose two ends are at depth >= Q Ts^2 / 8 keeps the truth in the cone; the apex ball does
# not turn, and a chord whose two ends are within a - acc Ts^2 / 8 of the chief stays in it. An
# interval that leaves one region for the other must stay in one of them by the motion bound from
# one of its ends (|p(s) - p_j| <= |v_j| s + acc s^2 / 2).

@nb.njit(cache=True, error_model="numpy")
def frame_rates(xc: NDArray, rp: NDArray, ts: float) -> tuple[float, float]:
    """Bounds of the turn rate |w| (rad/s) of the chief's velocity direction (the cone's axis)
    and of its derivative |w'| (rad/s^2) over one sample from the chief state xc (6,):
    w = v x a / |v|^2, |w| <= |a| / |v|, |w'| <= |a'| / |v| + 2 |a|^2 / |v|^2 with |a| <= 1.01 mu
    / r^2 and |a'| <= 2.02 mu |v| / r^3 (two-body and J2), at the lowest radius and speed the
    chief can reach within ts."""
    r = math.sqrt(xc[0] * xc[0] + xc[1] * xc[1] + xc[2] * xc[2])
    v = math.sqrt(xc[3] * xc[3] + xc[4] * xc[4] + xc[5] * xc[5])
    r_low = max(r - v * ts, 6000.0)
    acc = 0.5 * rp[R_GRAD] / (r_low * r_low)  # rp[R_GRAD] = 2.02 mu
    v_low = max(v - acc * ts, 1e-3)
    w = acc / v_low
    return w, rp[R_GRAD] / r_low ** 3 + 2.0 * w * w


@nb.njit(cache=True, error_model="numpy")
def sample_excess(x: NDArray, xc: NDArray, cp: NDArray, sin_a: float, rho: float) -> tuple[float, float]:
    """(cone excess, apex excess), km, of the tube of radius rho around the deputy x (chief xc):
    the depth of its shallowest position in the LoS cone, |p| sin(alpha - theta) - rho (negative:
    part of the tube is outside), and the room it leaves inside the apex ball, a - |p| - rho."""
    dot, pn, vn = los_terms_kernel(x, xc, cp[C_PORT])
    if pn == 0.0:
        return -rho, cp[C_APEX] - rho
    c = -dot / (vn * pn)
    s = math.sqrt(max(0.0, 1.0 - c * c))
    return pn * (sin_a * c - cp[C_COS_ALPHA] * s) - rho, cp[C_APEX] - pn - rho


@nb.njit(cache=True, error_model="numpy")
def interval_ok(cp: NDArray, ts: float, cone0: float, apex0: float, r0: float, v0: float,
                cone1: float, apex1: float, r1: float, v1: float, rho0: float, rho1: float,
                acc: float, w: float, wdot: float) -> bool:
    """h1 and h3 hold on the truth strictly between samples 0 and 1 of an interval: cone and apex
    excess (:func:`sample_excess`), predicted range r (km) and the truth's largest relative speed
    v (km/s) at each end, the tube radii rho, the bound acc (km/s^2) of the truth's relative
    acceleration over the interval and the cone's turn rates w, wdot (:func:`frame_rates`)."""
    vmax = max(v0, v1) + 0.5 * acc * ts  # |p'(s)| from the nearer end
    rmax = max(r0 + rho0, r1 + rho1) + acc * ts * ts / 8.0
    q = acc + 2.0 * w * vmax + (w * w + wdot) * rmax
    h1 = (min(cone0, cone1) >= q * ts * ts / 8.0  # the chord in the turning cone
          or min(apex0, apex1) >= acc * ts * ts / 8.0  # the chord in the apex ball
          or apex0 >= v0 * ts + 0.5 * acc * ts * ts or apex1 >= v1 * ts + 0.5 * acc * ts * ts
          or cone0 >= (v0 + w * rmax) * ts + 0.5 * q * ts * ts
          or cone1 >= (v1 + w * rmax) * ts + 0.5 * q * ts * ts)
    if not h1:
        return False
    # h3: the speed from the nearer end against the range from either end (each a lower bound
    # of the range at every instant of the interval)
    rmin = max(r0 - rho0 - v0 * ts - 0.5 * acc * ts * ts, r1 - rho1 - v1 * ts - 0.5 * acc * ts * ts, 0.0)
    return rmin > cp[C_GAMMA1] or vmax <= cp[C_GAMMA2] * rmin + cp[C_GAMMA3]


@nb.njit(cache=True, error_model="numpy")
def truth_acceleration(rp: NDArray, u_bound: float, r_max: float, r_chief: float) -> float:
    """A bound (km/s^2) of the truth's relative acceleration for a command of norm <= u_bound:
    the thruster map's gain (<= 1 + eps_u), the disturbance and the gravity difference over a
    range <= r_max at a chief radius r_chief (gradient <= 2.02 mu / r^3 there)."""
    return ((1.0 + rp[R_EPSU]) * u_bound + rp[R_DMAX]
            + rp[R_GRAD] / max(r_chief - r_max, 6000.0) ** 3 * r_max)


@nb.njit(cache=True, error_model="numpy")
def ball_between_ok(xv: NDArray, xc: NDArray, cp: NDArray, rp: NDArray, ball_p: float, ball_v: float,
                    u_bound: float, ts: float) -> bool:
    """After the terminal sample: the truth, within (ball_p, ball_v) of the virtual target x_v at
    every sample under a command of norm <= u_bound, keeps h1 and h3 between the samples too: its
    error from x_v lies within acc Ts^2 / 8 of the chord of two points of the ball (the ball is
    convex) and its speed within acc Ts / 2 of the nearer sample's; in the turning cone the chord
    bound takes Q (:func:`interval_ok`). Judged at the terminal sample's geometry, as the ball."""
    rng = math.sqrt((xv[0] - xc[0]) ** 2 + (xv[1] - xc[1]) ** 2 + (xv[2] - xc[2]) ** 2)
    vel = math.sqrt((xv[3] - xc[3]) ** 2 + (xv[4] - xc[4]) ** 2 + (xv[5] - xc[5]) ** 2)
    r_chief = math.sqrt(xc[0] * xc[0] + xc[1] * xc[1] + xc[2] * xc[2])
    acc = truth_acceleration(rp, u_bound, rng + ball_p, r_chief)
    w, wdot = frame_rates(xc, rp, ts)
    vmax = vel + ball_v + 0.5 * acc * ts
    q = acc + 2.0 * w * vmax + (w * w + wdot) * (rng + ball_p + acc * ts * ts / 8.0)
    return (robust_h1_ok(xv, xc, cp, rp[R_SINA], ball_p + q * ts * ts / 8.0)
            and robust_h3_ok(xv, xc, cp, ball_p + acc * ts * ts / 8.0, ball_v + 0.5 * acc * ts))


# -- the terminal ball over time (docking: docs/robustness.md, "Docking, certified") ------------

@nb.njit(cache=True, error_model="numpy")
def terminal_ball_after(xv: NDArray, xc: NDArray, rp: NDArray, dp: float, dv: float, rho: float,
                        sig: float, ball_p: float, ball_v: float, handoff: float, ts: float, n: int,
                        out: NDArray, r1: float = 0.0, s1: float = 0.0, r2: float = 0.0, s2: float = 0.0,
                        j: int = 0, b0p: float = 0.0, b0v: float = 0.0) -> None:
    """The ball (km, km/s) about x_v that the ancillary tube's terminal test certifies m = 0 .. n
    samples after its terminal sample, into ``out`` (n + 1, 2); the truth was within (rho, sigma)
    of the prediction there, the prediction within (dp, dv) of x_v, and the test accepted the
    ball (ball_p, ball_v) (:func:`ancillary_terminal_ok`).

    The terminal test bounds every later sample by that one ball, max(R_0, R_inf) (R_0 the handed-over
    transient, R_inf its recursion's fixed point). The recursion R_(m+1) = lam R_m + F_m gives more:
    R_m <= lam^m R_0 + (1 - lam^m) F / (1 - lam) with F bounding the forcing. The forcing (the
    navigation error's bounds and the thruster error of the command) grows with the range, which
    the ball itself bounds, so the bound is tightened by iteration: a sequence B_m that bounds the
    truth at every m (first the terminal test's ball) bounds the ranges at which the next
    sequence's forcing is taken, and that sequence bounds the truth too.

    - FTRE handoff (:data:`HANDOFF_FTRE`): B_m = P_m + R_m + G b, with the prediction's own
      transient P_m <= min(E (dp, dv), lam^m C0 (dp, dv)) (C0 includes the nominal loop's) and
      the forcing D Delta + C_e eta (``realistic``; C_n b and no offset under ``filter``), as
      :func:`robust_terminal_ok`;
    - tracking handoff (:data:`HANDOFF_TRACK`): B_m = R_m with R_0 = C0 (rho + dp, sigma + dv) and
      the forcing C_n b + C_e eta of the tracking loop, as :func:`ancillary_track_handoff`; under
      ``tsg.ancillary_bound`` l1 the plan's recursions go on from their states at its sample j
      (r1, s1, r2, s2; b0p, b0v its navigation bounds at sample 0), as
      :func:`ancillary_track_continued`, sample by sample (:func:`continued_ball_after`).
    """
    if handoff != HANDOFF_FTRE and rp[R_L1] != 0.0:
        continued_ball_after(xv, xc, rp, dp, dv, ball_p, ball_v, ts, n, out, r1, s1, r2, s2, j, b0p, b0v)
        return
    rng = math.sqrt((xv[0] - xc[0]) ** 2 + (xv[1] - xc[1]) ** 2 + (xv[2] - xc[2]) ** 2)
    vel = math.sqrt((xv[3] - xc[3]) ** 2 + (xv[4] - xc[4]) ** 2 + (xv[5] - xc[5]) ** 2)
    ftre = handoff == HANDOFF_FTRE
    jump = rp[R_NJUMP] != 0.0
    if ftre:
        lam = rp[R_LAM]
        bp, bv, _, _ = nav_terms(rp, rng + rho, vel + sig, ts)
        r0, s0 = loop_takes_over(rp, rho + rp[R_GPP] * bp + rp[R_GPV] * bv,
                                 sig + rp[R_GVP] * bp + rp[R_GVV] * bv)
        p_cap, v_cap = rp[R_EPP] * dp + rp[R_EPV] * dv, rp[R_EVP] * dp + rp[R_EVV] * dv
        p_dec, v_dec = rp[R_C0PP] * dp + rp[R_C0PV] * dv, rp[R_C0VP] * dp + rp[R_C0VV] * dv
    else:
        lam = rp[RA_LAM]
        r0 = rp[RA_C0PP] * (rho + dp) + rp[RA_C0PV] * (sig + dv)
        s0 = rp[RA_C0VP] * (rho + dp) + rp[RA_C0VV] * (sig + dv)
        p_cap = v_cap = p_dec = v_dec = 0.0
    for m in range(n + 1):  # the terminal test's own ball bounds every sample: the first sequence
        out[m, 0] = ball_p
        out[m, 1] = ball_v
    for _ in range(4):
        big_r, big_s = r0, s0
        dec = 1.0
        for m in range(n + 1):
            pm, vm = min(p_cap, dec * p_dec), min(v_cap, dec * v_dec)
            b_p, b_v = out[m, 0], out[m, 1]  # the previous sequence: this sample's range and speed
            bp, bv, d_p, d_v = nav_terms(rp, rng + b_p, vel + b_v, ts)
            if ftre:
                off_p = 0.0 if jump else rp[R_GPP] * bp + rp[R_GPV] * bv
                off_v = 0.0 if jump else rp[R_GVP] * bp + rp[R_GVV] * bv
                new_p, new_v = pm + big_r + off_p, vm + big_s + off_v
                un = rp[R_KP] * pm + rp[R_KV] * vm
                eta = rp[R_EPSU] * un + rp[R_DMAX] + rp[R_KG] * (rng + b_p)
                if jump:
                    fr = rp[R_CNPP] * bp + rp[R_CNPV] * bv + rp[R_CPE] * eta
                    fs = rp[R_CNVP] * bp + rp[R_CNVV] * bv + rp[R_CVE] * eta
                else:
                    fr = rp[R_DPP] * d_p + rp[R_DPV] * d_v + rp[R_CPE] * eta
                    fs = rp[R_DVP] * d_p + rp[R_DVV] * d_v + rp[R_CVE] * eta
            else:
                new_p, new_v = big_r, big_s
                un = rp[RA_KP] * (b_p + bp) + rp[RA_KV] * (b_v + bv)
                eta = rp[R_EPSU] * un + rp[R_DMAX] + rp[R_KG] * (rng + b_p)
                fr = rp[RA_CNPP] * bp + rp[RA_CNPV] * bv + rp[RA_CPE] * eta
                fs = rp[RA_CNVP] * bp + rp[RA_CNVV] * bv + rp[RA_CVE] * eta
            out[m, 0] = min(b_p, new_p)
            out[m, 1] = min(b_v, new_v)
            big_r = lam * big_r + fr
            big_s = lam * big_s + fs
            dec *= lam


@nb.njit(cache=True, error_model="numpy")
def docking_limit(rp: NDArray, handoff: float, ts: float) -> tuple[float, float]:
    """The ball (km, km/s) about the chief that the certified balls of a shift of 0
    (:func:`terminal_ball_after`) settle to, once every transient has decayed: the handoff
    loop's fixed point with the forcing at the ball's own range and speed (x_v is the chief).
    FTRE handoff: R_inf + G b (R_inf = (D Delta + C_e d_max) / (1 - lam), the nominal loop's
    transient gone); tracking handoff under the l1 bound (:func:`continued_ball_after`): min(V1_inf +
    F1 + G b, V2_inf + F2), F the constant parts' bounds min(L F, C F / (1 - lam)), V_inf the
    rest's fixed point."""
    ball_p = ball_v = 0.0
    for _ in range(200):  # increasing from 0 to the (unique: the forcing is affine in the range) fixed point
        bp, bv, d_p, d_v = nav_terms(rp, ball_p, ball_v, ts)
        if handoff == HANDOFF_FTRE:
            gain = 1.0 / (1.0 - rp[R_LAM])
            eta = rp[R_DMAX] + rp[R_KG] * ball_p
            if rp[R_NJUMP] != 0.0:
                new_p = gain * (rp[R_CNPP] * bp + rp[R_CNPV] * bv + rp[R_CPE] * eta)
                new_v = gain * (rp[R_CNVP] * bp + rp[R_CNVV] * bv + rp[R_CVE] * eta)
            else:
                new_p = gain * (rp[R_DPP] * d_p + rp[R_DPV] * d_v + rp[R_CPE] * eta) + rp[R_GPP] * bp + rp[R_GPV] * bv
                new_v = gain * (rp[R_DVP] * d_p + rp[R_DVV] * d_v + rp[R_CVE] * eta) + rp[R_GVP] * bp + rp[R_GVV] * bv
        else:
            lam = rp[RA_LAM]
            gain = 1.0 / (1.0 - lam)
            k, p0, v0, d0, c1p, c1v, l1p, l1v, c2p, c2v, l2p, l2v = floor_forcings(rp, ts)
            f1p, f1v, f2p, f2v = rest_forcing(rp, k, p0, v0, d0, bp, bv, d_p, d_v, d0 + rp[R_KG] * ball_p)
            i1p, i1v, i2p, i2v = gain * f1p, gain * f1v, gain * f2p, gain * f2v
            new_p = min(i1p + min(l1p, gain * c1p) + rp[RA_GPP] * bp + rp[RA_GPV] * bv, i2p + min(l2p, gain * c2p))
            new_v = min(i1v + min(l1v, gain * c1v) + rp[RA_GVP] * bp + rp[RA_GVV] * bv, i2v + min(l2v, gain * c2v))
        settled = new_p - ball_p <= 1e-12 and new_v - ball_v <= 1e-15
        ball_p, ball_v = new_p, new_v
        if settled:
            break
    return ball_p, ball_v


@nb.njit(cache=True, error_model="numpy")
def ancillary_docks(rp: NDArray, handoff: float, ts: float) -> bool:
    """Under the l1 bound, do the balls a shift of 0 is certified with settle inside the docking
    test (``R_DOCK_P``, ``R_DOCK_V``; :func:`docking_limit`)? The tracking handoff may certify
    tau = 0 safe with a ball that holds the truth decimetres off the client (the paper's orbit:
    0.69 m under its soft tracking law), where the FTRE handoff, certified a few minutes later,
    docks; a shift of 0 whose handoff cannot dock is refused, and the governor holds a shift
    near it until one can."""
    ball_p, ball_v = docking_limit(rp, handoff, ts)
    return ball_p <= rp[R_DOCK_P] and ball_v <= rp[R_DOCK_V]


@nb.njit(cache=True, error_model="numpy")
def continued_ball_after(xv: NDArray, xc: NDArray, rp: NDArray, dp: float, dv: float, ball_p: float,
                         ball_v: float, ts: float, n: int, out: NDArray, r1: float, s1: float, r2: float,
                         s2: float, j: int, b0p: float, b0v: float) -> None:
    """:func:`terminal_ball_after` for the tracking handoff under ``tsg.ancillary_bound`` l1: m
    samples after the plan's terminal sample j the truth is within T_off(m) + min(V1_m + F1(j + m)
    + T1(j + m) + G b_m, V2_m + F2(j + m) + T2(j + m)) of x_v (:func:`ancillary_track_continued`:
    the offset's envelope T_off from (dp, dv), the rests V from their states at j by V' = lam V +
    the rest of the forcing at the range the previous sequence bounds, the constant parts F
    (:func:`l1_floor`) and the initial transients T (:func:`transient_bound`) at sample j + m), the
    terminal test's ball (ball_p, ball_v) first, tightened by iteration as there."""
    rng = math.sqrt((xv[0] - xc[0]) ** 2 + (xv[1] - xc[1]) ** 2 + (xv[2] - xc[2]) ** 2)
    vel = math.sqrt((xv[3] - xc[3]) ** 2 + (xv[4] - xc[4]) ** 2 + (xv[5] - xc[5]) ** 2)
    lam = rp[RA_LAM]
    k, p0, v0, d0, c1p, c1v, l1p, l1v, c2p, c2v, l2p, l2v = floor_forcings(rp, ts)
    z1p, z1v, z2p, z2v = start_transients(rp, b0p, b0v)
    w1p, w1v, w2p, w2v = plan_rests(rp, ts, r1, s1, r2, s2, j, b0p, b0v)
    for m in range(n + 1):
        out[m, 0] = ball_p
        out[m, 1] = ball_v
    for _ in range(4):
        v1p, v1v, v2p, v2v = w1p, w1v, w2p, w2v
        for m in range(n + 1):
            b_p, b_v = out[m, 0], out[m, 1]  # the previous sequence: this sample's range and speed
            bp, bv, d_p, d_v = nav_terms(rp, rng + b_p, vel + b_v, ts)
            op, ov = transient_bound(rp, m, dp, dv)
            a1p, a1v = transient_bound(rp, j + m, z1p, z1v)
            a2p, a2v = transient_bound(rp, j + m, z2p, z2v)
            new_p = op + min(v1p + l1_floor(lam, j + m, c1p, l1p) + a1p + rp[RA_GPP] * bp + rp[RA_GPV] * bv,
                             v2p + l1_floor(lam, j + m, c2p, l2p) + a2p)
            new_v = ov + min(v1v + l1_floor(lam, j + m, c1v, l1v) + a1v + rp[RA_GVP] * bp + rp[RA_GVV] * bv,
                             v2v + l1_floor(lam, j + m, c2v, l2v) + a2v)
            out[m, 0] = min(b_p, new_p)
            out[m, 1] = min(b_v, new_v)
            # u = -K_a (x_hat - x_v): no command outside the loop's M
            f1p, f1v, f2p, f2v = rest_forcing(rp, k, p0, v0, d0, bp, bv, d_p, d_v, d0 + rp[R_KG] * (rng + b_p))
            v1p, v1v, v2p, v2v = lam * v1p + f1p, lam * v1v + f1v, lam * v2p + f2p, lam * v2v + f2v

