"""Golden tests of the edge-function bases against independent references (scipy, math)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.interpolate import BSpline

from cikan_ros.learn.arch import (Arch, bspline_cox_de_boor, cubic_bspline_uniform, gaussian_rbf,
                                  rswaf)
from cikan_ros.learn.models import (GaussianRBFBasis, ReflectionalSwitchBasis,
                                    UniformBSplineBasis)


def scipy_basis(x: np.ndarray, knots: np.ndarray, k: int) -> np.ndarray:
    """B_m(x) for every basis m of the knot vector: scipy's ``BSpline.basis_element`` on the
    knots t_m .. t_{m+k+1} (zero outside its support)."""
    n = len(knots) - k - 1
    out = np.empty((len(x), n))
    for m in range(n):
        out[:, m] = BSpline.basis_element(knots[m:m + k + 2], extrapolate=False)(x)
    return np.nan_to_num(out)


@pytest.mark.parametrize("grid,grid_range", [(5, 3.0), (8, 2.5), (17, 4.0)])
def test_cubic_bspline_fast_path_matches_scipy(grid: int, grid_range: float) -> None:
    arch = Arch("cikan", 4, 2, grid=grid, grid_range=grid_range)
    knots = arch.knots()
    assert len(knots) == grid + 2 * 3 + 1
    x = np.linspace(knots[0] + 1e-9, knots[-1] - 1e-9, 1001)
    ref = scipy_basis(x, knots, 3)
    fast = cubic_bspline_uniform(x[None, :], knots)[0]
    assert fast.shape == (len(x), grid + 3)
    np.testing.assert_allclose(fast, ref, atol=1e-12)
    general = bspline_cox_de_boor(x[None, :], knots, 3)[0]
    np.testing.assert_allclose(general, ref, atol=1e-12)
    basis = UniformBSplineBasis(grid, 3, grid_range, knots)
    xt = torch.tensor(x[None, :], dtype=torch.float32)
    np.testing.assert_allclose(basis.cardinal_cubic(xt)[0].numpy(), ref, atol=2e-6)
    np.testing.assert_allclose(basis.cox_de_boor(xt)[0].numpy(), ref, atol=2e-6)


@pytest.mark.parametrize("order", [1, 2, 4])
def test_other_orders_match_scipy(order: int) -> None:
    arch = Arch("cikan", 4, 2, grid=6, order=order)
    knots = arch.knots()
    x = np.linspace(-3.0, 3.0 - 1e-9, 301)
    np.testing.assert_allclose(bspline_cox_de_boor(x[None, :], knots, order)[0],
                               scipy_basis(x, knots, order), atol=1e-12)


def test_partition_of_unity_inside_grid_and_zero_far_outside() -> None:
    arch = Arch("cikan", 4, 2, grid=9, grid_range=3.0)
    x = np.linspace(-3.0, 3.0, 2001)
    b = cubic_bspline_uniform(x[None, :], arch.knots())[0]
    np.testing.assert_allclose(b.sum(axis=-1), 1.0, atol=1e-12)
    assert np.all(b >= -1e-15)
    far = cubic_bspline_uniform(np.array([[-10.0, 10.0]]), arch.knots())[0]
    assert np.all(far == 0.0)


def test_grbf_basis_matches_formula() -> None:
    arch = Arch("grbf", 4, 2, grid=7, grid_range=2.0, h=0.37)
    c, h = arch.centres(), arch.basis_width
    assert h == 0.37
    x = np.array([-3.1, -2.0, -0.4, 0.0, 0.25, 1.9, 5.0])
    ref = np.array([[math.exp(-(xi - ci) ** 2 / (2 * h * h)) for ci in c] for xi in x])
    np.testing.assert_allclose(gaussian_rbf(x[None, :], c, h)[0], ref, rtol=1e-13, atol=1e-300)
    t = GaussianRBFBasis(c, h)(torch.tensor(x[None, :], dtype=torch.float64))[0]
    np.testing.assert_allclose(t.numpy(), ref, rtol=1e-6, atol=1e-12)


def test_rswaf_basis_matches_formula_and_honours_h() -> None:
    arch = Arch("rswaf", 4, 2, grid=6, grid_range=3.0)
    c = arch.centres()
    np.testing.assert_allclose(arch.basis_width, 6.0 / 5.0)
    x = np.array([-4.0, -1.3, 0.0, 0.7, 2.9])
    for h in (0.3, 1.2, 2.5):
        ref = np.array([[1.0 - math.tanh((xi - ci) / h) ** 2 for ci in c] for xi in x])
        np.testing.assert_allclose(rswaf(x[None, :], c, h)[0], ref, rtol=1e-12, atol=1e-15)
        t = ReflectionalSwitchBasis(c, h)(torch.tensor(x[None, :], dtype=torch.float64))[0]
        np.testing.assert_allclose(t.numpy(), ref, rtol=1e-6, atol=1e-12)


def test_rswaf_gradient_is_plain_autograd_with_h() -> None:
    """d/dx (1 - tanh²(u)) = -2 tanh(u) (1 - tanh²(u)) / h with u = (x - c)/h: the width enters."""
    c = np.array([0.0, 0.5])
    for h in (0.5, 2.0):
        basis = ReflectionalSwitchBasis(c, h).double()
        x = torch.tensor([[0.3]], dtype=torch.float64, requires_grad=True)
        basis(x).sum().backward()
        u = (0.3 - c) / h
        ref = float(np.sum(-2.0 * np.tanh(u) * (1.0 - np.tanh(u) ** 2) / h))
        assert float(x.grad) == pytest.approx(ref, rel=1e-12)
