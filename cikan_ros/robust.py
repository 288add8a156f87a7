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
along its rollout (:func:`cikan_ros.tsg.rollout_kernel`). Here "p" rows are the position block,
"v" the velocity block; the forcing columns are B_d K restricted to position or velocity errors
(navigation) and B_d (accelerations). E_XY = max_m |X Phi^m Y| (the nominal loop, M = I, not
divided by lam^m) bounds how far the prediction's own transient carries it from the virtual
target after the terminal set (robust Verify's terminal ball, docs/robustness.md).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import NDArray

from .config import Config, ControlConfig, TruthConfig, control_config, prediction_gravity
from .control import B_INPUT, gain_table, zoh_discretise
from .dynamics import J2_EARTH, R_EARTH_KM, linearisation
from .errors import ConfigError
from .orbit import KeplerOrbit, elements_to_state

# Layout of the packed robustness parameters (``Predictor.rparams``).
(R_ON, R_LAM, R_C0PP, R_C0PV, R_C0VP, R_C0VV, R_DPP, R_DPV, R_CPE, R_DVP, R_DVV, R_CVE, R_KP, R_KV,
 R_NPF, R_NPG, R_NVF, R_NVG, R_EPSU, R_DMAX, R_KG, R_SINA, R_ZETA, R_GRAD, R_GPP, R_GPV, R_GVP,
 R_GVV, R_NRATE, R_HPP, R_HPV, R_HVP, R_HVV, R_EPP, R_EPV, R_EVP, R_EVV) = range(37)
N_RPARAMS = 37

#: Powers of the closed-loop matrix scanned for the constants C (lam^200 < 1e-11 here).
N_POWERS = 200
#: True anomalies (deg) of the gain table at which the closed loop is analysed.
ANALYSIS_STEP_DEG = 15.0


def thrust_matrices(bias: float, pointing_rad: float) -> list[NDArray]:
    """Extreme thruster maps M = (1 + b) R(theta) of the declared set |b| <= bias, theta <=
    pointing: b = -bias, 0, +bias times no rotation or a rotation by the full angle about two
    axes (the FTRE loop is isotropic to well within a percent, so the axis matters little)."""
    from .truth import rotation

    rots = [np.eye(3)] + ([rotation(np.array(a), pointing_rad) for a in
                           ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0])] if pointing_rad > 0 else [])
    gains = sorted({1.0 - bias, 1.0, 1.0 + bias})
    return [g * r for g in gains for r in rots]


class UnstableLoopError(ConfigError):
    """The declared thruster errors destabilise the FTRE loop: no error tube exists."""


@functools.lru_cache(maxsize=16)
def tube_constants(orbit: KeplerOrbit, cfg: ControlConfig, bias: float = 0.0,
                   pointing_rad: float = 0.0) -> dict[str, float]:
    """lam, the C, G, D, H and E constants and the gain norms |K_p|, |K_v| of the FTRE closed loop
    Phi_M = A_d - B_d M K flown with the thruster map M (:func:`thrust_matrices`), each the worst
    over M (E: over the nominal M = I only, the prediction's loop) and over the chief orbit's true
    anomaly (frozen-time analysis, every ANALYSIS_STEP_DEG). Raises UnstableLoopError when some M
    makes the loop unstable."""
    table = gain_table(orbit, cfg)
    n_cells = table.shape[0] - 1
    stride = max(1, round(ANALYSIS_STEP_DEG / cfg.grid_deg))
    keys = ("lam", "kp", "kv") + tuple(f"{c}{row}{col}" for c in ("c0", "g", "d", "h", "e")
                                        for row in "pv" for col in "pv") + ("cpe", "cve")
    out = {k: 0.0 for k in keys}
    systems = []
    for j in range(0, n_cells, stride):
        nu = 2.0 * math.pi * j / n_cells
        r = elements_to_state(orbit.a, orbit.e, orbit.i, orbit.raan, orbit.argp, nu, orbit.mu)[:3]
        a_d, b_d = zoh_discretise(linearisation(r, orbit.mu), B_INPUT, cfg.period_s)
        k = table[j]
        out["kp"] = max(out["kp"], float(np.linalg.norm(k[:, :3], 2)))
        out["kv"] = max(out["kv"], float(np.linalg.norm(k[:, 3:], 2)))
        for mat in thrust_matrices(bias, pointing_rad):
            bmk = b_d @ mat @ k
            phi = a_d - bmk
            systems.append((phi, b_d, bmk, bool(np.array_equal(mat, np.eye(3)))))
            out["lam"] = max(out["lam"], float(np.max(np.abs(np.linalg.eigvals(phi)))))
    if not out["lam"] < 1.0 - 1e-6:
        raise UnstableLoopError(
            f"thruster errors of {bias:.1%} in magnitude and {math.degrees(pointing_rad):.2f} deg in "
            f"pointing destabilise the FTRE loop with control weight R = {cfg.r_diag[0]:g} I (spectral "
            f"radius {out['lam']:.4f} >= 1): no error tube exists; a larger control.robust_r_diag "
            "widens the loop's gain margin (cikan tube prints it)")
    lam = out["lam"] = out["lam"] * (1.0 + 1e-6)
    rows = {"p": np.hstack([np.eye(3), np.zeros((3, 3))]), "v": np.hstack([np.zeros((3, 3)), np.eye(3)])}

    def worst(key: str, value: float) -> None:
        out[key] = max(out[key], value)

    scale = lam ** -np.arange(N_POWERS + 1.0)
    for phi, b_d, bmk, nominal in systems:
        powers = np.empty((N_POWERS + 2, 6, 6))
        powers[0] = np.eye(6)
        for m in range(N_POWERS + 1):
            powers[m + 1] = phi @ powers[m]
        # DC response to a constant navigation error: sum_l Phi^l B M K = (I - Phi)^-1 B M K, and
        # what is left of it after m steps: D_m = sum_{l > m} Phi^l B M K = Phi^(m+1) (DC).
        dc = np.linalg.solve(np.eye(6) - phi, bmk)
        # What of a constant navigation error the controller still sees once the loop has
        # settled: x_truth + delta - x_pred = (I - G) delta (the deputy flies to the target
        # displaced by delta, so a position error cancels, 1 - G_pp ~ 1e-4).
        seen = np.eye(6) - dc
        for row, rmat in rows.items():
            for col, cols in (("p", slice(0, 3)), ("v", slice(3, 6))):
                worst(f"h{row}{col}", float(np.linalg.norm(rmat @ seen[:, cols], 2)))
            rp_ = rmat @ powers  # (N + 2, 3, 6)
            for col, cols in (("p", slice(0, 3)), ("v", slice(3, 6))):
                worst(f"g{row}{col}", float(np.linalg.norm(rmat @ dc[:, cols], 2)))
                worst(f"d{row}{col}", float(np.max(norms(rp_[1:] @ dc[:, cols]) * scale)))
                worst(f"c0{row}{col}", float(np.max(norms(rp_[:-1][:, :, cols]) * scale)))
            worst(f"c{row}e", float(np.max(norms(rp_[:-1] @ b_d) * scale)))
            if nominal:  # the prediction's own loop: how far its transient can carry it
                for col, cols in (("p", slice(0, 3)), ("v", slice(3, 6))):
                    worst(f"e{row}{col}", float(np.max(norms(rp_[:-1][:, :, cols]))))
    return out


def norms(mats: NDArray) -> NDArray:
    """Spectral norms of a stack of matrices (..., r, c)."""
    return np.linalg.norm(mats, 2, axis=(-2, -1))


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
    tc = tube_constants(orbit, control_config(cfg), bias, point)
    rp[R_ON] = 1.0
    rp[R_LAM] = tc["lam"]
    for name, idx in (("c0pp", R_C0PP), ("c0pv", R_C0PV), ("c0vp", R_C0VP), ("c0vv", R_C0VV),
                      ("dpp", R_DPP), ("dpv", R_DPV), ("cpe", R_CPE), ("dvp", R_DVP),
                      ("dvv", R_DVV), ("cve", R_CVE), ("kp", R_KP), ("kv", R_KV),
                      ("gpp", R_GPP), ("gpv", R_GPV), ("gvp", R_GVP), ("gvv", R_GVV),
                      ("hpp", R_HPP), ("hpv", R_HPV), ("hvp", R_HVP), ("hvv", R_HVV),
                      ("epp", R_EPP), ("epv", R_EPV), ("evp", R_EVP), ("evv", R_EVV)):
        rp[idx] = tc[name]
    rp[R_NRATE] = truth.nav_rate_per_s
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
    rp.setflags(write=False)
    return rp


def gain_margin(orbit: KeplerOrbit, cfg: ControlConfig, tol: float = 1e-4) -> float:
    """The largest thrust magnitude error (fraction, no pointing error) the FTRE loop stays
    stable under, by bisection on :func:`tube_constants`."""
    lo, hi = 0.0, 8.0
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        try:
            tube_constants(orbit, cfg, mid, 0.0)
            lo = mid
        except UnstableLoopError:
            hi = mid
    return lo
