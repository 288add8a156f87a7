"""Network inputs (SPEC §7): 12 features of (x_d, x_c) computed in float64, then z-scored.

Feature sets (named in every model card):

- ``"eci"``: (x_d - x_c, x_c) in ECI, km and km/s: the SPEC's default inputs.
- ``"vnb"``: the relative state x_d - x_c rotated into the chief's VNB frame (SPEC §1: x̂ along
  v_c, ŷ = r_c × x̂ normalised, ẑ = x̂ × ŷ), then x_c in ECI. Same information (the rotation is a
  function of x_c), but the line-of-sight cone is fixed in this frame, so the map is simpler.
- ``"vnb-prev"``: ``"vnb"`` and ln|τ_{k-1}| (s) as a 13th input. π* at update k is the search's
  answer over [τ_{k-1}, 0] (SPEC §5, §8), so it depends on τ_{k-1}, which the state alone does not
  show; this set lets a network see it.

Raw ECI positions in float32 cannot resolve metre offsets, hence float64 until after z-scoring.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray


FEATURE_SETS = ("eci", "vnb", "vnb-prev")
#: State features of every set; "vnb-prev" adds ln|τ_{k-1}|.
N_FEATURES = 12


def n_features(kind: str) -> int:
    """Number of network inputs of a feature set."""
    if kind not in FEATURE_SETS:
        raise ValueError(f"unknown feature set {kind!r}; known: {FEATURE_SETS}")
    return N_FEATURES + (kind == "vnb-prev")


def uses_tau_prev(kind: str) -> bool:
    """Does the feature set take τ_{k-1} as an input?"""
    return kind == "vnb-prev"


def features(x_d: ArrayLike, x_c: ArrayLike, kind: str = "vnb", tau_prev: ArrayLike | None = None
             ) -> NDArray:
    """Features of states x_d, x_c (..., 6) [km, km/s] (and τ_{k-1} (...) != 0 [s] for
    ``"vnb-prev"``) -> (..., n_features(kind)) float64."""
    x_d = np.asarray(x_d, dtype=np.float64)
    x_c = np.asarray(x_c, dtype=np.float64)
    rel = x_d - x_c
    if kind == "eci":
        return np.concatenate([rel, x_c], axis=-1)
    if kind in ("vnb", "vnb-prev"):
        from ..orbit import vnb_frame  # numba-backed; imported on use so the CLI starts fast

        rot = vnb_frame(x_c)                                     # (..., 3, 3)
        p = np.einsum("...ij,...j->...i", rot, rel[..., :3])
        v = np.einsum("...ij,...j->...i", rot, rel[..., 3:])
        if kind == "vnb":
            return np.concatenate([p, v, x_c], axis=-1)
        if tau_prev is None:
            raise ValueError("feature set 'vnb-prev' needs tau_prev")
        lp = np.log(np.abs(np.asarray(tau_prev, dtype=np.float64)))[..., None]
        return np.concatenate([p, v, x_c, np.broadcast_to(lp, p.shape[:-1] + (1,))], axis=-1)
    raise ValueError(f"unknown feature set {kind!r}; known: {FEATURE_SETS}")


#: Feature-set codes of the compiled single-sample path (:func:`features_into`).
FEATURE_CODES = {kind: code for code, kind in enumerate(FEATURE_SETS)}
ECI, VNB, VNB_PREV = range(len(FEATURE_SETS))


@nb.njit(cache=True)
def features_into(x_d: NDArray, x_c: NDArray, code: int, tau_prev: float, out: NDArray) -> None:
    """Single-sample :func:`features` of x_d, x_c (6,) [km, km/s] into ``out``
    (n_features,), feature set by ``code`` (FEATURE_CODES), with scalar arithmetic: a governor
    update pays no small-array overhead. Equal to :func:`features` to rounding."""
    r0, r1, r2, w0, w1, w2 = x_c[0], x_c[1], x_c[2], x_c[3], x_c[4], x_c[5]
    if code == ECI:
        for i in range(6):
            out[i] = x_d[i] - x_c[i]
    else:
        nv = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        a0, a1, a2 = w0 / nv, w1 / nv, w2 / nv                    # x̂ along v_c
        b0, b1, b2 = r1 * a2 - r2 * a1, r2 * a0 - r0 * a2, r0 * a1 - r1 * a0
        nb_ = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        b0, b1, b2 = b0 / nb_, b1 / nb_, b2 / nb_                  # ŷ = r_c × x̂, normalised
        c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0   # ẑ = x̂ × ŷ
        for o in (0, 3):
            d0, d1, d2 = x_d[o] - x_c[o], x_d[o + 1] - x_c[o + 1], x_d[o + 2] - x_c[o + 2]
            out[o] = a0 * d0 + a1 * d1 + a2 * d2
            out[o + 1] = b0 * d0 + b1 * d1 + b2 * d2
            out[o + 2] = c0 * d0 + c1 * d1 + c2 * d2
    for i in range(6):
        out[6 + i] = x_c[i]
    if code == VNB_PREV:
        # ln|τ_{k-1}| (either side of the chief): -inf at 0 makes the proposal unusable.
        out[12] = math.log(abs(tau_prev)) if tau_prev != 0.0 else -math.inf


def features_one(x_d: ArrayLike, x_c: ArrayLike, kind: str, out: NDArray, tau_prev: float = math.nan
                 ) -> NDArray:
    """Single-sample :func:`features` into ``out`` (n_features(kind),) (see :func:`features_into`)."""
    if kind not in FEATURE_CODES:
        raise ValueError(f"unknown feature set {kind!r}; known: {FEATURE_SETS}")
    features_into(np.asarray(x_d, dtype=np.float64), np.asarray(x_c, dtype=np.float64),
                  FEATURE_CODES[kind], float(tau_prev), out)
    return out


def fit_normalisation(feats: NDArray) -> tuple[NDArray, NDArray]:
    """Mean and standard deviation (12,) of training features; a constant feature gets std 1."""
    mean = feats.mean(axis=0)
    std = feats.std(axis=0)
    std = np.where(std > 0, std, 1.0)
    return mean, std
