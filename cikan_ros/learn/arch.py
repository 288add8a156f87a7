"""Architectures of the five model families, without torch: tensor names and shapes, parameter
counts, the paper's complexity n²ℓ(G+3), and the float64 inference forward of each family.

The governor runs networks through :class:`NumpyNet` (no torch import, no autograd): one compiled
numba kernel with one layer per family (B-spline KAN, radial KAN, MLP) takes a batch of z-scored
features, and one sample is the same kernel on a batch of one. Training uses the torch modules of
``cikan_ros.learn.models``, which have the same tensor names; tests check that both agree.

Widths: ``[n_in] + [width] * (layers - 1) + [1]``, so ``layers`` = ℓ counts the maps (KAN layers
Φ_l or linear layers), as in the paper's complexity n²ℓ(G+3).

Edge functions (x a scalar input of layer l, one function per edge (j, i)):

- ``cikan`` (B-spline KAN): φ(x) = β_ji SiLU(x) + α_ji Σ_m c_jim B_m(x), cubic (order k) B-splines
  on a uniform grid of G intervals over [-R, R], extended by k knots each side: G + k bases.
- ``grbf``: φ(x) = Σ_m θ_jim exp(-(x - c_m)² / (2h²)), G centres c_m uniform on [-R, R].
- ``rswaf``: φ(x) = Σ_m θ_jim (1 - tanh²((x - c_m) / h)), same centres.
- ``relu``, ``gelu``: MLP, y = act(W x + b) on hidden layers, linear output.

Optional ``hidden_norm``: a LayerNorm on the input of every KAN layer but the first (SPEC §7
pitfalls: keeps hidden activations inside the grid; the first layer sees z-scored features and
must keep their per-sample offsets). The network's output is de-normalised into its target
y = target_mean + target_std · net(z), and ``target`` says what y is:

- ``"log-shift"`` (the paper's): y = ln|τ| (s);
- ``"log-ratio"``: y = ln(|τ| / |τ_{k-1}|) <= 0, so ln|τ| = ln|τ_{k-1}| + y. The network learns
  π*'s step relative to the shift it starts from, not the shift itself: a relative error of the
  step, not of |τ| (needs a feature set with τ_{k-1}, ``vnb-prev``; docs/learned_update_rule.md,
  "A network of the step").
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

import numba as nb
import numpy as np
from numpy.typing import NDArray

from .errors import ModelFileError
from .features import FEATURE_SETS, features_into, n_features, uses_tau_prev

FAMILIES = ("cikan", "grbf", "rswaf", "relu", "gelu")
KAN_FAMILIES = ("cikan", "grbf", "rswaf")
#: What a network's de-normalised output is (module docstring): ln|τ| or ln(|τ| / |τ_{k-1}|).
TARGETS = ("log-shift", "log-ratio")


def target_problem(features: str, target: str) -> str | None:
    """Why a network of feature set ``features`` cannot learn ``target``, or None."""
    if target not in TARGETS:
        return f"target must be one of {TARGETS}"
    if target == "log-ratio" and not uses_tau_prev(features):
        return "target 'log-ratio' needs a feature set with tau_prev (vnb-prev)"
    return None


def log_shift_offset(target: str, feats: NDArray) -> NDArray:
    """What to add to a network's target to get ln|τ| (s), for raw features (..., n_in) -> (...):
    ln|τ_{k-1}| (the last feature of ``vnb-prev``) for ``log-ratio``, else 0."""
    feats = np.asarray(feats, dtype=np.float64)
    return feats[..., -1].copy() if target == "log-ratio" else np.zeros(feats.shape[:-1])
#: Buffers every model file carries (float64): feature and target normalisation.
NORM_TENSORS = ("feature_mean", "feature_std", "target_mean", "target_std")


def norm_tensor_shapes(n_in: int) -> dict[str, tuple[int, ...]]:
    """Shapes of the normalisation buffers of a network with ``n_in`` inputs."""
    return dict(zip(NORM_TENSORS, ((n_in,), (n_in,), (1,), (1,))))


LAYERNORM_EPS = 1e-5


@dataclass(frozen=True)
class Arch:
    """Architecture of one network. ``grid`` = G (intervals for cikan, centres for grbf/rswaf);
    ``h`` = basis width of grbf/rswaf (0: the centre spacing 2R/(G-1))."""

    family: str
    width: int
    layers: int
    grid: int = 8
    order: int = 3
    grid_range: float = 3.0
    h: float = 0.0
    hidden_norm: bool = True
    n_in: int = 0           # 0: the feature set's input count
    features: str = "vnb"
    target: str = "log-shift"

    def __post_init__(self) -> None:
        def bad(what: str) -> None:
            raise ModelFileError(f"invalid architecture {asdict(self)}: {what}")

        if self.family not in FAMILIES:
            bad(f"family must be one of {FAMILIES}")
        if not (isinstance(self.width, int) and self.width >= 1):
            bad("width must be an integer >= 1")
        if not (isinstance(self.layers, int) and self.layers >= 1):
            bad("layers must be an integer >= 1")
        if self.family in KAN_FAMILIES and not (isinstance(self.grid, int) and self.grid >= 2):
            bad("grid must be an integer >= 2")
        if self.family == "cikan" and not (isinstance(self.order, int) and 1 <= self.order <= 5):
            bad("order must be an integer in [1, 5]")
        if not (math.isfinite(self.grid_range) and self.grid_range > 0):
            bad("grid_range must be > 0")
        if not (math.isfinite(self.h) and self.h >= 0):
            bad("h must be >= 0")
        if self.features not in FEATURE_SETS:
            bad(f"features must be one of {FEATURE_SETS}")
        if self.n_in == 0:
            object.__setattr__(self, "n_in", n_features(self.features))
        if self.n_in != n_features(self.features):
            bad(f"n_in must be {n_features(self.features)} for features {self.features!r}")
        problem = target_problem(self.features, self.target)
        if problem:
            bad(problem)

    @property
    def relative(self) -> bool:
        """Is the target ln(|τ| / |τ_{k-1}|) (``log-ratio``)?"""
        return self.target == "log-ratio"

    def log_shift_offset(self, feats: NDArray) -> NDArray:
        """:func:`log_shift_offset` of this network's target."""
        return log_shift_offset(self.target, feats)

    # -- shape -------------------------------------------------------------------------------
    @property
    def widths(self) -> list[int]:
        """Layer widths [n_in, n, ..., n, 1] (ℓ + 1 entries)."""
        return [self.n_in] + [self.width] * (self.layers - 1) + [1]

    @property
    def is_kan(self) -> bool:
        return self.family in KAN_FAMILIES

    @property
    def n_basis(self) -> int:
        """Basis functions per edge: G + k (B-splines) or G (GRBF, RSWAF)."""
        return self.grid + self.order if self.family == "cikan" else self.grid

    @property
    def basis_width(self) -> float:
        """h of GRBF/RSWAF: the configured value, or the centre spacing 2R/(G-1)."""
        return self.h if self.h > 0 else 2.0 * self.grid_range / (self.grid - 1)

    def layer_norm_on(self, layer: int) -> bool:
        return self.is_kan and self.hidden_norm and layer > 0

    def tensor_shapes(self) -> dict[str, tuple[int, ...]]:
        """Trainable tensors by state-dict name -> shape."""
        shapes: dict[str, tuple[int, ...]] = {}
        w = self.widths
        for l in range(self.layers):
            n_i, n_o = w[l], w[l + 1]
            pre = f"layers.{l}."
            if self.layer_norm_on(l):
                shapes[pre + "norm.weight"] = (n_i,)
                shapes[pre + "norm.bias"] = (n_i,)
            if self.family == "cikan":
                shapes[pre + "base_weight"] = (n_o, n_i)
                shapes[pre + "spline_weight"] = (n_o, n_i, self.n_basis)
                shapes[pre + "spline_scaler"] = (n_o, n_i)
            elif self.is_kan:
                shapes[pre + "coef"] = (n_o, n_i, self.n_basis)
            else:
                shapes[pre + "weight"] = (n_o, n_i)
                shapes[pre + "bias"] = (n_o,)
        return shapes

    def n_params(self) -> int:
        """Trainable parameter count (from the tensor shapes)."""
        return sum(math.prod(s) for s in self.tensor_shapes().values())

    def complexity(self) -> int:
        """The paper's model complexity n²ℓ(G+3) for KANs, n²ℓ for MLPs."""
        n2l = self.width ** 2 * self.layers
        return n2l * (self.grid + 3) if self.is_kan else n2l

    def to_dict(self) -> dict[str, Any]:
        """The card's ``architecture``; ``target`` only when not the paper's ``log-shift`` (so the
        cards written before targets existed read back as they were)."""
        d = asdict(self)
        if d["target"] == "log-shift":
            del d["target"]
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Arch":
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ModelFileError(f"architecture has unknown fields {sorted(unknown)}")
        try:
            return cls(**dict(d))
        except TypeError as exc:
            raise ModelFileError(f"architecture is incomplete: {exc}") from None

    # -- grids -------------------------------------------------------------------------------
    def knots(self) -> NDArray:
        """B-spline knots (G + 2k + 1,): uniform, spacing 2R/G, k extra knots beyond each end."""
        hstep = 2.0 * self.grid_range / self.grid
        j = np.arange(-self.order, self.grid + self.order + 1, dtype=np.float64)
        return -self.grid_range + j * hstep

    def centres(self) -> NDArray:
        """GRBF/RSWAF centres (G,): uniform on [-R, R]."""
        return np.linspace(-self.grid_range, self.grid_range, self.grid)


# -- compiled inference forward --------------------------------------------------------------
# One numba kernel, network_forward, runs a batch z (B, n_in) -> (B,) network outputs (before the
# target de-normalisation) through one compiled layer per family (bspline_kan_layer,
# radial_kan_layer, mlp_layer); a single sample is the same kernel on a (1, n_in) view. A layer
# adds scaled rows of its weight matrices (rows, O) to its O outputs: contiguous and vectorised
# across outputs, in a fixed order (no fastmath, no reassociation).
# Layout (NumpyNet._pack): every tensor of a network once, row-major in one flat array, each block
# from a 64-byte boundary (aligned vector loads), and per layer l the start offsets
# ``offsets[l] = (norm, edge, second)`` (-1: none): the LayerNorm weight and bias (2, I); the
# edge weights (I·M, O), row i·M + m for input i and basis m (MLPs: (I, O)); the second tensor,
# the SiLU base weights β (I, O) of B-spline KANs or the bias (1, O) of MLPs. _block views a
# block as a C-contiguous matrix. Trained weights are float32 values: the array is then float32
# (half the memory traffic, the bottleneck of the radial KANs' sums) and every product widens
# them exactly, so the arithmetic is float64 on the same values.
# error_model="numpy": a float division by zero gives inf or NaN instead of raising, so divisions
# carry no check that stops vectorisation (no division here has a zero divisor).

BSPLINE, GRBF, RSWAF, RELU, GELU = range(len(FAMILIES))   # ``kind``: FAMILIES[kind]
_SQRT1_2 = 1.0 / math.sqrt(2.0)
#: Bound on |t| of the factors exp(t) that carry the radial ladders onto the float32 centres
#: (see below): _exp_small(t) is then exp(t) to t⁵/120 < 1e-17.
_LADDER_TOL = 1e-3

_kernel = nb.njit(cache=True, error_model="numpy", inline="always")


@_kernel
def _block(params: NDArray, start: int, n_rows: int, n_cols: int) -> NDArray:
    """The (n_rows, n_cols) matrix stored row-major at params[start:]."""
    return params[start:start + n_rows * n_cols].reshape(n_rows, n_cols)


@_kernel
def _add_row(y: NDArray, a: float, w: NDArray, r: int) -> None:
    """y[:O] += a · w[r] (w (R, O))."""
    for j in range(w.shape[1]):
        y[j] += a * w[r, j]


@_kernel
def _add_rows(y: NDArray, a: NDArray, w: NDArray, r0: int, n: int) -> None:
    """y[:O] += Σ_{t<n} a[t] w[r0 + t] (w (R, O)), term by term in t order as n calls of
    _add_row would add them, but four rows per pass over y (a quarter of its loads and stores)."""
    if w.shape[1] == 1:                     # a dot product: accumulate in a register
        acc = y[0]
        for t in range(n):
            acc += a[t] * w[r0 + t, 0]
        y[0] = acc
        return
    t = 0
    while t + 4 <= n:
        a0, a1, a2, a3 = a[t], a[t + 1], a[t + 2], a[t + 3]
        w0, w1, w2, w3 = w[r0 + t], w[r0 + t + 1], w[r0 + t + 2], w[r0 + t + 3]
        for j in range(w.shape[1]):
            y[j] = (((y[j] + a0 * w0[j]) + a1 * w1[j]) + a2 * w2[j]) + a3 * w3[j]
        t += 4
    for t in range(t, n):
        _add_row(y, a[t], w, r0 + t)


@_kernel
def _layer_norm(x: NDArray, n: int, wb: NDArray) -> None:
    """In place on x[:n]: (x - mean) / sqrt(var + eps) · weight + bias, biased variance (torch);
    weight and bias the rows of wb (2, n)."""
    mu = 0.0
    for i in range(n):
        mu += x[i]
    mu /= n
    var = 0.0
    for i in range(n):
        d = x[i] - mu
        var += d * d
    inv = 1.0 / np.sqrt(var / n + LAYERNORM_EPS)
    for i in range(n):
        x[i] = (x[i] - mu) * inv * wb[0, i] + wb[1, i]


@_kernel
def bspline_span(x: float, knots: NDArray) -> int:
    """Knot span s with knots[s] <= x < knots[s+1] (half-open, as the torch ``cox_de_boor``);
    -1 when x is outside [t_0, t_last) or NaN (then every B-spline is zero)."""
    n = knots.shape[0]
    if not (x >= knots[0] and x < knots[n - 1]):
        return -1
    s = min(int((x - knots[0]) / (knots[1] - knots[0])), n - 2)
    while x < knots[s]:
        s -= 1
    while x >= knots[s + 1]:
        s += 1
    return s


@_kernel
def cardinal_cubic_bases(x: float, s: int, knots: NDArray, phi: NDArray) -> None:
    """phi[r] = B_{s-3+r}(x), r = 0..3, cubic, as the torch ``cardinal_cubic``: N(u),
    u = (x - t_m)/Δ, s = |u - 2|, N = (relu(2 - s)³ - 4 relu(1 - s)³) / 6, Δ = t_1 - t_0.
    Entries of bases outside 0 .. G+2 are set to 0."""
    step = knots[1] - knots[0]
    n_basis = knots.shape[0] - 4
    for r in range(4):
        m = s - 3 + r
        if m < 0 or m >= n_basis:
            phi[r] = 0.0
            continue
        d = abs((x - knots[m]) / step - 2.0)
        a = max(2.0 - d, 0.0)
        b = max(1.0 - d, 0.0)
        phi[r] = (a * a * a - 4.0 * b * b * b) / 6.0


@_kernel
def de_boor_bases(x: float, s: int, knots: NDArray, order: int, phi: NDArray) -> None:
    """phi[r] = B_{s-k+r}(x), r = 0..k (k = order), the k + 1 B-splines that can be non-zero on
    the span s, by the Cox-de Boor recursion restricted to that span:
    B_m^p = (x - t_m)/(t_{m+p} - t_m) B_m^{p-1} + (t_{m+p+1} - x)/(t_{m+p+1} - t_{m+1}) B_{m+1}^{p-1},
    B_s^0 = 1. Bases the knot vector does not hold (m < 0, m + p + 1 > last knot) are 0."""
    last = knots.shape[0] - 1
    phi[0] = 1.0
    for p in range(1, order + 1):
        for r in range(p, -1, -1):        # phi[r] becomes B_{s-p+r}^p from phi[r-1], phi[r]
            m = s - p + r
            v = 0.0
            if m >= 0 and m + p + 1 <= last:
                if r > 0:
                    v = (x - knots[m]) / (knots[m + p] - knots[m]) * phi[r - 1]
                if r < p:
                    v += (knots[m + p + 1] - x) / (knots[m + p + 1] - knots[m + 1]) * phi[r]
            phi[r] = v


@_kernel
def bspline_kan_layer(x: NDArray, y: NDArray, n_i: int, n_o: int, params: NDArray,
                      offsets: NDArray, knots: NDArray, order: int, phi: NDArray) -> None:
    """y[:n_o] = Φ(x[:n_i]) of a B-spline KAN layer: y_j = Σ_i β_ji SiLU(x_i) + Σ_m α_ji c_jim
    B_m(x_i). Only the order + 1 bases of each input's knot span enter the sums (none outside the
    grid); cubic bases in the cardinal form of the torch module, other orders by the local
    Cox-de Boor recursion."""
    n_basis = knots.shape[0] - order - 1
    edge = _block(params, offsets[1], n_i * n_basis, n_o)
    base = _block(params, offsets[2], n_i, n_o)
    y[:n_o] = 0.0
    for i in range(n_i):
        xi = x[i]
        _add_row(y, xi / (1.0 + np.exp(-xi)), base, i)
        s = bspline_span(xi, knots)
        if s < 0:
            continue
        if order == 3:
            cardinal_cubic_bases(xi, s, knots, phi)
        else:
            de_boor_bases(xi, s, knots, order, phi)
        for r in range(order + 1):
            m = s - order + r
            if 0 <= m < n_basis:
                _add_row(y, phi[r], edge, i * n_basis + m)


# The radial bases walk geometric ladders, 1-2 exps per input instead of G: from a centre c_a
# next to x, on the uniform grid c_a + (m - a)Δ, Δ = (c_{G-1} - c_0)/(G - 1) rounded to float32,
# δ = Δ/h, the ladder distances are d̃_m = d_a - (m - a)δ, d_a = (x - c_a)/h. The centres are
# float32 values off the uniform grid c_0 + mΔ by hε_m (~1e-7 relative, or 0; ε_m is exact to
# its last rounding, c_0 + mΔ being exact): factors exp(t), |t| tiny (_exp_small), carry the
# ladder values onto d_m = d̃_m - (ε_m - ε_a). Inputs more than Δ outside the grid, NaN, and
# grids the ladders do not hold on (_uniform_grid) take the direct formula.

@_kernel
def _uniform_grid(centres: NDArray, h: float, kind: int) -> tuple[float, float, bool]:
    """(Δ, δ, ladder): the ladders' spacing (a float32, so that c_0 + mΔ is exact), δ = Δ/h, and
    whether the ladders of family ``kind`` hold: every |t| <= _LADDER_TOL, with ε the largest
    |ε_m|: GRBF |t| <= 2ε (min(Gδ, 40) + 1) (beyond |d̃| = 40 the bases underflow to 0 anyway),
    RSWAF |t| <= 4ε; and δ <= 20 (neighbouring bases that hardly overlap; the ratios could
    underflow)."""
    n_c = centres.shape[0]
    step = np.float64(np.float32((centres[n_c - 1] - centres[0]) / (n_c - 1)))
    delta = step / h
    eps = 0.0
    for m in range(n_c):
        eps = max(eps, abs(_offset(centres, m, step, h)))
    t_max = 2.0 * eps * (min(n_c * delta, 40.0) + 1.0) if kind == GRBF else 4.0 * eps
    return step, delta, t_max <= _LADDER_TOL and delta <= 20.0


@_kernel
def _offset(centres: NDArray, m: int, step: float, h: float) -> float:
    """ε_m = (c_m - (c_0 + mΔ))/h."""
    return (centres[m] - (centres[0] + m * step)) / h


@_kernel
def _exp_small(t: float) -> float:
    """exp(t) for |t| <= _LADDER_TOL: 1 + t + t²/2 + t³/6 + t⁴/24."""
    return 1.0 + t * (1.0 + t * (0.5 + t * (1.0 / 6.0 + t * (1.0 / 24.0))))


@_kernel
def gaussian_bases(x: NDArray, centres: NDArray, h: float, phi: NDArray) -> None:
    """phi[i, m] = exp(-d²/2), d = (x_i - c_m)/h, for inputs x (n,) and the G centres, with 2
    exps per input: from the nearest centre c_k, g_{k±n} = exp(-d̃_{k±n}²/2) = g_k (r^±)^n Q_n,
    r^± = exp(±δ d_k - δ²/2), Q_n = exp(-δ² n(n - 1)/2) (all <= 1 where walked: far terms
    underflow to 0 as they should, and rounding errors grow as n, not n²). Then
    exp(-d_m²/2) = g_m exp(t), t = e (d̃_m - e/2), e = ε_m - ε_k."""
    n_c = centres.shape[0]
    c0, c_last = centres[0], centres[n_c - 1]
    step, delta, ladder = _uniform_grid(centres, h, GRBF)
    lad = np.empty((3, n_c))                        # ε_m, mδ, Q_m
    for m in range(n_c):
        lad[0, m] = _offset(centres, m, step, h)
        lad[1, m] = m * delta
        lad[2, m] = np.exp(-0.5 * delta * delta * m * (m - 1))
    q, inv_step = np.exp(-delta * delta), 1.0 / step
    for i in range(x.shape[0]):
        xi = x[i]
        row = phi[i]
        if not (ladder and c0 - step <= xi <= c_last + step):
            for m in range(n_c):
                d = (xi - centres[m]) / h
                row[m] = np.exp(-0.5 * d * d)
            continue
        k = min(max(int(np.rint((xi - c0) * inv_step)), 0), n_c - 1)
        dk = (xi - centres[k]) / h
        g = np.exp(-0.5 * dk * dk)
        row[k] = g
        r = np.exp(delta * dk - 0.5 * delta * delta)
        v = g
        for n in range(1, n_c - k):
            v *= r
            row[k + n] = v * lad[2, n]
        r = q / r                                   # r^- = exp(-δ²)/r^+
        v = g
        for n in range(1, k + 1):
            v *= r
            row[k - n] = v * lad[2, n]
        eps_k, dk0 = lad[0, k], dk + lad[1, k]                # d̃_m = dk0 - mδ
        for m in range(n_c):
            e = lad[0, m] - eps_k
            row[m] *= _exp_small(e * (dk0 - lad[1, m] - 0.5 * e))


@_kernel
def sech2_bases(x: NDArray, centres: NDArray, h: float, phi: NDArray) -> None:
    """phi[i, m] = 1 - tanh²(d) = sech²(d) = 4e/(1 + e)², e = exp(-2|d|), d = (x_i - c_m)/h, for
    inputs x (n,) and the G centres (no cancellation in the tails), with 1 exp per input:
    ẽ_m = exp(-2|d̃_m|) is geometric with ratio exp(-2δ) walking away from x on either side, d̃
    from c_a, a = j the first ladder point above x (j = G: none, a = G - 1). Then
    |d_m| = |d̃_m| ± (ε_m - ε_a) (+ above x) gives e_m = ẽ_m exp(∓2ε_m) exp(±2ε_a). (Where x is
    within ~1e-7 of a centre that sign may be the other one: it gives 1/e_m, whose sech² is the
    same.)"""
    n_c = centres.shape[0]
    c0, c_last = centres[0], centres[n_c - 1]
    step, delta, ladder = _uniform_grid(centres, h, RSWAF)
    lad = np.empty((2, n_c))                        # exp(-2ε_m), exp(2ε_m)
    for m in range(n_c):
        lad[0, m] = _exp_small(-2.0 * _offset(centres, m, step, h))
        lad[1, m] = _exp_small(2.0 * _offset(centres, m, step, h))
    q = np.exp(-2.0 * delta)
    inv_step = 1.0 / step
    for i in range(x.shape[0]):
        xi = x[i]
        row = phi[i]
        if not (ladder and c0 - step <= xi <= c_last + step):
            for m in range(n_c):
                row[m] = np.exp(-2.0 * abs((xi - centres[m]) / h))
        else:
            j = min(max(int(np.floor((xi - c0) * inv_step)) + 1, 0), n_c)
            a = min(j, n_c - 1)
            e = np.exp(2.0 * ((xi - centres[a]) / h - (j - a) * delta))   # ẽ_j, d̃_j <= 0
            v = e * lad[1, a]
            for m in range(j, n_c):
                row[m] = v * lad[0, m]
                v *= q
            v = q / e * lad[0, a]
            for m in range(j - 1, -1, -1):
                row[m] = v * lad[1, m]
                v *= q
        for m in range(n_c):
            e = row[m]
            row[m] = 4.0 * e / ((1.0 + e) * (1.0 + e))


@_kernel
def radial_bases(x: NDArray, centres: NDArray, h: float, kind: int, phi: NDArray) -> None:
    """phi[i, m] = ψ_m(x_i) for inputs x (n,), the G centres c_m and width h, d = (x - c_m)/h:
    GRBF exp(-d²/2) (``kind`` = GRBF, gaussian_bases) or RSWAF 1 - tanh²(d) (``kind`` = RSWAF,
    sech2_bases)."""
    if kind == GRBF:
        gaussian_bases(x, centres, h, phi)
    else:
        sech2_bases(x, centres, h, phi)


@_kernel
def radial_kan_layer(x: NDArray, y: NDArray, n_i: int, n_o: int, params: NDArray,
                     offsets: NDArray, centres: NDArray, h: float, kind: int,
                     phi: NDArray) -> None:
    """y[:n_o] = Φ(x[:n_i]) of a GRBF or RSWAF KAN layer: y_j = Σ_i Σ_m θ_jim ψ_m(x_i), the
    bases of all inputs, phi[i·G + m] = ψ_m(x_i), times the edge weights (I·G, O)."""
    n_c = centres.shape[0]
    n = n_i * n_c
    radial_bases(x[:n_i], centres, h, kind, phi[:n].reshape(n_i, n_c))
    y[:n_o] = 0.0
    _add_rows(y, phi, _block(params, offsets[1], n, n_o), 0, n)


@_kernel
def mlp_layer(x: NDArray, y: NDArray, n_i: int, n_o: int, params: NDArray, offsets: NDArray,
              kind: int, hidden: bool) -> None:
    """y[:n_o] = act(W x[:n_i] + b), act = ReLU or GELU 0.5 v (1 + erf(v/√2)) on hidden layers,
    none on the output layer. Zero inputs (after a ReLU) are skipped."""
    w = _block(params, offsets[1], n_i, n_o)
    y[:n_o] = _block(params, offsets[2], 1, n_o)[0]
    for i in range(n_i):
        if x[i] != 0.0:
            _add_row(y, x[i], w, i)
    if hidden:
        for j in range(n_o):
            v = y[j]
            y[j] = v * 0.5 * (1.0 + math.erf(v * _SQRT1_2)) if kind == GELU else max(v, 0.0)


@nb.njit(cache=True, error_model="numpy")
def network_forward(z: NDArray, kind: int, widths: NDArray, offsets: NDArray, params: NDArray,
                    grid: NDArray, order: int, h: float) -> NDArray:
    """Network output (before the target de-normalisation) of z-scored features z (B, n_in) ->
    (B,): the layers of family ``kind`` in turn, a LayerNorm first where ``offsets[l, 0] >= 0``.
    ``params``: the packed tensors (float32 or float64); ``grid``: the knots (B-spline KAN) or
    centres (radial KAN; unused by MLPs); ``order``: the B-spline order; ``h``: the radial basis
    width."""
    n_layers = widths.shape[0] - 1
    n_max = widths.max()
    x = np.empty(n_max)
    y = np.empty(n_max)
    if kind == BSPLINE:
        phi = np.empty(order + 1)
    elif kind == GRBF or kind == RSWAF:
        phi = np.empty(n_max * grid.shape[0])
    else:
        phi = np.empty(0)
    out = np.empty(z.shape[0])
    for b in range(z.shape[0]):
        for i in range(widths[0]):
            x[i] = z[b, i]
        for l in range(n_layers):
            n_i, n_o = widths[l], widths[l + 1]
            if offsets[l, 0] >= 0:
                _layer_norm(x, n_i, _block(params, offsets[l, 0], 2, n_i))
            if kind == BSPLINE:
                bspline_kan_layer(x, y, n_i, n_o, params, offsets[l], grid, order, phi)
            elif kind == GRBF or kind == RSWAF:
                radial_kan_layer(x, y, n_i, n_o, params, offsets[l], grid, h, kind, phi)
            else:
                mlp_layer(x, y, n_i, n_o, params, offsets[l], kind, l < n_layers - 1)
            x, y = y, x
        out[b] = x[0]
    return out


def _aligned_zeros(n: int, dtype: Any, align: int = 64) -> NDArray:
    """Zeros (n,) of ``dtype`` whose data starts on an ``align``-byte boundary."""
    itemsize = np.dtype(dtype).itemsize
    buf = np.zeros(n * itemsize + align, dtype=np.uint8)
    start = -buf.ctypes.data % align
    return buf[start:start + n * itemsize].view(dtype)


@nb.njit(cache=True)
def log_shift_kernel(x_d: NDArray, x_c: NDArray, code: int, tau_prev: float, mean: NDArray,
                     inv_std: NDArray, target_mean: float, target_std: float, relative: bool,
                     z: NDArray, net_args: tuple) -> float:
    """NN(features(x_d, x_c, τ_{k-1})): ln|τ| (s) in one compiled call (features, z-score into
    the (1, n_in) buffer z, network, target scale, plus ln|τ_{k-1}| for a ``relative``
    (log-ratio) network), so an update pays one dispatch. It lives here, beside
    network_forward, because numba rebuilds a cached function only when its own file changes:
    compiled elsewhere it could keep an old forward."""
    features_into(x_d, x_c, code, tau_prev, z[0])
    n = z.shape[1]
    offset = z[0, n - 1] if relative else 0.0   # the raw ln|τ_{k-1}| feature (-inf at τ_{k-1} = 0)
    for i in range(n):
        z[0, i] = (z[0, i] - mean[i]) * inv_std[i]
    return target_mean + target_std * network_forward(z, *net_args)[0] + offset


class NumpyNet:
    """float64 inference forward of a network given its tensors (names as ``Arch.tensor_shapes``),
    packed once here and run by :func:`network_forward`; the torch modules stay the training path."""

    def __init__(self, arch: Arch, tensors: Mapping[str, NDArray]) -> None:
        self.arch = arch
        t = {k: np.asarray(v, dtype=np.float64) for k, v in tensors.items()}
        self.feature_mean = t["feature_mean"].copy()
        self.feature_inv_std = 1.0 / t["feature_std"]
        self.target_mean = float(t["target_mean"][0])
        self.target_std = float(t["target_std"][0])
        #: The target is ln(|τ| / |τ_{k-1}|) (Arch.target "log-ratio"), not ln|τ|.
        self.relative = arch.relative
        self._n_in = arch.n_in
        kind = FAMILIES.index(arch.family)
        # The torch modules hold grids as float32 buffers: use the same values here.
        grid = (arch.knots() if kind == BSPLINE else arch.centres()).astype(np.float32)
        h = arch.basis_width if kind in (GRBF, RSWAF) else 0.0
        self._args = (kind, *self._pack(t), grid.astype(np.float64), arch.order, float(h))
        #: The arguments of :func:`network_forward` after z (for callers compiled with numba).
        self.kernel_args = self._args
        # Compile (or load from numba's cache) here, at model load, not at the first update.
        network_forward(np.zeros((1, arch.n_in)), *self._args)

    def _pack(self, t: Mapping[str, NDArray]) -> tuple[NDArray, NDArray, NDArray]:
        """(widths, offsets, params) of :func:`network_forward`: every tensor once, row-major in
        one flat array, each block from a 64-byte boundary; float32 when every value is a float32
        value (exact: trained weights; B-spline KANs pack products α·c, float64)."""
        a = self.arch
        blocks: dict[tuple[int, int], NDArray] = {}     # (layer, offsets column) -> block
        for l in range(a.layers):
            pre = f"layers.{l}."
            if a.layer_norm_on(l):
                blocks[l, 0] = np.stack([t[pre + "norm.weight"], t[pre + "norm.bias"]])
            if a.family == "cikan":
                eff = t[pre + "spline_weight"] * t[pre + "spline_scaler"][..., None]
                blocks[l, 1] = eff.reshape(eff.shape[0], -1).T           # (I·M, O)
                blocks[l, 2] = t[pre + "base_weight"].T                   # (I, O)
            elif a.is_kan:
                coef = t[pre + "coef"]
                blocks[l, 1] = coef.reshape(coef.shape[0], -1).T          # (I·M, O)
            else:
                blocks[l, 1] = t[pre + "weight"].T                        # (I, O)
                blocks[l, 2] = t[pre + "bias"][None, :]                   # (1, O)
        exact32 = all(np.array_equal(b.astype(np.float32), b) for b in blocks.values())
        dtype = np.float32 if exact32 else np.float64
        align = 64 // np.dtype(dtype).itemsize
        offsets = np.full((a.layers, 3), -1, dtype=np.int64)
        size = 0
        for (l, col), block in blocks.items():
            offsets[l, col] = size
            size += -(-block.size // align) * align
        params = _aligned_zeros(size, dtype)
        for (l, col), block in blocks.items():
            params[offsets[l, col]:offsets[l, col] + block.size] = block.ravel()
        return np.array(a.widths, dtype=np.int64), offsets, params

    def normalise(self, feats: NDArray) -> NDArray:
        """z-score raw features (..., n_in) with the training statistics."""
        return (feats - self.feature_mean) * self.feature_inv_std

    def log_shift(self, feats: NDArray) -> NDArray:
        """ln|τ| (s) predictions for raw features (B, n_in) -> (B,): the target
        (:meth:`forward` of the z-scored features) plus ln|τ_{k-1}| for a log-ratio network."""
        feats = np.asarray(feats, dtype=np.float64)
        return self.forward(self.normalise(feats)) + self.arch.log_shift_offset(feats)

    def forward(self, z: NDArray) -> NDArray:
        """Target predictions (ln|τ|, or ln(|τ| / |τ_{k-1}|) for a log-ratio network) for
        z-scored features z (B, n_in) -> (B,)."""
        z = np.ascontiguousarray(z, dtype=np.float64)
        if z.ndim != 2 or z.shape[1] != self._n_in:
            raise ValueError(f"features must have shape (B, {self._n_in}), got {z.shape}")
        return self.target_mean + self.target_std * network_forward(z, *self._args)

    def forward_one(self, z: NDArray) -> float:
        """The target (as :meth:`forward`) for one z-scored feature vector z (n_in,): the batch
        kernel on a (1, n_in) view."""
        z = np.ascontiguousarray(z, dtype=np.float64)
        if z.shape != (self._n_in,):
            raise ValueError(f"features must have shape ({self._n_in},), got {z.shape}")
        return self.target_mean + self.target_std * float(network_forward(z.reshape(1, -1), *self._args)[0])
