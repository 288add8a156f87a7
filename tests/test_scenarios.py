"""Scenarios and both approach sides (docs/scenarios.md): the scenario files, the docking port's
cone on either side (golden), the sign-agnostic searches against Verify itself (golden), whole
missions from ahead (contract), models per scenario and side, and bad input (one line, exit 2)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cikan_ros.cli import main
from cikan_ros.config import Side, load_config, scenario_names, scenario_overrides, truth_overrides
from cikan_ros.constraints import h1_line_of_sight, h3_approach_velocity
from cikan_ros.errors import ConfigError
from cikan_ros.governor import ConventionalGovernor
from cikan_ros.learn.errors import ModelFileError
from cikan_ros.learn.modelfile import MODELS_DIR, label_mismatch, scenario_model_dir
from cikan_ros.mission import nominal_shift, nominal_start, run_mission, sample_start
from cikan_ros.registry import make_governor
from cikan_ros.tsg import Predictor
from cikan_ros.units import through_si
from constant_network import constant_governor

COS20 = math.cos(math.radians(20.0))


def test_shipped_scenarios_load_and_name_themselves() -> None:
    assert {"paper", "leo", "geo"} <= set(scenario_names())
    for name in scenario_names():
        cfg = load_config(**scenario_overrides(name))
        assert cfg.scenario.name == name
        assert cfg.scenario.description
    # "paper" is config/cikan.yaml itself.
    assert load_config(**scenario_overrides("paper")) == load_config()


def test_bad_scenarios_are_refused_naming_the_problem(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="unknown scenario 'mars'.*paper"):
        scenario_overrides("mars")
    f = tmp_path / "s.yaml"
    f.write_text("/**:\n  ros__parameters:\n    orbit:\n      a_kmm: 7000.0\n")
    with pytest.raises(ConfigError, match=r"s\.yaml.*unknown configuration parameter 'orbit\.a_kmm'"):
        scenario_overrides(str(f))
    f.write_text("/**:\n  ros__parameters:\n    orbit:\n      e: 1.5\n")
    with pytest.raises(ConfigError, match=r"s\.yaml.*orbit\.e = 1\.5"):
        scenario_overrides(str(f))
    f.write_text("/**:\n  ros__parameters:\n    truth:\n      scale: 2.0\n")
    with pytest.raises(ConfigError, match="does not choose the truth"):
        scenario_overrides(str(f))
    with pytest.raises(ConfigError, match="mission.approach"):
        load_config(**{"mission.approach": "sideways"})


@pytest.mark.parametrize("argv, needle", [
    (["mission", "--offline", "--scenario", "mars"], "unknown scenario 'mars'"),
    (["mission", "--offline", "--set", "mission.approach=left"], "mission.approach"),
    (["mission", "--offline", "--governor", "cikan", "--set", "mission.approach=ahead",
      "--set", "scenario.models_dir=/nonexistent"], "no cikan model for scenario 'paper', approach 'ahead'"),
    (["mission", "--offline", "--governor", str(MODELS_DIR / "cikan"), "--set", "mission.approach=ahead"],
     "trained for scenario 'paper', approach 'behind'"),
])
def test_bad_input_is_one_line_and_exit_code_2(argv: list[str], needle: str, capsys) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and needle in err and "Traceback" not in err


def test_h1_port_faces_the_approach() -> None:
    """h1 = a v_c.p + cos(a) |v_c| |p| with port sign a = +1 behind, -1 ahead: a deputy 2 km
    along -v_c is inside the cone from behind (h1 = |v|2(cos20 - 1) < 0) and outside it from
    ahead (h1 = |v|2(1 + cos20) > 0), and the other way round along +v_c."""
    cfg = load_config()
    x_c = np.array([7000.0, 0.0, 0.0, 0.0, 7.5, 0.0])
    vn = 7.5
    behind = x_c.copy()
    behind[1] -= 2.0
    ahead = x_c.copy()
    ahead[1] += 2.0
    assert h1_line_of_sight(behind, x_c, cfg.constraints, Side.BEHIND)[0] == pytest.approx(vn * 2 * (COS20 - 1))
    assert h1_line_of_sight(behind, x_c, cfg.constraints, Side.AHEAD)[0] == pytest.approx(vn * 2 * (COS20 + 1))
    assert h1_line_of_sight(ahead, x_c, cfg.constraints, Side.AHEAD)[0] == pytest.approx(vn * 2 * (COS20 - 1))
    assert h1_line_of_sight(ahead, x_c, cfg.constraints, Side.BEHIND)[0] == pytest.approx(vn * 2 * (COS20 + 1))


@pytest.fixture(scope="module")
def ahead() -> Predictor:
    return Predictor.from_config(load_config(**{"mission.approach": "ahead"}))


def test_nominal_start_ahead_is_the_chief_orbit_point_d_ahead(ahead: Predictor) -> None:
    """tau_nom > 0 with |x_c(tau_nom) - x_c(0)| = D (Kepler motion), the mirror of behind."""
    tau = nominal_shift(ahead)
    assert tau > 0
    d = np.linalg.norm(ahead.orbit.state(tau)[:3] - ahead.orbit.state(0.0)[:3])
    assert d == pytest.approx(ahead.config.mission.nominal_distance_km, rel=1e-10)
    np.testing.assert_array_equal(nominal_start(ahead), ahead.orbit.state(tau))


def test_searches_ahead_agree_with_verify(ahead: Predictor) -> None:
    """First-instant search and pi* ahead of the chief, checked against Verify itself: the
    answer passes, and the bisection's bracket ends within the tolerance closer to 0 on a shift
    Verify rejects (feasibility is not monotone near the answer, SPEC §5: the rejected shift is
    the bracket's end, not any shift one tolerance away)."""
    x0 = sample_start(ahead, 3)
    tau0, _ = ahead.initial_shift(x0, 0.0)
    assert 0.0 < tau0 <= ahead.config.tsg.initial_window_s
    assert ahead.verify(x0, 0.0, tau0)
    res = run_mission(ConventionalGovernor(ahead), x0, 3)
    checked = 0
    for u in res.updates:
        if not u.active or u.tau_s in (0.0, u.tau_prev):
            continue
        step = round(u.k * 6)
        x = through_si(res.x_d[step])                      # what the governor saw
        t = float(res.t[step])
        assert ahead.verify(x, t, u.tau_s)
        lo, hi, _ = ahead.bisect_bracket(x, t, u.tau_prev, 0.0)
        assert lo == u.tau_s and 0.0 < lo - hi <= ahead.config.tsg.tolerance_s + 1e-12
        assert not ahead.verify(x, t, hi)
        checked += 1
        if checked == 5:
            break
    assert checked


@settings(max_examples=25, deadline=None)
@given(tau_prev=st.floats(0.5, 50.0), ratio=st.floats(0.0, 1.5))
def test_keep_rule_candidates_are_mirrored(tau_prev: float, ratio: float) -> None:
    """The ladder ahead is the ladder behind with every shift negated (one implementation)."""
    cfg = load_config()
    behind_gov = constant_governor(_predictor(cfg, "behind"), 1.0)
    ahead_gov = constant_governor(_predictor(cfg, "ahead"), 1.0)
    tau_c = ratio * tau_prev
    assert ahead_gov.candidates(tau_c, tau_prev) == [-c for c in behind_gov.candidates(-tau_c, -tau_prev)]


_PREDICTORS: dict[str, Predictor] = {}


def _predictor(cfg, approach: str) -> Predictor:
    if approach not in _PREDICTORS:
        _PREDICTORS[approach] = Predictor.from_config(cfg.replace(**{"mission.approach": approach}))
    return _PREDICTORS[approach]


@pytest.mark.parametrize("scenario", ["paper", "leo"])
def test_conventional_docks_from_ahead(scenario: str) -> None:
    """From ahead, on the paper's orbit and in LEO: 0 violations (h1 with the port facing
    forward), docked, tau >= 0 all along and 0 at the end."""
    cfg = load_config(**scenario_overrides(scenario), **{"mission.approach": "ahead"})
    pred = Predictor.from_config(cfg)
    res = run_mission(ConventionalGovernor(pred), sample_start(pred, 2), 2)
    m = res.metrics()
    assert m["violations"] == 0 and m["success"], m
    assert np.all(res.tau[np.isfinite(res.tau)] >= 0.0)
    assert res.tau[-1] == 0.0


def _speed_limit(cfg, ranges_km: np.ndarray) -> np.ndarray:
    """The approach-speed limit (km/s) that h3 puts on a deputy at each range (km): the |v_rel| at
    which h3 = |v_rel| - gamma2 |p_rel| - gamma3 is 0 where h3 is evaluated (|p_rel| <= gamma1),
    +inf (no limit) where it is not. Read from the constraint code on constructed states: h3 is
    affine in |v_rel|, so the limit is |v_rel| - h3 at any probe speed."""
    x_c = np.array([42164.17, 0.0, 0.0, 0.0, 3.0747, 0.0])
    x_d = np.tile(x_c, (len(ranges_km), 1))
    x_d[:, 1] -= ranges_km                       # behind along -v_c
    probe = 2e-3                                 # km/s, closing along +v_c
    x_d[:, 4] += probe
    h3 = h3_approach_velocity(x_d, x_c, cfg.constraints)
    return np.where(np.isnan(h3), np.inf, probe - h3)


def test_geo_speed_limit_has_no_jump_the_governor_can_ride() -> None:
    """The mechanism behind GEO Monte Carlo start 83 (SPEC §4, cikan_ros/constraints.py):
    h3 = |v_rel| - gamma2 |p_rel| - gamma3, evaluated only when |p_rel| <= gamma1, so the speed
    limit is L(r) = gamma2 r + gamma3 inside gamma1 and none beyond. With gamma1 = 1 km L jumps at
    1 km from none to 1.01 m/s: a prediction sampled just outside sees no limit while the plant,
    just inside at 1.03 m/s, violates (measured on one processor: h3 = +1.9e-5 km/s; which side
    a whole mission's samples land on differs between processors, so only the jump is asserted).
    With the shipped gamma1 L is the continuous gamma2 r + gamma3 over the whole approach, from
    beyond every Monte Carlo start (nominal range + 6 sigma per axis) down to the dock."""
    geo = load_config(**scenario_overrides("geo"))
    c, m = geo.constraints, geo.mission
    far = m.nominal_distance_km + 6.0 * m.mc_sigma_km * math.sqrt(3.0)
    pred = Predictor.from_config(geo)
    x83 = sample_start(pred, 83)
    assert np.linalg.norm(x83[:3] - pred.orbit.state(0.0)[:3]) < far

    # gamma1 = 1 km: none just outside, gamma2 (1 km) + gamma3 = 1.01 m/s just inside.
    old = geo.replace(**{"constraints.gamma1_km": 1.0})
    outside, inside = _speed_limit(old, np.array([1.0 + 1e-9, 1.0 - 1e-9]))
    assert outside == math.inf
    assert inside == pytest.approx(c.gamma2_per_s * 1.0 + c.gamma3_kmps, rel=1e-6)
    assert inside == pytest.approx(1.01e-3, rel=1e-6)    # the limit start 83 met at 1 km
    # the plant's crossing speed of start 83 (1.03 m/s) is free outside and a violation inside
    assert 1.03e-3 < outside and 1.03e-3 - inside == pytest.approx(2e-5, rel=1e-3)

    # Shipped gamma1: one affine limit, no jump, from beyond every start down to the dock range.
    assert c.gamma1_km >= far
    r = np.geomspace(m.dock_distance_km, far, 4001)
    limit = _speed_limit(geo, r)
    assert np.all(np.isfinite(limit))
    np.testing.assert_allclose(limit, c.gamma2_per_s * r + c.gamma3_kmps, rtol=1e-9, atol=1e-15)
    assert np.all(np.abs(np.diff(limit)) <= c.gamma2_per_s * np.diff(r) * (1 + 1e-9) + 1e-15)


def test_models_are_per_scenario_and_side(tmp_path: Path, capsys) -> None:
    """A family resolves to <models_dir>/<family>[-ahead]; a model whose card names another
    scenario or side is refused unless learned.foreign_model, and then the mission says so."""
    cfg = load_config(**{"scenario.models_dir": str(tmp_path), "mission.approach": "ahead"})
    assert scenario_model_dir(str(tmp_path), "cikan", "ahead") == tmp_path / "cikan-ahead"
    shutil.copytree(MODELS_DIR / "cikan", tmp_path / "cikan-ahead")   # a behind model, misplaced
    with pytest.raises(ModelFileError, match="trained for scenario 'paper', approach 'behind'"):
        make_governor("cikan", cfg)
    gov = make_governor("cikan", cfg.replace(**{"learned.foreign_model": True}))
    assert gov.foreign == "trained for scenario 'paper', approach 'behind', not scenario 'paper', approach 'ahead'"
    assert main(["mission", "--offline", "--json", "--seed", "1", "--governor", "cikan",
                 "--set", f"scenario.models_dir={tmp_path}", "--set", "mission.approach=ahead",
                 "--set", "learned.foreign_model=true"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["foreign_model"] == gov.foreign
    assert out["violations"] == 0 and out["success"]


def test_robust_verify_flies_its_own_models(tmp_path: Path) -> None:
    """Under robust Verify a family resolves to <models_dir>/<family>[-ahead]-robust and the
    campaign's shipped list holds only those; with no robust model it is refused (naming the make
    target), unless learned.foreign_model, and then the nominal model flies, foreign."""
    from cikan_ros.learn.modelfile import check_dataset_labels, flown_model_dir
    from cikan_ros.learn.errors import DatasetError
    from cikan_ros.registry import shipped_names

    assert scenario_model_dir(str(tmp_path), "relu", "ahead", True) == tmp_path / "relu-ahead-robust"
    cfg = load_config(**{"scenario.models_dir": str(tmp_path), "tsg.robust": True})
    shutil.copytree(MODELS_DIR / "cikan", tmp_path / "cikan")   # nominal labels only
    assert shipped_names(cfg) == ["conventional"]
    assert shipped_names(cfg.replace(**{"tsg.robust": False})) == ["conventional", "cikan"]
    with pytest.raises(ModelFileError, match=r"no cikan model of robust Verify .* \(make scenario-models SCENARIO=paper VERIFY=robust TRUTH=nominal\)"):
        make_governor("cikan", cfg)
    allowed = cfg.replace(**{"learned.foreign_model": True})
    assert flown_model_dir(allowed, "cikan") == tmp_path / "cikan"
    assert make_governor("cikan", allowed).foreign.startswith("trained on labels of nominal Verify")
    # A model of the ancillary tube's labels (the shipped robust CIKAN) flown under the ball tube is
    # another Verify's: refused naming the tube and the settings the ball tube has not, flown
    # foreign when allowed; a model of the ball tube's labels under the ancillary tube likewise.
    shipped = load_config(**{**truth_overrides("realistic"), "tsg.robust": True})
    assert make_governor("cikan", shipped).foreign is None
    ball = shipped.replace(**{"tsg.tube": "ball"})
    with pytest.raises(ModelFileError, match=r"ancillary tube\), not of .*\(differs: .*tsg\.tube"):
        make_governor("cikan", ball)
    foreign = make_governor("cikan", ball.replace(**{"learned.foreign_model": True})).foreign
    assert foreign.endswith("tsg.ancillary_r_diag, tsg.tube)"), foreign
    # GEO's shipped robust models (both sides) are of the ancillary tube's labels, which GEO flies:
    # `--governor shipped` lists them; under the ball tube they are another Verify's, left out
    # saying why, unless foreign models are allowed.
    from cikan_ros.registry import shipped_models
    geo = load_config(**{**scenario_overrides("geo"), **truth_overrides("realistic"), "tsg.robust": True})
    assert geo.tsg.tube == "ancillary"
    assert shipped_models(geo) == {"cikan": None, "relu": None}
    assert shipped_models(geo.replace(**{"mission.approach": "ahead"})) == {"cikan": None, "relu": None}
    assert shipped_names(geo) == ["conventional", "cikan", "relu"]
    geo_ball = geo.replace(**{"tsg.tube": "ball"})
    why = shipped_models(geo_ball)
    assert sorted(why) == ["cikan", "relu"] and all(r.startswith("trained on labels of robust Verify") and
                                                    "tsg.tube" in r for r in why.values()), why
    assert shipped_names(geo_ball) == ["conventional"]
    assert shipped_names(geo_ball.replace(**{"learned.foreign_model": True})) == ["conventional", "cikan", "relu"]
    card = json.loads((MODELS_DIR / "cikan-robust" / "card.json").read_text())
    card["config"] = {**card["config"], "tsg.tube": "ball"}
    assert label_mismatch(card, shipped.flat()).endswith("tsg.ancillary_r_diag, tsg.tube)")
    # A dataset of nominal labels does not train a robust model, and the other way round.
    meta = {"config": cfg.replace(**{"tsg.robust": False}).flat()}
    check_dataset_labels(meta, "d.parquet", cfg.replace(**{"tsg.robust": False}).flat())
    with pytest.raises(DatasetError, match="holds labels of nominal Verify .* not of robust Verify"):
        check_dataset_labels(meta, "d.parquet", cfg.flat())
