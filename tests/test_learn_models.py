"""Contract tests of the networks and model files: parameter counts, torch = numpy forward,
save -> load identical outputs, clear errors on missing/truncated/corrupt/mismatched files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from cikan_ros.learn.arch import Arch, NumpyNet
from cikan_ros.learn.errors import ModelFileError
from cikan_ros.learn.modelfile import CARD, WEIGHTS, load_model, save_model
from cikan_ros.learn.models import TimeShiftNet

ARCHS = [
    Arch("cikan", width=8, layers=3, grid=5),
    Arch("cikan", width=6, layers=2, grid=7, hidden_norm=False, features="eci"),
    Arch("grbf", width=8, layers=3, grid=6, h=0.7),
    Arch("rswaf", width=8, layers=3, grid=6),
    Arch("relu", width=16, layers=4),
    Arch("gelu", width=16, layers=3),
]


def closed_form_params(a: Arch) -> int:
    """Parameter counts written out per family (independent of Arch.tensor_shapes)."""
    n_in, n, ell, g = 12, a.width, a.layers, a.grid
    w = [n_in] + [n] * (ell - 1) + [1]
    pairs = list(zip(w[:-1], w[1:]))
    if a.family == "cikan":   # base β (O·I) + coefficients c (O·I·(G+k)) + scaler α (O·I)
        total = sum(o * i * (g + a.order + 2) for i, o in pairs)
    elif a.family in ("grbf", "rswaf"):   # θ (O·I·G)
        total = sum(o * i * g for i, o in pairs)
    else:   # W (O·I) + b (O)
        return sum(o * i + o for i, o in pairs)
    if a.hidden_norm:   # LayerNorm weight and bias on the inputs of layers 1 .. ℓ-1
        total += 2 * n * (ell - 1)
    return total


def _net(a: Arch, seed: int = 0) -> TimeShiftNet:
    torch.manual_seed(seed)
    net = TimeShiftNet(a)
    rng = np.random.default_rng(seed)
    net.set_normalisation(rng.normal(size=12), rng.uniform(0.5, 2.0, 12), 0.3, 1.7)
    return net


@pytest.mark.parametrize("a", ARCHS, ids=lambda a: f"{a.family}-{a.width}x{a.layers}")
def test_parameter_counts_equal_closed_forms(a: Arch) -> None:
    net = _net(a)
    assert net.n_params() == a.n_params() == closed_form_params(a)
    n2l = a.width ** 2 * a.layers
    assert a.complexity() == (n2l * (a.grid + 3) if a.is_kan else n2l)


def test_paper_complexities() -> None:
    assert Arch("cikan", 128, 5, grid=17).complexity() == 1_638_400
    assert Arch("grbf", 32, 6, grid=17).complexity() == 122_880
    assert Arch("rswaf", 64, 6, grid=17).complexity() == 491_520
    assert Arch("relu", 2048, 5).complexity() == 20_971_520
    assert Arch("gelu", 1024, 5).complexity() == 5_242_880


@pytest.mark.parametrize("a", ARCHS, ids=lambda a: f"{a.family}-{a.width}x{a.layers}")
def test_numpy_forward_equals_torch(a: Arch) -> None:
    net = _net(a).double()
    z = np.random.default_rng(1).normal(size=(200, 12)) * 3.0   # many inputs outside the grid
    with torch.no_grad():
        ref = net(torch.tensor(z)).numpy()
    sd = {k: v.numpy() for k, v in net.state_dict().items()}
    npn = NumpyNet(a, sd)
    np.testing.assert_allclose(npn.forward(z), ref, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose([npn.forward_one(r) for r in z], ref, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("a", ARCHS, ids=lambda a: f"{a.family}-{a.width}x{a.layers}")
def test_save_load_identical_outputs(a: Arch, tmp_path: Path) -> None:
    net = _net(a, seed=3)
    save_model(tmp_path / "m", a, net.state_dict(), {"name": "t"})
    m = load_model(tmp_path / "m")
    assert m.arch == a
    back = TimeShiftNet(m.arch)
    back.load_state_dict({k: torch.from_numpy(v).to(net.state_dict()[k].dtype)
                          for k, v in m.tensors.items()})
    z = torch.randn(64, 12)
    with torch.no_grad():
        assert torch.equal(net(z), back(z))
    # Through the file the numpy path sees exactly the saved float32 weights.
    npn = NumpyNet(m.arch, m.tensors)
    with torch.no_grad():
        ref = net.double()(z.double()).numpy()
    np.testing.assert_allclose(npn.forward(z.double().numpy()), ref, rtol=1e-12, atol=1e-12)
    # A file path inside the directory resolves too.
    assert load_model(tmp_path / "m" / CARD).arch == a


def _saved(tmp_path: Path) -> Path:
    a = ARCHS[0]
    return save_model(tmp_path / "m", a, _net(a).state_dict(), {"name": "t"})


def test_truncated_weights_file_is_a_clear_error(tmp_path: Path) -> None:
    d = _saved(tmp_path)
    raw = (d / WEIGHTS).read_bytes()
    (d / WEIGHTS).write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ModelFileError, match="truncated, corrupt or replaced"):
        load_model(d)


def test_truncated_file_with_matching_hash_fails_on_parse(tmp_path: Path) -> None:
    d = _saved(tmp_path)
    raw = (d / WEIGHTS).read_bytes()
    (d / WEIGHTS).write_bytes(raw[:40])
    card = json.loads((d / CARD).read_text())
    from cikan_ros.learn.modelfile import sha256_file

    card["weights_sha256"] = sha256_file(d / WEIGHTS)
    (d / CARD).write_text(json.dumps(card))
    with pytest.raises(ModelFileError, match="not a readable safetensors file"):
        load_model(d)


def test_mismatched_architecture_is_a_clear_error(tmp_path: Path) -> None:
    d = _saved(tmp_path)
    card = json.loads((d / CARD).read_text())
    card["architecture"]["width"] = 9
    (d / CARD).write_text(json.dumps(card))
    with pytest.raises(ModelFileError, match="has shape"):
        load_model(d)
    card["architecture"]["family"] = "grbf"
    card["architecture"]["width"] = 8
    (d / CARD).write_text(json.dumps(card))
    with pytest.raises(ModelFileError, match="do not match the grbf architecture"):
        load_model(d)


def test_missing_and_corrupt_cards_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(ModelFileError, match="not found"):
        load_model(tmp_path / "nowhere")
    d = _saved(tmp_path)
    norm_card = json.loads((d / CARD).read_text())
    norm_card["normalisation"]["feature_mean"][0] += 1.0
    (d / CARD).write_text(json.dumps(norm_card))
    with pytest.raises(ModelFileError, match="normalisation feature_mean differs"):
        load_model(d)
    (d / CARD).write_text("{not json")
    with pytest.raises(ModelFileError, match="not valid JSON"):
        load_model(d)
    (d / CARD).unlink()
    with pytest.raises(ModelFileError, match="card missing"):
        load_model(d)


def test_governor_factory_reports_a_bad_model(tmp_path: Path, cfg, predictor) -> None:
    from cikan_ros.governor import make_governor

    d = _saved(tmp_path)
    (d / WEIGHTS).write_bytes(b"\x00" * 10)
    with pytest.raises(ModelFileError, match="truncated, corrupt or replaced"):
        make_governor(str(d), cfg, predictor)
    with pytest.raises(ModelFileError, match="model directory not found"):
        make_governor(str(tmp_path / "absent"), cfg, predictor)


def test_cli_reports_a_bad_file_without_traceback(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from cikan_ros.cli import main

    bad = tmp_path / "labels.parquet"
    bad.write_bytes(b"PAR1 not really")
    assert main(["train", "--model", "cikan", "--data", str(bad), "--out", str(tmp_path / "m")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.startswith("cikan train: error: dataset") and "not a readable Parquet file" in err
