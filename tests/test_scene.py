"""The scene's geometry in the chief's LVLH frame against independent references: the frame's
axes from the orbit's own geometry, the cone against h1 of cikan_ros.constraints, the rotating-frame
velocity against a finite difference of positions, the virtual target against the orbit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cikan_ros.config import Side, load_config
from cikan_ros.constraints import margins
from cikan_ros.orbit import KeplerOrbit, lvlh_frame
from cikan_ros.scene import (SceneBuilder, cone_rim, cone_triangles, port_axis_lvlh, relative_lvlh,
                             virtual_target_lvlh)

CFG = load_config()
ORBIT = KeplerOrbit.from_config(CFG.orbit)
TIMES = np.linspace(0.0, ORBIT.period, 37)


def test_lvlh_is_a_rotation_with_radial_along_track_normal_axes() -> None:
    x_c = ORBIT.state(TIMES)
    rot = lvlh_frame(x_c)
    np.testing.assert_allclose(rot @ np.swapaxes(rot, -1, -2), np.broadcast_to(np.eye(3), rot.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-14)
    r, v = x_c[:, :3], x_c[:, 3:]
    np.testing.assert_allclose(np.einsum("nij,nj->ni", rot, r), np.c_[np.linalg.norm(r, axis=1), 0 * r[:, :2]],
                               atol=1e-9)
    # the velocity has no normal part; its along-track part is h/|r| > 0, its radial part r.v/|r|
    v_l = np.einsum("nij,nj->ni", rot, v)
    h = np.linalg.norm(np.cross(r, v), axis=1)
    np.testing.assert_allclose(v_l[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(v_l[:, 1], h / np.linalg.norm(r, axis=1), rtol=1e-12)
    np.testing.assert_allclose(v_l[:, 0], np.sum(r * v, axis=1) / np.linalg.norm(r, axis=1), atol=1e-12)


def test_a_point_on_the_chief_velocity_maps_to_plus_y_at_periapsis() -> None:
    x_c = ORBIT.state(0.0)   # nu0 = 0: periapsis, r ⟂ v
    x_d = x_c.copy()
    x_d[:3] += 3.0 * x_c[3:] / np.linalg.norm(x_c[3:])
    p, _ = relative_lvlh(x_d, x_c)
    np.testing.assert_allclose(p[0], [0.0, 3.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("side", [Side.BEHIND, Side.AHEAD])
def test_cone_vertices_lie_on_h1_zero(side: Side) -> None:
    """Rim points of the cone drawn in LVLH, taken back to ECI, have normalised h1 = 0 by
    cikan_ros.constraints (so the drawn cone is the constraint's); the axis point is inside
    (h1 = cos a - 1) and its mirror outside."""
    for t in TIMES[::4]:
        x_c = ORBIT.state(t)
        rot = lvlh_frame(x_c)
        axis = port_axis_lvlh(x_c, side)
        rim = cone_rim(axis, CFG.constraints.los_half_angle_deg, 50.0)
        pts = np.vstack([rim, 50.0 * axis, -50.0 * axis])
        x_d = np.tile(x_c, (len(pts), 1))
        x_d[:, :3] += pts @ rot     # R^T p
        h1n = margins(x_d, x_c, np.zeros(3), CFG.constraints, 1.0, side).h1_normalised
        np.testing.assert_allclose(h1n[:-2], 0.0, atol=1e-12)
        cos_a = math.cos(math.radians(CFG.constraints.los_half_angle_deg))
        assert h1n[-2] == pytest.approx(cos_a - 1.0) and h1n[-1] == pytest.approx(cos_a + 1.0)
    tri = cone_triangles(axis, 20.0, 50.0, n=12)
    assert tri.shape == (36, 3) and np.all(tri[::3] == 0.0)   # every triangle has the apex (the port)


def test_port_axis_points_against_the_velocity_behind_and_along_it_ahead() -> None:
    x_c = ORBIT.state(0.0)
    np.testing.assert_allclose(port_axis_lvlh(x_c, Side.BEHIND), [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(port_axis_lvlh(x_c, Side.AHEAD), [0.0, 1.0, 0.0], atol=1e-12)


def test_relative_velocity_is_the_rate_in_the_rotating_frame() -> None:
    """Two Kepler orbits: the LVLH velocity equals the central difference of LVLH positions."""
    deputy = KeplerOrbit.from_state(ORBIT.state(-60.0), 0.0, ORBIT.mu)   # 60 s behind on the same orbit
    deputy = KeplerOrbit.from_state(deputy.state(0.0) + np.r_[0.5, -0.2, 0.3, 1e-4, 0.0, -2e-4], 0.0, ORBIT.mu)
    dt = 1e-2
    for t in (0.0, 3000.0, 20000.0):
        p_m, _ = relative_lvlh(deputy.state(t - dt), ORBIT.state(t - dt))
        p_p, _ = relative_lvlh(deputy.state(t + dt), ORBIT.state(t + dt))
        _, v = relative_lvlh(deputy.state(t), ORBIT.state(t))
        np.testing.assert_allclose(v[0], (p_p[0] - p_m[0]) / (2 * dt), rtol=1e-6, atol=1e-9)


def test_virtual_target_is_the_chief_orbit_tau_away() -> None:
    x_c = ORBIT.state(100.0)
    np.testing.assert_allclose(virtual_target_lvlh(ORBIT, x_c, 100.0, 0.0), 0.0, atol=1e-9)
    p_v = virtual_target_lvlh(ORBIT, x_c, 100.0, -30.0)[:3]
    assert np.linalg.norm(p_v) == pytest.approx(np.linalg.norm(ORBIT.state(70.0)[:3] - x_c[:3]), rel=1e-12)
    assert p_v[1] < 0.0    # behind: along-track negative


def test_builder_sends_the_constraints_when_the_axis_turned_and_decimates_the_path() -> None:
    b = SceneBuilder(CFG, path_every=6)
    assert b.constraints(ORBIT.state(0.0)) is not None
    assert b.constraints(ORBIT.state(10.0)) is None          # near periapsis the axis turns slowly
    turned = [t for t in np.arange(20.0, 3000.0, 10.0) if b.constraints(ORBIT.state(t)) is not None]
    assert turned    # the flight-path angle grows after periapsis: the cone turns in LVLH
    trails = [b.trail(k, np.array([float(k), 0.0, 0.0]), last=(k == 20)) for k in range(21)]
    assert [k for k, s in enumerate(trails) if s is not None] == [0, 6, 12, 18, 20]
    assert trails[20].points[:, 0].tolist() == [0.0, 6.0, 12.0, 18.0, 20.0]
