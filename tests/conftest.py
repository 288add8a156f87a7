"""Shared fixtures: one configuration and one predictor (gain table computed once per session)."""

from __future__ import annotations

import pytest

from cikan_ros.config import Config, load_config
from cikan_ros.tsg import Predictor


@pytest.fixture(scope="session")
def cfg() -> Config:
    return load_config()


@pytest.fixture(scope="session")
def predictor(cfg: Config) -> Predictor:
    return Predictor.from_config(cfg)
