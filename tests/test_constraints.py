"""Constraints h1 (LoS, sign fixed), h2 (thrust), h3 (approach velocity): golden values and signs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cikan_ros.config import APPROACHES, Side, load_config
from cikan_ros.constraints import constraint_params, h1_line_of_sight, h2_thrust, h3_approach_velocity, margins

COS20 = math.cos(math.radians(20.0))


def _deputy(x_c, direction, dist, v_rel=(0.0, 0.0, 0.0)):
    x = x_c.copy()
    x[:3] += dist * np.asarray(direction) / np.linalg.norm(direction)
    x[3:] += v_rel
    return x


def test_h1_sign_on_the_velocity_axis(cfg, predictor):
    """Behind the chief (on -v_c) h1 = -|v||p| + cos a |v||p| < 0; ahead (+v_c) > 0."""
    x_c = predictor.orbit.state(0.0)
    v = x_c[3:]
    behind = _deputy(x_c, -v, 2.0)
    ahead = _deputy(x_c, v, 2.0)
    vn = np.linalg.norm(v)
    assert h1_line_of_sight(behind, x_c, cfg.constraints, Side.BEHIND)[0] == pytest.approx(-vn * 2 + COS20 * vn * 2)
    assert h1_line_of_sight(ahead, x_c, cfg.constraints, Side.BEHIND)[0] == pytest.approx(vn * 2 + COS20 * vn * 2)
    assert h1_line_of_sight(behind, x_c, cfg.constraints, Side.BEHIND)[0] < 0 \
        < h1_line_of_sight(ahead, x_c, cfg.constraints, Side.BEHIND)[0]


def test_h1_zero_on_the_cone_and_normalised_range(cfg, predictor):
    """On the cone (20 deg off -v_c) h1 = 0; normalised h1 = cos a - cos(angle from -v_c)."""
    x_c = predictor.orbit.state(500.0)
    e1 = -x_c[3:] / np.linalg.norm(x_c[3:])
    e2 = np.cross(e1, x_c[:3])
    e2 /= np.linalg.norm(e2)
    for deg in (0.0, 10.0, 20.0, 45.0, 180.0):
        a = math.radians(deg)
        d = _deputy(x_c, math.cos(a) * e1 + math.sin(a) * e2, 3.0)
        m = margins(d, x_c, np.zeros(3), cfg.constraints, 5e-4, Side.BEHIND)
        assert m.h1_normalised[0] == pytest.approx(COS20 - math.cos(a), abs=1e-12)
    assert abs(h1_line_of_sight(_deputy(x_c, math.cos(math.radians(20)) * e1 + math.sin(math.radians(20)) * e2,
                                        3.0), x_c, cfg.constraints, Side.BEHIND)[0]) < 1e-9


def test_h1_not_evaluated_inside_the_apex(cfg, predictor):
    x_c = predictor.orbit.state(0.0)
    for side in Side:
        assert math.isnan(h1_line_of_sight(_deputy(x_c, x_c[3:], 0.5e-3), x_c, cfg.constraints, side)[0])


def test_h3_inactive_beyond_gamma1_and_formula_inside(cfg, predictor):
    """h3 = |v_rel| - 20 |p_rel| - 1e-3 within 5 km; not evaluated (NaN) beyond."""
    x_c = predictor.orbit.state(0.0)
    far = _deputy(x_c, -x_c[3:], 5.001, v_rel=(1.0, 0, 0))
    assert math.isnan(h3_approach_velocity(far, x_c, cfg.constraints)[0])
    near = _deputy(x_c, -x_c[3:], 0.01, v_rel=(0.3, 0.0, 0.4))
    assert h3_approach_velocity(near, x_c, cfg.constraints)[0] == pytest.approx(0.5 - 20 * 0.01 - 1e-3)


def test_h2_thrust():
    assert h2_thrust(np.array([[3e-4, 4e-4, 0.0]]), 5e-4)[0] == pytest.approx(0.0, abs=1e-18)
    assert h2_thrust(np.array([[6e-4, 0.0, 0.0]]), 5e-4)[0] == pytest.approx(1e-4)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 180.0), st.floats(0.002, 50.0), st.floats(0.0, 40000.0))
def test_h1_sign_matches_the_cone_angle(angle_deg, dist, t):
    """h1 <= 0 exactly when the angle between p_rel and -v_c is <= alpha (away from the boundary)."""
    from cikan_ros.config import ConstraintConfig
    from cikan_ros.config import load_config
    from cikan_ros.orbit import KeplerOrbit

    cfg = load_config()
    x_c = KeplerOrbit.from_config(cfg.orbit).state(t)
    e1 = -x_c[3:] / np.linalg.norm(x_c[3:])
    e2 = np.cross(e1, x_c[:3])
    e2 /= np.linalg.norm(e2)
    a = math.radians(angle_deg)
    h1 = h1_line_of_sight(_deputy(x_c, math.cos(a) * e1 + math.sin(a) * e2, dist), x_c, ConstraintConfig(),
                          Side.BEHIND)[0]
    if abs(angle_deg - 20.0) > 1e-6:
        assert (h1 <= 0) == (angle_deg < 20.0)


def test_side_is_read_from_the_approach_and_packs_the_port() -> None:
    """mission.approach "behind" is Side.BEHIND = -1 (shifts <= 0), "ahead" Side.AHEAD = +1; the
    packed port sign (last slot) is -side; anything but -1 or +1 is refused."""
    assert APPROACHES == ("behind", "ahead")
    for approach, sign in (("behind", -1), ("ahead", 1)):
        side = load_config(**{"mission.approach": approach}).side
        assert side is Side.of(approach) and side == sign and side.approach == approach
        assert constraint_params(load_config().constraints, 5e-4, side)[-1] == -sign
    with pytest.raises(ValueError):
        constraint_params(load_config().constraints, 5e-4, 0)
