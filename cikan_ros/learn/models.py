"""Torch modules of the five families, written from the equations (SPEC §7; style of efficient-kan:
one class per mathematical object, methods named after the maths, shapes in docstrings).

Shapes: B batch, I layer inputs, O layer outputs, M basis functions per edge. Tensor names match
:meth:`cikan_ros.learn.arch.Arch.tensor_shapes`, and :class:`cikan_ros.learn.arch.NumpyNet` is
the same network in float64 numpy (tests compare them).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .arch import LAYERNORM_EPS, Arch, norm_tensor_shapes


class UniformBSplineBasis(nn.Module):
    """B-splines of order k on a uniform grid of G intervals over [-R, R] (G + k functions).

    ``forward`` uses the fast closed form of the cardinal cubic B-spline when k = 3 and the
    Cox-de Boor recursion otherwise (``cox_de_boor`` is kept callable for tests).
    """

    def __init__(self, grid: int, order: int, grid_range: float, knots: np.ndarray) -> None:
        super().__init__()
        self.grid, self.order, self.grid_range = grid, order, grid_range
        self.register_buffer("knots", torch.tensor(knots, dtype=torch.float32), persistent=False)
        k32 = np.asarray(knots, dtype=np.float32).astype(np.float64)
        self.step = float(k32[1] - k32[0])   # as the numpy path computes it from the same buffer

    def cardinal_cubic(self, x: Tensor) -> Tensor:
        """(B, I) -> (B, I, G+3): N((x - t_m)/Δ) with s = |u - 2|, N = (relu(2-s)³ - 4 relu(1-s)³)/6."""
        s = ((x.unsqueeze(-1) - self.knots[:-4]) / self.step - 2.0).abs()
        a = F.relu(2.0 - s)
        b = F.relu(1.0 - s)
        return (a * a * a - 4.0 * b * b * b) / 6.0

    def cox_de_boor(self, x: Tensor) -> Tensor:
        """(B, I) -> (B, I, G+k) by the Cox-de Boor recursion on half-open knot spans."""
        t = self.knots
        x = x.unsqueeze(-1)
        b = ((x >= t[:-1]) & (x < t[1:])).to(x.dtype)
        for p in range(1, self.order + 1):
            b = ((x - t[: -(p + 1)]) / (t[p:-1] - t[: -(p + 1)]) * b[..., :-1]
                 + (t[p + 1:] - x) / (t[p + 1:] - t[1:-p]) * b[..., 1:])
        return b

    def forward(self, x: Tensor) -> Tensor:
        return self.cardinal_cubic(x) if self.order == 3 else self.cox_de_boor(x)


class GaussianRBFBasis(nn.Module):
    """exp(-(x - c_m)² / (2h²)) with G centres c_m uniform on [-R, R]: (B, I) -> (B, I, G)."""

    def __init__(self, centres: np.ndarray, h: float) -> None:
        super().__init__()
        self.register_buffer("centres", torch.tensor(centres, dtype=torch.float32), persistent=False)
        self.h = float(h)

    def forward(self, x: Tensor) -> Tensor:
        d = (x.unsqueeze(-1) - self.centres) / self.h
        return torch.exp(-0.5 * d * d)


class ReflectionalSwitchBasis(nn.Module):
    """RSWAF 1 - tanh²((x - c_m)/h), G centres on [-R, R]: (B, I) -> (B, I, G). Plain autograd
    (the width h enters the gradient; no custom backward)."""

    def __init__(self, centres: np.ndarray, h: float) -> None:
        super().__init__()
        self.register_buffer("centres", torch.tensor(centres, dtype=torch.float32), persistent=False)
        self.h = float(h)

    def forward(self, x: Tensor) -> Tensor:
        t = torch.tanh((x.unsqueeze(-1) - self.centres) / self.h)
        return 1.0 - t * t


class BSplineKANLayer(nn.Module):
    """Φ_l of the B-spline KAN: x_{l+1,j} = Σ_i β_ji SiLU(x_i) + α_ji Σ_m c_jim B_m(x_i).

    Parameters: base_weight β (O, I), spline_weight c (O, I, G+k), spline_scaler α (O, I).
    """

    def __init__(self, n_in: int, n_out: int, basis: UniformBSplineBasis, norm: bool) -> None:
        super().__init__()
        m = basis.grid + basis.order
        self.norm = nn.LayerNorm(n_in, eps=LAYERNORM_EPS) if norm else None
        self.basis = basis
        self.base_weight = nn.Parameter(torch.empty(n_out, n_in))
        self.spline_weight = nn.Parameter(torch.empty(n_out, n_in, m))
        self.spline_scaler = nn.Parameter(torch.empty(n_out, n_in))
        nn.init.kaiming_uniform_(self.base_weight, a=math.sqrt(5))
        nn.init.normal_(self.spline_weight, std=0.1 / math.sqrt(n_in))
        nn.init.kaiming_uniform_(self.spline_scaler, a=math.sqrt(5))

    def scaled_spline_weight(self) -> Tensor:
        """α_ji c_jim: (O, I, G+k)."""
        return self.spline_weight * self.spline_scaler.unsqueeze(-1)

    def forward(self, x: Tensor) -> Tensor:
        """(B, I) -> (B, O)."""
        if self.norm is not None:
            x = self.norm(x)
        base = F.linear(F.silu(x), self.base_weight)
        spline = F.linear(self.basis(x).flatten(1), self.scaled_spline_weight().flatten(1))
        return base + spline


class RadialKANLayer(nn.Module):
    """Φ_l of GRBF- or RSWAF-KAN: x_{l+1,j} = Σ_i Σ_m θ_jim ψ_m(x_i); coef θ (O, I, G)."""

    def __init__(self, n_in: int, n_out: int, basis: nn.Module, n_basis: int, norm: bool) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(n_in, eps=LAYERNORM_EPS) if norm else None
        self.basis = basis
        self.coef = nn.Parameter(torch.empty(n_out, n_in, n_basis))
        nn.init.normal_(self.coef, std=1.0 / math.sqrt(n_in * n_basis))

    def forward(self, x: Tensor) -> Tensor:
        """(B, I) -> (B, O)."""
        if self.norm is not None:
            x = self.norm(x)
        return F.linear(self.basis(x).flatten(1), self.coef.flatten(1))


class MLPLayer(nn.Linear):
    """y = act(W x + b) (act = ReLU, GELU, or none on the output layer): (B, I) -> (B, O)."""

    def __init__(self, n_in: int, n_out: int, act: str | None) -> None:
        super().__init__(n_in, n_out)
        self.act = act

    def forward(self, x: Tensor) -> Tensor:
        y = super().forward(x)
        if self.act == "relu":
            return F.relu(y)
        if self.act == "gelu":
            return F.gelu(y)
        return y


class TimeShiftNet(nn.Module):
    """π̃_θ: z-scored features z (B, I) -> ln|τ| (B,) = target_mean + target_std · net(z).

    Buffers (saved with the weights, float64): feature_mean, feature_std (I,) with I = arch.n_in, target_mean,
    target_std (1,). Features are z-scored outside, in float64 (:func:`normalise`).
    """

    def __init__(self, arch: Arch) -> None:
        super().__init__()
        self.arch = arch
        for name, shape in norm_tensor_shapes(arch.n_in).items():
            self.register_buffer(name, torch.zeros(shape, dtype=torch.float64)
                                 if "mean" in name else torch.ones(shape, dtype=torch.float64))
        w = arch.widths
        layers: list[nn.Module] = []
        if arch.family == "cikan":
            basis = UniformBSplineBasis(arch.grid, arch.order, arch.grid_range, arch.knots())
        elif arch.family == "grbf":
            basis = GaussianRBFBasis(arch.centres(), arch.basis_width)
        elif arch.family == "rswaf":
            basis = ReflectionalSwitchBasis(arch.centres(), arch.basis_width)
        for l in range(arch.layers):
            norm = arch.layer_norm_on(l)
            if arch.family == "cikan":
                layers.append(BSplineKANLayer(w[l], w[l + 1], basis, norm))
            elif arch.is_kan:
                layers.append(RadialKANLayer(w[l], w[l + 1], basis, arch.n_basis, norm))
            else:
                act = arch.family if l < arch.layers - 1 else None
                layers.append(MLPLayer(w[l], w[l + 1], act))
        self.layers = nn.ModuleList(layers)

    def set_normalisation(self, feature_mean: np.ndarray, feature_std: np.ndarray,
                          target_mean: float, target_std: float) -> None:
        """Store the training statistics (float64)."""
        self.feature_mean.copy_(torch.as_tensor(feature_mean, dtype=torch.float64))
        self.feature_std.copy_(torch.as_tensor(feature_std, dtype=torch.float64))
        self.target_mean.fill_(float(target_mean))
        self.target_std.fill_(float(target_std))

    def normalise(self, feats: np.ndarray) -> np.ndarray:
        """Raw float64 features (..., I) -> z-scored (float64)."""
        return (feats - self.feature_mean.numpy()) / self.feature_std.numpy()

    def forward(self, z: Tensor) -> Tensor:
        """(B, I) float32 z-scored features -> (B,) predicted ln|τ| (s)."""
        x = z
        for layer in self.layers:
            x = layer(x)
        return self.target_mean.to(x.dtype) + self.target_std.to(x.dtype) * x[:, 0]

    def n_params(self) -> int:
        """Trainable parameter count."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)
