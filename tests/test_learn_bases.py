"""Golden tests of the edge-function bases of the compiled kernels and of the torch modules
against independent references (scipy, math), plus a property test of the knot-span boundaries."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import BSpline

from cikan_ros.learn.arch import (GRBF, RSWAF, Arch, _uniform_grid, bspline_span,
                                  cardinal_cubic_bases, de_boor_bases, radial_bases)
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


def kernel_basis(x: np.ndarray, knots: np.ndarray, k: int, cardinal: bool = False) -> np.ndarray:
    """All G + k bases at each x from the kernels' span routines (the k + 1 span bases scattered
    into place, zero elsewhere)."""
    n = len(knots) - k - 1
    out = np.zeros((len(x), n))
    phi = np.empty(k + 1)
    for row, xi in enumerate(x):
        s = bspline_span(xi, knots)
        if s < 0:
            continue
        if cardinal:
            cardinal_cubic_bases(xi, s, knots, phi)
        else:
            de_boor_bases(xi, s, knots, k, phi)
        for r in range(k + 1):
            if 0 <= s - k + r < n:
                out[row, s - k + r] = phi[r]
    return out


@pytest.mark.parametrize("grid,grid_range", [(5, 3.0), (8, 2.5), (17, 4.0)])
def test_cubic_bspline_bases_match_scipy(grid: int, grid_range: float) -> None:
    arch = Arch("cikan", 4, 2, grid=grid, grid_range=grid_range)
    knots = arch.knots()
    assert len(knots) == grid + 2 * 3 + 1
    x = np.linspace(knots[0] + 1e-9, knots[-1] - 1e-9, 1001)
    ref = scipy_basis(x, knots, 3)
    fast = kernel_basis(x, knots, 3, cardinal=True)
    assert fast.shape == (len(x), grid + 3)
    np.testing.assert_allclose(fast, ref, atol=1e-12)
    np.testing.assert_allclose(kernel_basis(x, knots, 3), ref, atol=1e-12)
    basis = UniformBSplineBasis(grid, 3, grid_range, knots)
    xt = torch.tensor(x[None, :], dtype=torch.float32)
    np.testing.assert_allclose(basis.cardinal_cubic(xt)[0].numpy(), ref, atol=2e-6)
    np.testing.assert_allclose(basis.cox_de_boor(xt)[0].numpy(), ref, atol=2e-6)


@pytest.mark.parametrize("order", [1, 2, 4, 5])
def test_other_orders_match_scipy(order: int) -> None:
    knots = Arch("cikan", 4, 2, grid=6, order=order).knots()
    x = np.linspace(knots[0], knots[-1] - 1e-9, 1201)
    np.testing.assert_allclose(kernel_basis(x, knots, order), scipy_basis(x, knots, order),
                               atol=1e-12)


def test_partition_of_unity_inside_grid_and_zero_far_outside() -> None:
    knots = Arch("cikan", 4, 2, grid=9, grid_range=3.0).knots()
    x = np.linspace(-3.0, 3.0, 2001)
    for cardinal in (True, False):
        b = kernel_basis(x, knots, 3, cardinal)
        np.testing.assert_allclose(b.sum(axis=-1), 1.0, atol=1e-12)
        assert np.all(b >= -1e-15)
    for x_out in (-10.0, knots[0] - 1e-12, knots[-1], 10.0, math.nan, math.inf):
        assert bspline_span(x_out, knots) == -1


@settings(max_examples=300, deadline=None)
@given(order=st.integers(1, 5), grid=st.integers(2, 12), m=st.integers(0, 30),
       ulps=st.integers(-3, 3))
def test_span_bases_equal_torch_cox_de_boor_at_knots(order: int, grid: int, m: int, ulps: int
                                                     ) -> None:
    """At and a few ulps around every knot (float32-rounded, as the torch buffer holds them), the
    half-open spans and the local recursion give the torch Cox-de Boor bases (float64)."""
    arch = Arch("cikan", 4, 2, grid=grid, order=order, grid_range=2.3)
    knots = arch.knots().astype(np.float32).astype(np.float64)
    t = knots[m % len(knots)]
    x = t + ulps * np.spacing(t)
    ref = UniformBSplineBasis(grid, order, 2.3, arch.knots()).double().cox_de_boor(
        torch.tensor([[x]], dtype=torch.float64))[0, 0].numpy()
    np.testing.assert_allclose(kernel_basis(np.array([x]), knots, order)[0], ref,
                               rtol=1e-14, atol=1e-15)


def radial_table(x: np.ndarray, centres: np.ndarray, h: float, kind: int) -> np.ndarray:
    """(len(x), G) basis values from the kernels' ``radial_bases``."""
    out = np.empty((len(x), len(centres)))
    radial_bases(np.asarray(x, dtype=np.float64), centres, h, kind, out)
    return out


def direct_radial(x: np.ndarray, centres: np.ndarray, h: float, kind: int) -> np.ndarray:
    """(len(x), G): the direct formulas, one exp per basis (the kernels' own fallback)."""
    d = (x[:, None] - centres[None, :]) / h
    if kind == GRBF:
        return np.exp(-0.5 * d * d)
    e = np.exp(-2.0 * np.abs(d))
    return 4.0 * e / ((1.0 + e) * (1.0 + e))


@settings(max_examples=400, deadline=None)
@given(kind=st.sampled_from([GRBF, RSWAF]), grid=st.integers(2, 32),
       grid_range=st.floats(0.5, 6.0), h_over_spacing=st.floats(0.05, 20.0),
       u=st.lists(st.floats(-1.5, 1.5), min_size=1, max_size=8),
       m=st.lists(st.integers(0, 31), max_size=4), ulps=st.integers(-2, 2))
def test_radial_ladders_equal_the_direct_formula(kind: int, grid: int, grid_range: float,
                                                  h_over_spacing: float, u: list[float],
                                                  m: list[int], ulps: int) -> None:
    """On the float32 centres of the networks (not exactly uniform) and for inputs across the
    grid, around its edges, exactly on and a few ulps off centres, far outside, infinite and NaN,
    the ladders give the direct formula to 1e-13 relative (NaN where it is NaN; below 1e-300 to
    1e-300). The direct formula is itself only good to ~d² ulps, from the rounding of
    d = (x - c)/h: the tolerance grows by that."""
    arch = Arch("grbf" if kind == GRBF else "rswaf", 4, 2, grid=grid, grid_range=grid_range,
                h=h_over_spacing * 2.0 * grid_range / (grid - 1))
    c = arch.centres().astype(np.float32).astype(np.float64)
    h = arch.basis_width
    on = c[np.array(m, dtype=int) % grid]
    far = [c[0] - h, c[-1] + 2 * h, -1e3, 1e3, -1e300, 1e300, -np.inf, np.inf, np.nan]
    x = np.concatenate([np.array(u) * 1.2 * grid_range, on, on + ulps * np.spacing(on), far])
    with np.errstate(all="ignore"):
        fast, ref = radial_table(x, c, h, kind), direct_radial(x, c, h, kind)
        d = np.clip(np.nan_to_num((x[:, None] - c[None, :]) / h), -1e100, 1e100)
    np.testing.assert_array_equal(np.isnan(fast), np.isnan(ref))
    fast, ref = np.nan_to_num(fast), np.nan_to_num(ref)
    tol = (1e-13 + 4.0 * np.finfo(float).eps * d * d) * ref + 1e-300
    assert np.all(np.abs(fast - ref) <= tol), np.max(np.abs(fast - ref) / (tol + 1e-300))


@settings(max_examples=200, deadline=None)
@given(kind=st.sampled_from([GRBF, RSWAF]), grid=st.integers(2, 32),
       grid_range=st.floats(1.0, 5.0), h_over_spacing=st.floats(0.25, 4.0))
def test_radial_ladders_hold_on_float32_centres(kind: int, grid: int, grid_range: float,
                                                 h_over_spacing: float) -> None:
    """The ladders (not the direct formula) run on the networks' grids, tuned h/Δ in [0.5, 2]
    and beyond: their float32 centres are close enough to uniform."""
    c = np.linspace(-grid_range, grid_range, grid).astype(np.float32).astype(np.float64)
    assert _uniform_grid(c, h_over_spacing * 2.0 * grid_range / (grid - 1), kind)[2]


def test_grbf_basis_matches_formula() -> None:
    arch = Arch("grbf", 4, 2, grid=7, grid_range=2.0, h=0.37)
    c, h = arch.centres(), arch.basis_width
    assert h == 0.37
    x = np.array([-3.1, -2.0, -0.4, 0.0, 0.25, 1.9, 5.0])
    ref = np.array([[math.exp(-(xi - ci) ** 2 / (2 * h * h)) for ci in c] for xi in x])
    np.testing.assert_allclose(radial_table(x, c, h, GRBF), ref, rtol=1e-13, atol=1e-300)
    t = GaussianRBFBasis(c, h)(torch.tensor(x[None, :], dtype=torch.float64))[0]
    np.testing.assert_allclose(t.numpy(), ref, rtol=1e-6, atol=1e-12)


def test_rswaf_basis_matches_formula_and_honours_h() -> None:
    arch = Arch("rswaf", 4, 2, grid=6, grid_range=3.0)
    c = arch.centres()
    np.testing.assert_allclose(arch.basis_width, 6.0 / 5.0)
    x = np.array([-4.0, -1.3, 0.0, 0.7, 2.9])
    for h in (0.3, 1.2, 2.5):
        ref = np.array([[1.0 - math.tanh((xi - ci) / h) ** 2 for ci in c] for xi in x])
        np.testing.assert_allclose(radial_table(x, c, h, RSWAF), ref, rtol=1e-12, atol=1e-15)
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
