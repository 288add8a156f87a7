"""The truth judged between the control samples: the states at the plant's substeps, counted
against scipy's DOP853 dense output of the same motion judged with SPEC §4's h1 written out."""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from cikan_ros.config import load_config, truth_overrides
from cikan_ros.constraints import constraint_params, margins
from cikan_ros.mission import StepJudge, between_violations
from cikan_ros.orbit import KeplerOrbit, elements_to_state
from cikan_ros.robust import (R_SINA, ball_between_ok, frame_rates, interval_ok, robust_params, sample_excess,
                              truth_acceleration)
from cikan_ros.truth import Truth

MU = 398600.4418


def test_between_violations_count_the_substeps_outside_the_cone():
    """A deputy 100 m behind the chief, 15 deg off the docking axis (inside the 20 deg cone),
    drifting sideways at 2.5 m/s: it leaves the cone within the 10-s control period. The count
    is the number of the 9 inner substep instants where DOP853's trajectory has h1 > 0."""
    cfg = load_config()
    truth = Truth(cfg, None, 3)
    x_c = truth.chief_state(1)
    v_hat = x_c[3:] / np.linalg.norm(x_c[3:])
    n_hat = np.cross(x_c[:3], x_c[3:])
    n_hat /= np.linalg.norm(n_hat)
    beta = math.radians(15.0)
    x_d = x_c + np.concatenate([0.1 * (-math.cos(beta) * v_hat + math.sin(beta) * n_hat), 2.5e-3 * n_hat])
    u = np.array([1e-6, -2e-6, 5e-7])
    path = truth.deputy_path(1, x_d, u)
    count = between_violations(cfg, path, truth.chief_path(1))

    def rhs(_t, y, acc):
        return np.concatenate([y[3:], -MU * y[:3] / np.linalg.norm(y[:3]) ** 3 + acc])

    t_inner = np.arange(1, 10) * cfg.control.period_s / cfg.mission.plant_substeps
    dep = solve_ivp(rhs, (0, 10.0), x_d, args=(u,), method="DOP853", rtol=1e-12, atol=1e-12,
                    dense_output=True).sol(t_inner).T
    chief = solve_ivp(rhs, (0, 10.0), x_c, args=(np.zeros(3),), method="DOP853", rtol=1e-12,
                      atol=1e-12, dense_output=True).sol(t_inner).T
    p, v_c = dep[:, :3] - chief[:, :3], chief[:, 3:]
    cos_a = math.cos(math.radians(cfg.constraints.los_half_angle_deg))
    # behind: the port faces -v_c, h1 = v_c . p + cos(alpha) |v_c| |p|, normalised by |v_c| |p|
    h1n = (np.sum(v_c * p, axis=1) + cos_a * np.linalg.norm(v_c, axis=1) * np.linalg.norm(p, axis=1)) \
        / (np.linalg.norm(v_c, axis=1) * np.linalg.norm(p, axis=1))
    assert np.all(np.abs(h1n) > 1e-4)     # no substep on the knife edge
    expected = int(np.count_nonzero(h1n > 0))
    assert 0 < expected < 9 and count == expected
    # the simulator's one-call judge of a step: the same margins at t_k and the same count
    judge = StepJudge(cfg, cfg.thrust_limit_kmps2)
    m = margins(x_d, x_c, u, cfg.constraints, cfg.thrust_limit_kmps2, cfg.side)
    assert judge(x_d, x_c, u, path, truth.chief_path(1)) == (m.h1_normalised[0], m.h2[0], m.h3[0], expected)
    # the samples themselves (first and last rows) are not counted: outside the cone at both
    # ends, inside in between, is no violation between samples
    outside = x_c + (path[-1] - truth.chief_path(1)[-1])
    assert between_violations(cfg, np.array([outside] + [x_d] * 9 + [outside]), np.array([x_c] * 11)) == 0
    assert between_violations(cfg, np.array([x_d] + [outside] * 9 + [x_d]), np.array([x_c] * 11)) == 9
    assert judge(outside, x_c, u, np.array([x_d] + [outside] * 9 + [x_d]), np.array([x_c] * 11))[3] == 9
    np.testing.assert_array_equal(truth.chief_path(1)[-1], truth.chief_state(2))


def test_the_j2_chief_path_ends_on_the_chief_the_truth_flies():
    from cikan_ros.config import truth_overrides

    truth = Truth(load_config(**truth_overrides("realistic")), 3, 5)
    np.testing.assert_array_equal(truth.chief_path(2)[0], truth.chief_state(2))
    np.testing.assert_array_equal(truth.chief_path(2)[-1], truth.chief_state(3))


# -- the ancillary tube's bound between samples (robust.interval_ok, robust.ball_between_ok) -----

ANC = load_config(**{**truth_overrides("realistic"), "tsg.robust": True, "tsg.tube": "ancillary"})
ANC_RP = robust_params(ANC, KeplerOrbit.from_config(ANC.orbit))
ANC_CP = constraint_params(ANC.constraints, ANC.control.u_max_kmps2, ANC.side)


def flown_interval(x_c: np.ndarray, x_d: np.ndarray, u: np.ndarray, ts: float) -> tuple[np.ndarray, ...]:
    """Chief and deputy (two-body, the deputy under the constant acceleration u) over one sample
    with scipy's DOP853: (chief, deputy) at the end and (201, 6) of each on a fine grid."""
    def rhs(_t, y, acc):
        return np.concatenate([y[3:], -MU * y[:3] / np.linalg.norm(y[:3]) ** 3 + acc])

    grid = np.linspace(0.0, ts, 201)
    chief = solve_ivp(rhs, (0, ts), x_c, args=(np.zeros(3),), method="DOP853", rtol=1e-12, atol=1e-12,
                      dense_output=True).sol(grid).T
    dep = solve_ivp(rhs, (0, ts), x_d, args=(u,), method="DOP853", rtol=1e-12, atol=1e-12,
                    dense_output=True).sol(grid).T
    return chief, dep


def violated(chief: np.ndarray, dep: np.ndarray) -> bool:
    """SPEC §4's h1 and h3 written out on rows of chief and deputy states (behind: the port faces
    -v_c; h1 not judged within the apex radius, h3 only within gamma1)."""
    c = ANC.constraints
    p, v = dep[:, :3] - chief[:, :3], dep[:, 3:] - chief[:, 3:]
    pn, vn = np.linalg.norm(p, axis=1), np.linalg.norm(v, axis=1)
    v_c = chief[:, 3:]
    cos_theta = -np.sum(v_c * p, axis=1) / (np.linalg.norm(v_c, axis=1) * np.maximum(pn, 1e-300))
    h1_bad = (pn > c.los_apex_radius_km) & (cos_theta < math.cos(math.radians(c.los_half_angle_deg)))
    h3_bad = (pn <= c.gamma1_km) & (vn > c.gamma2_per_s * pn + c.gamma3_kmps)
    return bool(np.any(h1_bad | h3_bad))


def near_chief(rng: np.random.Generator, x_c: np.ndarray, rng_km: float, off_deg: float, speed: float) -> np.ndarray:
    """A deputy rng_km from the chief, off_deg off the docking axis (-v_c) in a random direction,
    moving at speed (km/s) in a random direction."""
    axis = -x_c[3:] / np.linalg.norm(x_c[3:])
    side = np.cross(axis, rng.normal(size=3))
    side /= np.linalg.norm(side)
    off = math.radians(off_deg)
    vel = rng.normal(size=3)
    return x_c + np.concatenate([rng_km * (math.cos(off) * axis + math.sin(off) * side),
                                 speed * vel / np.linalg.norm(vel)])


def test_the_interval_bound_keeps_the_truth_in_the_cone_between_samples():
    """Truth flown with DOP853 for one sample from random states near the cone's surface and the
    apex ball (0.3 m to 3 km, 0-24 deg off the axis, any direction of motion, a constant command
    up to u_max), around a prediction off the truth by at most the tube radii at both ends:
    wherever interval_ok passes the interval, h1 and h3 hold on the truth at every instant of it
    (robust.interval_ok's chord and motion bounds, docs/robustness.md, "Between samples,
    derived"). Both outcomes occur often, so the bound is exercised."""
    rng = np.random.default_rng(7)
    orbit = KeplerOrbit.from_config(ANC.orbit)
    ts = ANC.control.period_s
    passed = 0
    for _ in range(300):
        nu = rng.uniform(0.0, 2.0 * math.pi)
        x_c = elements_to_state(orbit.a, orbit.e, orbit.i, orbit.raan, orbit.argp, nu, orbit.mu)
        rng_km = 10.0 ** rng.uniform(-3.5, 0.5)
        x_d = near_chief(rng, x_c, rng_km, rng.uniform(0.0, 24.0), rng_km * 10.0 ** rng.uniform(-4.0, -1.0))
        u = rng.normal(size=3)
        u *= rng.uniform(0.0, ANC.control.u_max_kmps2) / np.linalg.norm(u)
        chief, dep = flown_interval(x_c, x_d, u, ts)
        rho = [rng.uniform(0.0, 0.2) * rng_km for _ in range(2)]
        sig = [rng.uniform(0.0, 0.2) * np.linalg.norm(x_d[3:] - x_c[3:]) for _ in range(2)]
        ends = []
        for i, row in ((0, 0), (1, -1)):  # the prediction: off the truth within the radii
            x_p = dep[row] + np.concatenate([ball_vector(rng, rho[i]), ball_vector(rng, sig[i])])
            cone, apex = sample_excess(x_p, chief[row], ANC_CP, ANC_RP[R_SINA], rho[i])
            ends += [cone, apex, float(np.linalg.norm(x_p[:3] - chief[row, :3])),
                     float(np.linalg.norm(x_p[3:] - chief[row, 3:])) + sig[i]]
        r_max = max(ends[2] + rho[0], ends[6] + rho[1]) + ANC.control.u_max_kmps2 * ts * ts
        acc = truth_acceleration(ANC_RP, float(np.linalg.norm(u)), r_max, float(np.linalg.norm(x_c[:3])))
        w, wdot = frame_rates(x_c, ANC_RP, ts)
        if interval_ok(ANC_CP, ts, *ends[:4], *ends[4:], rho[0], rho[1], acc, w, wdot):
            passed += 1
            assert not violated(chief, dep)
    assert 40 <= passed <= 240


def test_the_terminal_ball_keeps_the_truth_in_the_apex_ball_between_samples():
    """After tau = 0 the truth is within the terminal ball (ball_p, ball_v) of the chief at every
    sample. Flown with DOP853 from a state in the ball under a command up to the loop's bound,
    wherever it is in the ball again at the next sample and ball_between_ok accepts the ball,
    h1 and h3 hold at every instant between (the truth stays within the apex radius)."""
    rng = np.random.default_rng(11)
    orbit = KeplerOrbit.from_config(ANC.orbit)
    ts = ANC.control.period_s
    apex = ANC.constraints.los_apex_radius_km
    judged = accepted = 0
    for _ in range(400):
        nu = rng.uniform(0.0, 2.0 * math.pi)
        x_c = elements_to_state(orbit.a, orbit.e, orbit.i, orbit.raan, orbit.argp, nu, orbit.mu)
        ball_p, ball_v = rng.uniform(0.7, 1.0) * apex, 10.0 ** rng.uniform(-5.5, -4.0)
        u_bound = 10.0 ** rng.uniform(-6.0, -4.5)
        u = ball_vector(rng, u_bound, surface=True)
        # the worst bulge: from the ball's surface against u with velocity -u Ts / 2, the truth
        # comes back to where it started and peaks u Ts^2 / 8 outside the ball half way
        pos = -u / u_bound * ball_p * rng.uniform(0.9, 1.0) + ball_vector(rng, 0.1 * ball_p)
        vel = -0.5 * u * ts + ball_vector(rng, 0.1 * u_bound * ts)
        ball_v = max(ball_v, 1.1 * float(np.linalg.norm(vel)))
        chief, dep = flown_interval(x_c, x_c + np.concatenate([pos, vel]), u, ts)
        rel = dep[-1] - chief[-1]
        if np.linalg.norm(rel[:3]) > ball_p or np.linalg.norm(rel[3:]) > ball_v:
            continue  # not a truth the ball certifies at the next sample
        judged += 1
        if ball_between_ok(x_c, x_c, ANC_CP, ANC_RP, ball_p, ball_v, u_bound, ts):
            accepted += 1
            assert np.linalg.norm(dep[:, :3] - chief[:, :3], axis=1).max() <= apex
            assert not violated(chief, dep)
    assert 20 <= accepted <= judged - 20


def ball_vector(rng: np.random.Generator, radius: float, surface: bool = False) -> np.ndarray:
    """A random 3-vector of norm at most radius (exactly radius with ``surface``)."""
    v = rng.normal(size=3)
    return v / np.linalg.norm(v) * radius * (1.0 if surface else rng.uniform())
