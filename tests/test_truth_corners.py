"""Corners of the declared bounds and the filter navigation model: each pinned draw checked on
the Truth object against the bound it names (axes and directions rebuilt here from the chief's
state), the random draw unchanged, and bad corners refused by the `cikan` command."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from cikan_ros.config import CORNER_AXES, corners, load_config, parse_corner, truth_overrides
from cikan_ros.errors import ConfigError
from cikan_ros.truth import Truth


def realistic(**extra) -> object:
    return load_config(**{**truth_overrides("realistic"), **extra})


def corner_truth(name: str, n_steps: int = 60, **extra) -> Truth:
    return Truth(realistic(**{"truth.draw": "corner", "truth.corner": name, **extra}), 3, n_steps)


def test_corners_enumerate_every_sign_and_axis_once_and_drop_the_zero_bounds():
    tc = realistic().truth
    names = [c.name for c in corners(tc)]
    assert len(names) == len(set(names)) == 2 * 3 * 2 * 2 * 2
    assert all(parse_corner(n).name == n for n in names)
    assert {n.split(".")[1][:-1] for n in names} == {"along", "normal", "radial"}
    # a bound of 0 gives one truth at either sign: kept once
    assert len(corners(realistic(**{"truth.thrust_pointing_max_deg": 0.0}).truth)) == 2 * 2 * 2
    assert len(corners(realistic(**{"truth.disturbance_max_kmps2": 0.0,
                                    "truth.thrust_bias_max": 0.0}).truth)) == 3 * 2 * 2
    assert len(corners(load_config().truth)) == 1   # the nominal truth: every bound 0


def expected_axis(x_c0: np.ndarray, axis: str) -> np.ndarray:
    """The chief's VNB axes at the epoch, from its position and velocity."""
    v = x_c0[3:] / np.linalg.norm(x_c0[3:])
    h = np.cross(x_c0[:3], x_c0[3:])
    h /= np.linalg.norm(h)
    return {"along": v, "normal": h, "radial": np.cross(v, h)}[axis]


@pytest.mark.parametrize("name", ["b+.normal+.d+.n+", "b-.normal-.d-.n-", "b+.along-.d-.n+",
                                  "b-.radial+.d+.n-"])
def test_a_corner_pins_every_draw_on_its_bound(name):
    tc = realistic().truth
    c = parse_corner(name)
    truth = corner_truth(name)
    b_max, theta = tc.bound("thrust_bias_max"), math.radians(tc.bound("thrust_pointing_max_deg"))
    m = truth.thrust_matrix
    # (1 + b) R: the magnitude factor from the determinant, the angle from the trace, the axis
    # from the antisymmetric part (R - R^T = 2 sin(angle) [axis]x)
    factor = np.linalg.det(m) ** (1 / 3)
    assert factor == pytest.approx(1 + c.bias * b_max, abs=1e-14)
    r = m / factor
    assert math.acos((np.trace(r) - 1) / 2) == pytest.approx(theta, rel=1e-9)
    skew = (r - r.T) / (2 * math.sin(theta))
    axis = np.array([skew[2, 1], skew[0, 2], skew[1, 0]])
    np.testing.assert_allclose(axis, c.rotation * expected_axis(truth.chief_state(0), c.axis), atol=1e-9)
    # the disturbance: d_max along +-the chief's velocity at every step
    d_max = tc.bound("disturbance_max_kmps2")
    v_hat = truth.chief[:, 3:] / np.linalg.norm(truth.chief[:, 3:], axis=1, keepdims=True)
    np.testing.assert_allclose(truth.disturbance, c.disturbance * d_max * v_hat, rtol=1e-12, atol=0)
    # the navigation error: b_p(r), b_v(r) at the true range, along +-the line of sight
    for k, offset in ((0, [3.0, -1.0, 2.0]), (17, [-0.2, 0.05, 0.01]), (59, [1e-3, 0.0, -2e-4])):
        x = truth.chief_state(k) + np.array([*offset, 1e-4, -2e-4, 5e-5])
        meas, _ = truth.measure_deputy(k, x)
        rel = x[:3] - truth.chief_state(k)[:3]
        rng = np.linalg.norm(rel)
        bp = tc.bound("nav_pos_floor_km") + tc.bound("nav_pos_range_fraction") * rng
        bv = tc.bound("nav_vel_floor_kmps") + tc.bound("nav_vel_range_fraction_per_s") * rng
        # (measured - true: ECI states of 7000 km round to 1e-12 km)
        np.testing.assert_allclose(meas[:3] - x[:3], c.nav * bp * rel / rng, rtol=0, atol=1e-11)
        np.testing.assert_allclose(meas[3:] - x[3:], c.nav * bv * rel / rng, rtol=0, atol=1e-14)
        e_p, e_v = truth.nav_error(k, x)
        assert np.linalg.norm(e_p) == pytest.approx(bp, rel=1e-14)
        assert np.linalg.norm(e_v) == pytest.approx(bv, rel=1e-14)


def test_corner_fraction_pins_inside_the_bounds():
    half = corner_truth("b-.along+.d+.n+", **{"truth.corner_fraction": 0.5})
    full = corner_truth("b-.along+.d+.n+")
    assert half.bias == pytest.approx(full.bias / 2) and half.pointing_rad == pytest.approx(full.pointing_rad / 2)
    np.testing.assert_allclose(half.disturbance, full.disturbance / 2)


def test_the_random_draw_is_unchanged():
    # values of the truth's draws before corners and the filter model existed (seed 3)
    truth = Truth(realistic(), 3, 50)
    assert truth.bias == 0.012057785940645082
    assert truth.nav_pos[10, 0] == -0.5905537161567458
    assert truth.corner is None and truth.nav_sign is None


def test_filter_navigation_error_is_constant_between_updates_and_within_its_bound():
    cfg = realistic(**{"truth.nav_model": "filter", "truth.nav_update_s": 30.0})
    tc = cfg.truth
    truth = Truth(cfg, 4, 300)
    period = cfg.control.period_s
    for arr in (truth.nav_pos, truth.nav_vel):
        assert np.all(np.linalg.norm(arr, axis=1) <= 1.0 + 1e-15)
        change = np.linalg.norm(np.diff(arr, axis=0), axis=1)
        at_update = (np.arange(1, 301) % 3) == 0        # t = 30 s, 60 s, ...: every third sample
        assert np.all(change[~at_update] == 0.0) and np.all(change[at_update] > 0.0)
        bounds = np.array([tc.nav_change_bound(k * period, (k + 1) * period) for k in range(300)])
        assert np.all(change <= bounds) and set(bounds) == {0.0, 2.0}
    # the realistic model's bound is its rate limit over the period
    assert realistic().truth.nav_change_bound(0.0, period) == pytest.approx(0.02 * period)
    # a corner under the filter model jumps by the whole 2 b at each update
    corner = corner_truth("b+.normal+.d+.n+", 12, **{"truth.nav_model": "filter", "truth.nav_update_s": 20.0})
    np.testing.assert_array_equal(corner.nav_sign, [1, 1, -1, -1, 1, 1, -1, -1, 1, 1, -1, -1, 1])


@pytest.mark.parametrize("extra", [{"truth.corner": "b+.sideways+.d+.n+"}, {"truth.corner": ""},
                                   {"truth.corner": "b+.normal+.d+"}, {"truth.corner_fraction": 1.5},
                                   {"truth.nav_model": "kalman"}, {"truth.nav_update_s": 0.0}])
def test_bad_corners_and_navigation_models_are_named(extra):
    flat = {"truth.draw": "corner", "truth.corner": "b+.normal+.d+.n+", **extra}
    with pytest.raises(ConfigError, match=list(extra)[0].replace(".", r"\.")):
        realistic(**flat)
    with pytest.raises(ConfigError, match="truth.draw is 'random'"):
        realistic(**{"truth.corner": "b+.normal+.d+.n+"})


@pytest.mark.parametrize("sets, named", [
    (["truth.draw=corner", "truth.corner=b+.sideways+.d+.n+"], "truth.corner = 'b+.sideways+.d+.n+'"),
    (["truth.draw=corner", "truth.corner=b+.normal+.d+.n+", "truth.corner_fraction=1.5"],
     "truth.corner_fraction = 1.5"),
])
def test_the_cikan_command_refuses_a_bad_corner_in_one_line(sets, named):
    cmd = [sys.executable, "-m", "cikan_ros.cli", "mission", "--offline", "--truth", "realistic"]
    for s in sets:
        cmd += ["--set", s]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr
    assert out.stderr.count("\n") == 1 and named in out.stderr and "Traceback" not in out.stderr


def test_a_corner_navigation_error_moves_no_faster_than_the_declared_rate():
    """Under the rate-limited navigation model a corner's error is a member of the declared set:
    along the line of sight on its bound while that turns slowly (a deputy drifting 100 m out),
    and, where the line of sight turns faster (a deputy circling the chief at 1 cm, a quarter turn
    per step), moving toward it by at most nav_rate_per_s T_c of its bound per step, inside it
    (to the rounding of the ECI positions the line of sight is taken from)."""
    tc = realistic().truth
    truth = corner_truth("b+.along+.d+.n+", n_steps=40)
    step = tc.nav_rate_per_s * truth.period
    prev = None
    for k in range(40):
        if k < 20:   # slowly: on the bound, along the line of sight
            rel = np.array([0.1 + 1e-4 * k, 0.0, 0.0])
        else:        # a quarter turn per step around the chief, 1 cm out
            a = math.pi / 2 * k
            rel = 1e-5 * np.array([math.cos(a), math.sin(a), 0.0])
        x = truth.chief_state(k) + np.concatenate([rel, np.zeros(3)])
        e_p, e_v = truth.nav_error(k, x)
        bp, bv = truth.nav_bounds(float(np.linalg.norm(rel)))
        unit = e_p / bp
        np.testing.assert_allclose(e_v / bv, unit, rtol=0, atol=1e-9)
        assert np.linalg.norm(unit) <= 1.0 + 1e-9
        if k < 20:
            np.testing.assert_allclose(unit, rel / np.linalg.norm(rel), rtol=0, atol=1e-9)
        if prev is not None:
            assert np.linalg.norm(unit - prev) <= step + 1e-9
        if k > 21:
            assert np.linalg.norm(unit - prev) == pytest.approx(step)   # the limit acts
        prev = unit
