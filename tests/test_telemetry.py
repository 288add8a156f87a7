"""The telemetry dictionary: its contract (keys, units, limits, the document's round trip), its
values against hand-computed geometry, and ``cikan telemetry --json``."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from cikan_ros.config import load_config
from cikan_ros.orbit import KeplerOrbit
from cikan_ros.telemetry import FORMAT, N_VALUES, dictionary, from_json, keys, to_json, values

UNITS = {"s", "1", "deg", "m", "m/s", "m/s^2"}


@pytest.fixture(scope="module", params=["behind", "ahead"])
def cfg(request):
    return load_config(**{"mission.approach": request.param, "truth.thrust_bias_max": 0.1})


def test_contract(cfg) -> None:
    """Keys unique; units SI from one set; every stated limit finite and the margins' limit 0;
    the points the brief names are there; the shift's bound is on the approach side."""
    points = dictionary(cfg)
    ks = [p.key for p in points]
    assert len(ks) == len(set(ks)) and ks == keys(cfg)
    assert {"tau", "h1", "h2", "h3", "thrust", "speed", "speed_limit", "range", "los_angle",
            "p_x", "p_y", "p_z", "v_x", "v_y", "v_z"} <= set(ks)
    by = {p.key: p for p in points}
    for p in points:
        assert p.unit in UNITS, p
        assert p.type == "float64"
        for bound in (p.limit_low, p.limit_high, p.goal_high):
            assert bound is None or math.isfinite(bound), p
        assert p.limit_key is None or p.limit_key in by
    assert all(by[k].limit_high == 0.0 and by[k].limit_low is None for k in ("h1", "h2", "h3"))
    assert by["h3"].unit == "m/s" and by["speed"].unit == "m/s" and by["range"].unit == "m"
    # 0.5 m/s^2 commanded, 10 % declared thrust bias: the truth's limit is 0.55 m/s^2
    assert by["thrust"].limit_high == pytest.approx(0.55)
    assert by["los_angle"].limit_high == 20.0
    assert by["range"].goal_high == pytest.approx(1.0) and by["speed"].goal_high == pytest.approx(1e-3)
    tau = by["tau"]
    assert (tau.limit_low, tau.limit_high) == ((None, 0.0) if cfg.side < 0 else (0.0, None))
    assert all(p.frame == "lvlh" for p in points if p.key[:2] in ("p_", "v_"))


def test_document_round_trip(cfg) -> None:
    points = dictionary(cfg)
    doc = to_json(points, cfg)
    text = json.dumps(doc, allow_nan=False)
    back = json.loads(text)
    assert back["format"] == FORMAT and back["version"] == 1
    assert back["config"]["side"] == cfg.side.approach and back["config"]["los_half_angle_deg"] == 20.0
    assert from_json(back) == points
    with pytest.raises(ValueError, match="version"):
        from_json({**back, "version": 99})
    with pytest.raises(ValueError, match="format"):
        from_json({**back, "format": "other"})


def test_values_against_hand_geometry() -> None:
    """A deputy 2 km behind a chief at periapsis, on the port axis -v_c, closing at 1 m/s:
    angle 0, h1 = cos 20° - 1, range 2000 m, relative position (0, -2000, 0) m in LVLH (at
    periapsis v_c is along-track), speed limit 20/s * 2000 m + 1 m/s, h3 = 1 - 40001 m/s; thrust 0.3
    m/s^2 against 0.5 m/s^2."""
    cfg = load_config()
    x_c = KeplerOrbit.from_config(cfg.orbit).state(0.0)
    vhat = x_c[3:] / np.linalg.norm(x_c[3:])
    x_d = x_c.copy()
    x_d[:3] -= 2.0 * vhat
    x_d[3:] += 1e-3 * vhat
    u = np.array([3e-4, 0.0, 0.0])
    row = dict(zip(keys(cfg), values(cfg, x_c, x_d, u, -12.5)[0]))
    assert row["tau"] == -12.5
    assert row["los_angle"] == pytest.approx(0.0, abs=1e-5)
    assert row["h1"] == pytest.approx(math.cos(math.radians(20.0)) - 1.0, abs=1e-12)
    assert row["range"] == pytest.approx(2000.0, rel=1e-12)
    assert [row["p_x"], row["p_y"], row["p_z"]] == pytest.approx([0.0, -2000.0, 0.0], abs=1e-6)
    assert row["speed"] == pytest.approx(1.0, rel=1e-9)
    assert row["speed_limit"] == pytest.approx(40001.0)
    assert row["h3"] == pytest.approx(1.0 - 40001.0)
    assert row["thrust"] == pytest.approx(0.3) and row["h2"] == pytest.approx(0.3 - 0.5)
    # beyond gamma1 = 5 km h3 and its limit are not evaluated
    x_far = x_c.copy()
    x_far[:3] -= 10.0 * vhat
    far = dict(zip(keys(cfg), values(cfg, x_c, x_far, np.zeros(3), 0.0)[0]))
    assert math.isnan(far["h3"]) and math.isnan(far["speed_limit"]) and far["range"] == pytest.approx(1e4)
    # at the port (within the apex radius) h1 and the angle are not evaluated
    at_port = dict(zip(keys(cfg), values(cfg, x_c, x_c, np.zeros(3), 0.0)[0]))
    assert math.isnan(at_port["h1"]) and math.isnan(at_port["los_angle"]) and at_port["range"] == 0.0
    assert len(keys(cfg)) == N_VALUES


def test_cli_json() -> None:
    out = subprocess.run([sys.executable, "-m", "cikan_ros.cli", "telemetry", "--json", "--scenario", "leo",
                          "--set", "mission.approach=ahead"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    assert doc["config"]["scenario"] == "leo" and doc["config"]["side"] == "ahead"
    assert [p["key"] for p in doc["points"]][:1] == ["tau"]
    assert from_json(doc)[0].limit_low == 0.0
