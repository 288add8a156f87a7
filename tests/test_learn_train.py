"""Training and tuning: resume continues exactly, early stopping, the card's contents, and two
`cikan tune` processes sharing one new SQLite study."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from cikan_ros.learn.arch import Arch
from cikan_ros.learn.dataset import DatasetSpec, generate, write_parquet
from cikan_ros.learn.modelfile import load_model
from cikan_ros.learn.train import TrainConfig, load_data, train


@pytest.fixture(scope="module")
def data_path(cfg, predictor, tmp_path_factory) -> Path:
    from cikan_ros.learn import dataset

    dataset._PREDICTORS[json.dumps(cfg.flat(), sort_keys=True)] = predictor
    df, meta = generate(cfg, 300, DatasetSpec(seed=7, val_fraction=0.25, test_fraction=0.25),
                        progress=False)
    assert set(df["split"]) == {"train", "val", "test"}
    return write_parquet(df, meta, tmp_path_factory.mktemp("data") / "labels.parquet")


def test_resume_continues_exactly(data_path: Path, tmp_path: Path) -> None:
    data = load_data(data_path)
    arch = Arch("cikan", 6, 2, grid=4)
    cfg = dict(epochs=4, batch=64, lr=3e-3, lr_inf=3e-5, patience=10, seed=2)
    straight = train(arch, data, TrainConfig(**cfg), tmp_path / "a", tmp_path / "ck_a", progress=False)
    train(arch, data, TrainConfig(**{**cfg, "max_minutes": 1e-9}), None, tmp_path / "ck_b",
          progress=False)   # stops after one epoch (wall budget)
    resumed = train(arch, data, TrainConfig(**cfg), tmp_path / "b", tmp_path / "ck_b", resume=True,
                    progress=False)
    assert resumed["training"]["epochs_run"] == 4
    h_a = straight["training"]["history"]
    h_b = resumed["training"]["history"]
    assert [h["val_loss"] for h in h_a] == [h["val_loss"] for h in h_b]
    for (k, v), (k2, v2) in zip(straight["net"].state_dict().items(), resumed["net"].state_dict().items()):
        assert k == k2 and torch.equal(v, v2)
    card = load_model(tmp_path / "b").card
    for s in ("train", "val", "test"):
        assert card["losses"][s]["loss"] > 0 and card["losses"][s]["labels"] > 0
    assert card["dataset"]["labels"] == 300 and card["dataset"]["seed"] == 7
    assert card["training"]["cpu_budget"]["wall_s"] > 0
    assert card["versions"]["torch"] == torch.__version__
    assert card["parameters"]["trainable"] == arch.n_params()
    # the labels' Verify, named in the card: this dataset's nominal Verify and paper controller
    assert card["labels"] == {"tsg.robust": False, "control.q_diag": [10.0, 10.0, 10.0, 1.0, 1.0, 1.0],
                              "control.r_diag": [1.0, 1.0, 1.0]}


def test_losses_in_the_card_are_the_papers_definition(data_path: Path, tmp_path: Path) -> None:
    data = load_data(data_path)
    res = train(Arch("relu", 16, 2), data, TrainConfig(epochs=2, batch=64, theta_c=2.5),
                tmp_path / "m", None, progress=False)
    m = load_model(tmp_path / "m")
    from cikan_ros.learn.arch import NumpyNet

    net = NumpyNet(m.arch, m.tensors)
    s = data.splits["val"]
    err = s.y - net.forward(net.normalise(s.feats))
    ref = np.mean(err ** 2) + 2.5 * np.mean(np.maximum(err, 0) ** 2)
    assert res["losses"]["val"]["loss"] == pytest.approx(ref, rel=1e-5)
    assert m.card["losses"]["theta_c"] == 2.5


def test_early_stopping(data_path: Path) -> None:
    data = load_data(data_path)
    res = train(Arch("relu", 8, 2), data, TrainConfig(epochs=50, batch=64, lr=1e-9, lr_inf=1e-10,
                                                      patience=2), None, progress=False)
    assert res["training"]["stop_reason"] == "early stopping"
    assert res["training"]["epochs_run"] < 50


def test_two_tune_processes_share_one_new_sqlite_study(data_path: Path, tmp_path: Path) -> None:
    import optuna

    url = f"sqlite:///{tmp_path / 'study.sqlite3'}"
    cmd = [sys.executable, "-m", "cikan_ros.cli", "tune", "--model", "grbf", "--trials", "1",
           "--storage", url, "--data", str(data_path), "--epochs", "2", "--max-train", "0", "--json"]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    for p, (out, err) in zip(procs, outs):
        assert p.returncode == 0, err
    study = optuna.load_study(study_name="cikan-tsg-grbf", storage=url)
    assert len(study.trials) == 2
    assert all(t.state.name in ("COMPLETE", "PRUNED") for t in study.trials)
    assert len({t.number for t in study.trials}) == 2


def test_cli_tune_then_train_from_the_study(data_path: Path, tmp_path: Path,
                                            capsys: pytest.CaptureFixture) -> None:
    from cikan_ros.cli import main

    url = f"sqlite:///{tmp_path / 's.sqlite3'}"
    assert main(["tune", "--model", "cikan", "--trials", "2", "--storage", url, "--data",
                 str(data_path), "--epochs", "2", "--max-train", "0", "--seed", "1", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["trials"] == 2 and "best_params" in summary
    out = tmp_path / "m"
    assert main(["train", "--model", "cikan", "--data", str(data_path), "--out", str(out),
                 "--study", url, "--epochs", "2", "--quiet", "--json",
                 "--checkpoint-dir", str(tmp_path / "ck")]) == 0
    m = load_model(out)
    best = summary["best_params"]
    assert (m.arch.width, m.arch.layers, m.arch.grid) == (best["width"], best["layers"], best["grid"])
    assert m.card["losses"]["theta_c"] == pytest.approx(best["theta_c"])
    assert m.card["tuning"]["trials"] == 2


def test_tau_prev_network_trains_and_flies(data_path: Path, tmp_path: Path, predictor) -> None:
    """The "vnb-prev" feature set end to end: the 13th input is ln|tau_{k-1}| of each label,
    the model file round-trips with 13 normalisation entries, and its governor feeds tau_prev
    (same proposal as the batch features of the same state)."""
    from cikan_ros.learn.dataset import read_parquet
    from cikan_ros.learn.features import features
    from cikan_ros.learn.governor import LearnedGovernor
    from cikan_ros.tsg import quantise_shift

    data = load_data(data_path, "vnb-prev")
    df, _ = read_parquet(data_path)
    train_rows = df[df["split"] == "train"]
    np.testing.assert_array_equal(data.splits["train"].feats[:, 12],
                                  np.log(-train_rows["tau_prev_s"].to_numpy()))
    arch = Arch("cikan", 6, 2, grid=4, features="vnb-prev", n_in=13)
    train(arch, data, TrainConfig(epochs=2, batch=64), tmp_path / "m", None, progress=False)
    m = load_model(tmp_path / "m")
    assert m.arch.n_in == 13 and m.tensors["feature_mean"].shape == (13,)
    gov = LearnedGovernor.from_model(m, predictor)
    row = train_rows.iloc[0]
    x_d = row[[f"xd{i}" for i in range(6)]].to_numpy(dtype=float)
    x_c = row[[f"xc{i}" for i in range(6)]].to_numpy(dtype=float)
    z = gov.net.normalise(features(x_d, x_c, "vnb-prev", row["tau_prev_s"]))
    expected = quantise_shift(-np.exp(gov.net.forward(z[None, :])[0]))
    assert gov.proposal(x_d, x_c, float(row["tau_prev_s"])) == expected
    rec = gov.update(x_d, x_c, float(row["t_s"]), float(row["tau_prev_s"]))
    assert rec.tau_s == row["tau_prev_s"] or predictor.verify(x_d, float(row["t_s"]), rec.tau_s)


def test_log_ratio_network_learns_the_step_and_flies(data_path: Path, tmp_path: Path, predictor) -> None:
    """Target "log-ratio": the labels are y = ln(|tau*| / |tau_{k-1}|) (golden: from the
    dataset's columns), y + offset = ln|tau*|, the card names the target, and the governor's
    ln|tau| is ln|tau_{k-1}| plus the torch network's output at the same state."""
    from cikan_ros.learn.dataset import read_parquet
    from cikan_ros.learn.features import features
    from cikan_ros.learn.governor import LearnedGovernor

    data = load_data(data_path, "vnb-prev", "log-ratio")
    df, _ = read_parquet(data_path)
    rows = df[df["split"] == "train"]
    tau, prev = rows["tau_star_s"].to_numpy(), rows["tau_prev_s"].to_numpy()
    s = data.splits["train"]
    np.testing.assert_allclose(s.y, np.log(tau / prev), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(s.offset, np.log(-prev))
    np.testing.assert_allclose(s.y + s.offset, np.log(-tau), rtol=0, atol=1e-12)
    assert (s.y <= 1e-12).all()   # pi* lies between tau_{k-1} and 0: no step away from 0

    arch = Arch("relu", 16, 2, features="vnb-prev", target="log-ratio")
    res = train(arch, data, TrainConfig(epochs=2, batch=64), tmp_path / "m", None, progress=False)
    m = load_model(tmp_path / "m")
    assert m.card["architecture"]["target"] == "log-ratio" and m.arch.relative
    assert "ln|tau_{k-1}|" in m.card["losses"]["definition"]
    gov = LearnedGovernor.from_model(m, predictor)
    net = res["net"]
    for _, row in rows.head(5).iterrows():
        x_d = row[[f"xd{i}" for i in range(6)]].to_numpy(dtype=float)
        x_c = row[[f"xc{i}" for i in range(6)]].to_numpy(dtype=float)
        z = torch.from_numpy(net.normalise(features(x_d, x_c, "vnb-prev", row["tau_prev_s"]))[None, :]).float()
        with torch.no_grad():
            expected = float(np.log(-row["tau_prev_s"])) + float(net(z)[0])
        assert gov.log_shift(x_d, x_c, float(row["tau_prev_s"])) == pytest.approx(expected, abs=1e-5)
    # tau_{k-1} = 0 gives no usable proposal (ln 0 = -inf), not an exception
    assert np.isnan(gov.proposal(x_d, x_c, 0.0))


def test_log_ratio_needs_tau_prev_in_the_features(data_path: Path, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture) -> None:
    from cikan_ros.cli import main
    from cikan_ros.learn.errors import ModelFileError

    with pytest.raises(ModelFileError, match="log-ratio.*vnb-prev"):
        Arch("relu", 16, 2, target="log-ratio")
    with pytest.raises(ModelFileError, match="log-ratio.*vnb-prev"):
        load_data(data_path, "vnb", "log-ratio")
    with pytest.raises(ModelFileError, match="target must be one of"):
        Arch("relu", 16, 2, features="vnb-prev", target="ln-tau")
    assert main(["train", "--model", "relu", "--data", str(data_path), "--target", "log-ratio",
                 "--epochs", "1", "--out", str(tmp_path / "m"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("\n") == 1
    assert err.startswith("cikan train: error:") and "log-ratio" in err and "vnb-prev" in err
    assert not (tmp_path / "m").exists()


def test_models_page_tables_come_from_cards_and_data(data_path: Path, tmp_path: Path) -> None:
    """`cikan models`: one row per model directory from its card; the breakdown's groups hold
    the stated shares of the split and their losses are the paper's loss on those labels."""
    from cikan_ros.learn.arch import NumpyNet
    from cikan_ros.learn.cards import loss_breakdown, models_page, shipped_models
    from cikan_ros.learn.dataset import read_parquet
    from cikan_ros.learn.features import features
    from cikan_ros.learn.loss import cinn_log_loss_np

    data = load_data(data_path)
    for name, features_kind in (("a", "vnb"), ("b", "vnb-prev")):
        train(Arch("relu", 8, 2, features=features_kind),
              load_data(data_path, features_kind) if features_kind != "vnb" else data,
              TrainConfig(epochs=1, batch=64), tmp_path / "models" / name, None, progress=False)
    models = shipped_models(tmp_path / "models")
    page, meta = models_page("# intro\n", data_path, "val", tmp_path / "models")
    assert meta["models"] == 2 and page.startswith("# intro")
    assert "| a | paper, behind, nominal | vnb |" in page and "| b | paper, behind, nominal | vnb-prev |" in page
    table = loss_breakdown(models, data_path, "val")
    rows = {line.split(" | ")[0].lstrip("| "): line for line in table.splitlines() if line.startswith("| ")}
    df, _ = read_parquet(data_path)
    val = df[df["split"] == "val"]
    tau, prev = val["tau_star_s"].to_numpy(), val["tau_prev_s"].to_numpy()
    y = np.log(-tau)
    m = models[0]
    net = NumpyNet(m.arch, m.tensors)
    pred = net.forward(net.normalise(features(val[[f"xd{i}" for i in range(6)]].to_numpy(),
                                              val[[f"xc{i}" for i in range(6)]].to_numpy(), "vnb")))
    hold = np.abs(tau - prev) <= 1e-4
    assert rows["all"].split(" | ")[2] == f"{cinn_log_loss_np(pred, y):.3e}"
    assert rows["move"].split(" | ")[1] == f"{np.mean(~hold):.1%}"
    if (~hold).any():
        assert rows["move"].split(" | ")[2] == f"{cinn_log_loss_np(pred[~hold], y[~hold]):.3e}"


def test_models_page_keeps_the_breakdowns_of_datasets_not_given(data_path: Path, tmp_path: Path) -> None:
    """`cikan models --data D --out PAGE` over a page that has breakdowns of other labels (here
    LEO's from ahead, its dataset not on the machine): D's breakdown is computed afresh and
    replaces its old one, the other is kept as it was, in scenario order, and the footer names
    what was kept; without an existing page nothing is kept."""
    from cikan_ros.learn.cards import loss_breakdown, models_page, shipped_models

    train(Arch("relu", 8, 2), load_data(data_path), TrainConfig(epochs=1, batch=64), tmp_path / "models" / "a",
          None, progress=False)
    fresh = loss_breakdown(shipped_models(tmp_path / "models"), data_path, "val")
    other = ("Split `val` of `labels.parquet` (scenario leo, approach ahead, robust Verify; 12 labels); "
             "loss = the paper's definition at θ_c = 1.\n\n| labels | share of split | leo/x |\n|---|---|---|\n"
             "| all | 100.0% | 1.000e-01 |\n")
    stale = fresh.replace("| all | 100.0% |", "| all | 99.9% |")
    page_path = tmp_path / "README.md"
    page_path.write_text("# intro\n\n## Loss by |τ*| band and by hold/move update\n\n" + stale + "\n" + other
                         + "\n*Generated by `cikan models`; do not edit the tables by hand.*\n")
    page, _ = models_page("# intro\n", data_path, "val", tmp_path / "models", out=page_path)
    assert fresh in page and stale not in page and other in page
    assert page.index(other) < page.index(fresh)            # scenario order: leo before paper
    assert "the breakdowns of leo ahead robust kept from the page before" in page.splitlines()[-1]
    page, _ = models_page("# intro\n", data_path, "val", tmp_path / "models", out=tmp_path / "new.md")
    assert other not in page and "kept" not in page


def test_several_datasets_are_concatenated_split_by_split(data_path: Path) -> None:
    """``--data A B``: each split is A's labels then B's (each label keeps its file's split);
    the metadata names both files and counts all labels."""
    one = load_data(data_path)
    two = load_data([data_path, data_path])
    for s in ("train", "val", "test"):
        np.testing.assert_array_equal(two.splits[s].y, np.concatenate([one.splits[s].y] * 2))
        np.testing.assert_array_equal(two.splits[s].feats, np.concatenate([one.splits[s].feats] * 2))
    assert two.meta["labels"] == 2 * one.meta["labels"]
    assert [f["file"] for f in two.meta["files"]] == [data_path.name] * 2
    assert two.path == f"{data_path.name}+{data_path.name}"


def test_tune_then_train_a_scenario_given_as_a_file(predictor, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture) -> None:
    """The pipeline for a custom scenario: `cikan tune --scenario FILE` creates its study under
    the one naming rule and `cikan train --scenario FILE --study URL` finds it (it looked for the
    paper's name before). A scenario file named my_orbit.yaml is scenario 'my_orbit'; the study
    is cikan-tsg-grbf-my_orbit-behind, written out here from the documented rule."""
    import optuna

    from cikan_ros.cli import main
    from cikan_ros.config import load_config, scenario_overrides
    from cikan_ros.learn import dataset

    scenario = tmp_path / "my_orbit.yaml"   # the paper's orbit under another name: same labels
    scenario.write_text("/**:\n  ros__parameters:\n    scenario:\n"
                        f"      models_dir: \"{tmp_path / 'models'}\"\n")
    mine = load_config(**scenario_overrides(str(scenario)))
    assert mine.scenario.name == "my_orbit"
    dataset._PREDICTORS[json.dumps(mine.flat(), sort_keys=True)] = predictor
    df, meta = generate(mine, 120, DatasetSpec(seed=3, val_fraction=0.25, test_fraction=0.25), progress=False)
    data = write_parquet(df, meta, tmp_path / "labels.parquet")
    url = f"sqlite:///{tmp_path / 's.sqlite3'}"
    assert main(["tune", "--scenario", str(scenario), "--model", "grbf", "--trials", "1", "--storage", url,
                 "--data", str(data), "--epochs", "1", "--max-train", "0", "--json"]) == 0
    assert optuna.get_all_study_names(url) == ["cikan-tsg-grbf-my_orbit-behind"]
    capsys.readouterr()
    assert main(["train", "--scenario", str(scenario), "--model", "grbf", "--data", str(data), "--study", url,
                 "--epochs", "1", "--quiet", "--json", "--checkpoint-dir", str(tmp_path / "ck")]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert Path(out["out"]) == tmp_path / "models" / "grbf"   # the scenario's own models directory
    assert load_model(out["out"]).card["tuning"]["study"] == "cikan-tsg-grbf-my_orbit-behind"
    # Flying it from ahead, where no model is: the hint names the make target that trains one.
    assert main(["mission", "--offline", "--scenario", str(scenario), "--governor", "grbf",
                 "--set", "mission.approach=ahead"]) == 2
    err = capsys.readouterr().err
    assert "make scenario-models SCENARIO=<your my_orbit scenario file> APPROACH=ahead" in err
