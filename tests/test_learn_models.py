"""Contract tests of the networks and model files: parameter counts, torch (float64) = compiled
inference forward for every family and for the shipped models, save -> load identical outputs,
clear errors on missing/truncated/corrupt/mismatched files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from cikan_ros.registry import LEARNED_NAMES
from cikan_ros.learn.arch import Arch, NumpyNet, network_forward
from cikan_ros.learn.errors import ModelFileError
from cikan_ros.learn.modelfile import CARD, WEIGHTS, load_model, save_model
from cikan_ros.learn.models import TimeShiftNet

ARCHS = [
    Arch("cikan", width=8, layers=3, grid=5),
    Arch("cikan", width=6, layers=2, grid=7, hidden_norm=False, features="eci"),
    Arch("cikan", width=7, layers=3, grid=4, order=1),
    Arch("cikan", width=7, layers=3, grid=6, order=2, hidden_norm=False),
    Arch("cikan", width=5, layers=4, grid=9, order=5, grid_range=2.0),
    Arch("cikan", width=6, layers=3, grid=3, order=5, hidden_norm=False),
    Arch("grbf", width=8, layers=3, grid=6, h=0.7),
    Arch("grbf", width=8, layers=3, grid=5, hidden_norm=False),
    Arch("rswaf", width=8, layers=3, grid=6),
    Arch("rswaf", width=9, layers=2, grid=7, h=0.4, hidden_norm=False),
    Arch("relu", width=16, layers=4),
    Arch("relu", width=1, layers=1),
    Arch("gelu", width=16, layers=3),
]
IDS = [f"{a.family}-k{a.order}-{a.width}x{a.layers}-{'norm' if a.hidden_norm else 'raw'}"
       if a.is_kan else f"{a.family}-{a.width}x{a.layers}" for a in ARCHS]


def closed_form_params(a: Arch) -> int:
    """Parameter counts written out per family (independent of Arch.tensor_shapes)."""
    n_in, n, ell, g = a.n_in, a.width, a.layers, a.grid
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
    net.set_normalisation(rng.normal(size=a.n_in), rng.uniform(0.5, 2.0, a.n_in), 0.3, 1.7)
    return net


@pytest.mark.parametrize("a", ARCHS, ids=IDS)
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


def probe_inputs(a: Arch, seed: int = 1) -> np.ndarray:
    """z-scored inputs (B, n_in): inside the grid, around its edge, far outside (|z| up to 1e3,
    only the SiLU branch of a B-spline layer sees them), and exactly on the float32 knots."""
    rng = np.random.default_rng(seed)
    n = a.n_in
    far = rng.choice([-1.0, 1.0], size=(40, n)) * 10.0 ** rng.uniform(0.7, 3.0, size=(40, n))
    mixed = rng.normal(size=(40, n))
    mixed[:, ::2] = far[:, ::2]
    on_knots = rng.choice(a.knots().astype(np.float32).astype(np.float64), size=(40, n))
    return np.vstack([rng.normal(size=(100, n)), 3.0 * rng.normal(size=(100, n)), far, mixed,
                      on_knots, np.zeros((1, n))])


def torch_reference(net: TimeShiftNet, z: np.ndarray) -> np.ndarray:
    """The training path's output in float64 (a float64 copy of the module)."""
    ref = TimeShiftNet(net.arch)
    ref.load_state_dict(net.state_dict())
    with torch.no_grad():
        return ref.double()(torch.tensor(z, dtype=torch.float64)).numpy()


@pytest.mark.parametrize("a", ARCHS, ids=IDS)
def test_compiled_forward_equals_torch(a: Arch) -> None:
    net = _net(a)
    z = probe_inputs(a)
    ref = torch_reference(net, z)
    npn = NumpyNet(a, {k: v.numpy() for k, v in net.state_dict().items()})
    batch = npn.forward(z)
    assert batch.shape == (len(z),) and np.all(np.isfinite(ref))
    np.testing.assert_allclose(batch, ref, rtol=1e-12, atol=1e-12)
    # One sample is the same kernel on a batch of one: bit for bit the batch rows.
    one = np.array([npn.forward_one(r) for r in z])
    np.testing.assert_array_equal(one, batch)
    assert isinstance(npn.forward_one(z[0]), float)


@pytest.mark.parametrize("name", LEARNED_NAMES)
def test_shipped_model_compiled_forward_equals_torch(name: str) -> None:
    m = load_model(name)
    net = TimeShiftNet(m.arch)
    net.load_state_dict({k: torch.from_numpy(v) for k, v in m.tensors.items()}, strict=True)
    z = probe_inputs(m.arch, seed=2)
    npn = NumpyNet(m.arch, m.tensors)
    np.testing.assert_allclose(npn.forward(z), torch_reference(net, z), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal([npn.forward_one(r) for r in z[:20]], npn.forward(z[:20]))


@pytest.mark.parametrize("a", ARCHS, ids=IDS)
def test_float32_weights_packed_as_float32_change_no_bit(a: Arch) -> None:
    """Weights that are all float32 values (trained ones) are packed as float32 and widened
    exactly in the products: outputs bit for bit those of the same weights packed as float64.
    B-spline KANs pack the products α·c, not float32 values: float64."""
    npn = NumpyNet(a, {k: v.numpy() for k, v in _net(a).state_dict().items()})
    kind, widths, offsets, params, *rest = npn._args
    assert params.dtype == (np.float64 if a.family == "cikan" else np.float32)
    z = probe_inputs(a)
    np.testing.assert_array_equal(
        network_forward(z, kind, widths, offsets, params, *rest),
        network_forward(z, kind, widths, offsets, params.astype(np.float64), *rest))


def test_forward_rejects_a_wrong_feature_count() -> None:
    a = ARCHS[0]
    npn = NumpyNet(a, {k: v.numpy() for k, v in _net(a).state_dict().items()})
    with pytest.raises(ValueError, match=rf"shape \(B, {a.n_in}\)"):
        npn.forward(np.zeros((3, a.n_in - 1)))
    with pytest.raises(ValueError, match=rf"shape \({a.n_in},\)"):
        npn.forward_one(np.zeros(a.n_in + 1))


@pytest.mark.parametrize("a", ARCHS, ids=IDS)
def test_save_load_identical_outputs(a: Arch, tmp_path: Path) -> None:
    net = _net(a, seed=3)
    save_model(tmp_path / "m", a, net.state_dict(), {"name": "t"})
    m = load_model(tmp_path / "m")
    assert m.arch == a
    back = TimeShiftNet(m.arch)
    back.load_state_dict({k: torch.from_numpy(v).to(net.state_dict()[k].dtype)
                          for k, v in m.tensors.items()})
    z = torch.randn(64, a.n_in)
    with torch.no_grad():
        assert torch.equal(net(z), back(z))
    # Through the file the compiled path sees exactly the saved float32 weights.
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
    from cikan_ros.registry import make_governor

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
