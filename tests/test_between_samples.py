"""The truth judged between the control samples: the states at the plant's substeps, counted
against scipy's DOP853 dense output of the same motion judged with SPEC §4's h1 written out."""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from cikan_ros.config import load_config
from cikan_ros.constraints import margins
from cikan_ros.mission import StepJudge, between_violations
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
