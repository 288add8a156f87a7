"""The trained models shipped in models/: they load with every check, are small, state their
data and budget, and fly the nominal mission with zero violations."""

from __future__ import annotations

import pytest

from cikan_ros.registry import LEARNED_NAMES, make_governor
from cikan_ros.learn.modelfile import MODELS_DIR, load_model
from cikan_ros.mission import nominal_start, run_mission


def test_models_directory_is_under_30_mb() -> None:
    total = sum(p.stat().st_size for p in MODELS_DIR.rglob("*") if p.is_file())
    assert total < 30 * 2**20


@pytest.mark.parametrize("name", LEARNED_NAMES)
def test_shipped_model_card(name: str) -> None:
    m = load_model(name)
    assert m.arch.family == name
    card = m.card
    assert card["dataset"]["train_labels_used"] >= 200_000
    assert card["dataset"]["split_labels"]["train"] == card["dataset"]["train_labels_used"]
    assert {"train", "val", "test"} <= set(card["losses"])
    assert card["training"]["cpu_budget"]["wall_s"] > 0
    assert card["parameters"]["trainable"] == m.arch.n_params()
    assert card["versions"]["torch"].split("+")[0] == "2.13.0"


@pytest.mark.parametrize("name", LEARNED_NAMES)
def test_shipped_governor_flies_the_nominal_mission(name: str, cfg, predictor) -> None:
    gov = make_governor(name, cfg, predictor)
    m = run_mission(gov, nominal_start(predictor)).metrics()
    assert m["violations"] == 0
    assert m["success"], m
