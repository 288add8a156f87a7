"""Configuration: the shipped YAML equals the built-in defaults; bad values name themselves."""

from __future__ import annotations

import math

import pytest
import yaml

from cikan_ros.config import DEFAULT_CONFIG_PATH, Config, config_from_flat, load_config
from cikan_ros.errors import ConfigError


def test_shipped_file_is_ros_params_format_and_equals_defaults():
    doc = yaml.safe_load(DEFAULT_CONFIG_PATH.read_text())
    assert set(doc) == {"/**"} and "ros__parameters" in doc["/**"]
    assert load_config() == Config()


def test_flat_round_trip():
    cfg = load_config()
    assert config_from_flat(cfg.flat()) == cfg
    assert cfg.flat()["tsg.tolerance_s"] == 1e-5
    assert cfg.replace(**{"tsg.tolerance_s": 1e-4}).tsg.tolerance_s == 1e-4


@pytest.mark.parametrize("name, value, match", [
    ("orbit.e", 1.2, "orbit.e"),
    ("orbit.a_km", math.nan, "orbit.a_km"),
    ("orbit.a_km", 7000.0, "inside the Earth"),
    ("control.q_diag", [1.0, 2.0], "control.q_diag"),
    ("control.grid_deg", 0.7, "control.grid_deg"),
    ("tsg.rk4_substeps", 2.5, "tsg.rk4_substeps"),
    ("tsg.update_period_s", 65.0, "whole multiple"),
    ("tsg.tolerance_s", 1e-12, "nanoseconds"),
    ("constraints.los_half_angle_deg", 95.0, "los_half_angle_deg"),
    ("mission.duration_s", -1.0, "mission.duration_s"),
    ("mission.plant_substeps", "ten", "integer"),
    ("orbit.epoch_utc", "yesterday", "ISO 8601"),
    ("learned.ladder", [0.0, 0.03], "strictly decreasing"),
    ("learned.ladder", [1.0, 0.0], "learned.ladder"),
    ("learned.ladder", [], "learned.ladder"),
    ("learned.probe_every", 0, "learned.probe_every"),
    ("learned.search_rule", "bisect", "learned.search_rule"),
    ("learned.hold_test", 0.0, "learned.hold_test"),
    ("learned.search_ladder", [2.0, -1.0], "learned.search_ladder"),
    ("learned.search_depth", 31, "learned.search_depth"),
])
def test_invalid_values_are_named(name, value, match):
    with pytest.raises(ConfigError, match=match):
        load_config(**{name: value})


def test_unknown_parameter_and_bad_files(tmp_path):
    with pytest.raises(ConfigError, match="unknown configuration parameter 'tsg.tolerance'"):
        load_config(**{"tsg.tolerance": 1.0})
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("/**: [unclosed")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)
    bad.write_text("/**:\n  other: 1\n")
    with pytest.raises(ConfigError, match="ros__parameters"):
        load_config(bad)


def test_partial_file_overrides_defaults(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("/**:\n  ros__parameters:\n    tsg:\n      update_period_s: 120.0\n")
    cfg = load_config(f)
    assert cfg.tsg.update_period_s == 120.0 and cfg.orbit == Config().orbit


def test_an_empty_list_read_back_from_a_ros_params_file_is_empty():
    """A ROS params file cannot type an empty list (rcl reads `[]` as unset, None): a list key
    whose default is empty reads None as empty; one whose default is not stays an error."""
    from cikan_ros.config import config_from_flat

    assert config_from_flat({"tsg.ancillary_bands_km": None, "tsg.ancillary_bands_r": None}).tsg.ancillary_bands_km == ()
    with pytest.raises(ConfigError, match="tsg.ancillary_r_diag"):
        config_from_flat({"tsg.ancillary_r_diag": None})
