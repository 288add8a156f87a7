"""The learned Time Shift Governor: Algorithm 1 of the paper, made precise in SPEC §8.

update(x_d, x_c, t_k, τ_prev):
  τ_prev == 0                 -> 0, no prediction (recursive feasibility)           [path "zero"]
  τ_c = quantise(-exp(NN(z(x_d, x_c))))   (whole nanoseconds, so the verified shift is returned)
  τ_prev <= τ_c <= 0, Verify(τ_c)   -> τ_c                                          [path "nn"]
  τ_prev <= τ_c <= 0, not Verify    -> bisect(lo = τ_prev, hi = τ_c)                 [path "nn+bisect"]
  otherwise (or NN not finite)      -> bisect(lo = τ_prev, hi = 0)                   [path "bisect"]
  then, if τ < 0 and |τ| <= tsg.zero_snap_s and Verify(0): τ = 0                     [path "verify-zero"]

Whatever the network outputs, the answer passed Verify or is τ_prev (the bisection keeps a
verified lower end, τ_prev being feasible by recursive feasibility): a wrong network costs time,
never safety. The first shift comes from the conventional initial search.

No torch here: the network runs through :class:`cikan_ros.learn.arch.NumpyNet`.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Iterable

import numpy as np
from numpy.typing import ArrayLike

from ..governor import (PATH_BISECT, PATH_INITIAL, PATH_NN, PATH_NN_BISECT, PATH_VERIFY_ZERO,
                        PATH_ZERO, UpdateRecord, initial_update)
from ..tsg import Predictor, quantise_shift
from .arch import NumpyNet
from .features import features_one
from .modelfile import LoadedModel, load_model

#: ln|τ| above this (|τ| > ~1.4e17 s) is treated like a non-finite output: out of range.
MAX_LOG_SHIFT = 40.0


class LearnedGovernor:
    """Algorithm 1 with a network π̃_θ (ln|τ| from z-scored features) and Verify/bisection fallback."""

    def __init__(self, net: NumpyNet, predictor: Predictor, name: str = "learned") -> None:
        self.net = net
        self.predictor = predictor
        self.name = name
        self._feat = np.empty(12)
        self._kind = net.arch.features

    @classmethod
    def from_model(cls, model: LoadedModel, predictor: Predictor, name: str | None = None
                   ) -> "LearnedGovernor":
        return cls(NumpyNet(model.arch, model.tensors), predictor, name or model.arch.family)

    def log_shift(self, x_d: ArrayLike, x_c: ArrayLike) -> float:
        """NN(features): predicted ln|τ| (s) at states x_d, x_c (km, km/s)."""
        f = features_one(np.asarray(x_d, dtype=float), np.asarray(x_c, dtype=float), self._kind,
                         self._feat)
        return self.net.forward_one(self.net.normalise(f))

    def proposal(self, x_d: ArrayLike, x_c: ArrayLike) -> float:
        """τ_c = -exp(NN) on the nanosecond grid; NaN if the network's output is not usable."""
        y = self.log_shift(x_d, x_c)
        if not (math.isfinite(y) and y <= MAX_LOG_SHIFT):
            return math.nan
        return quantise_shift(-math.exp(y))

    def initial(self, x_d: ArrayLike, x_c: ArrayLike, t: float) -> UpdateRecord:
        return initial_update(self.predictor, x_d, t)

    def update(self, x_d: ArrayLike, x_c: ArrayLike, t: float, tau_prev: float) -> UpdateRecord:
        start = time.perf_counter()
        pred = self.predictor
        if tau_prev == 0.0:
            return UpdateRecord(0.0, PATH_ZERO, 0, time.perf_counter() - start)
        tau_c = self.proposal(x_d, x_c)
        cache = pred.cache(t)  # chief states along the horizon, shared by this update's predictions
        calls = 0
        if tau_prev <= tau_c <= 0.0:
            calls += 1
            if pred.verify(x_d, t, tau_c, cache):
                tau, path = tau_c, PATH_NN
            else:
                tau, c = pred.bisect(x_d, t, tau_prev, tau_c, cache)
                calls += c
                path = PATH_NN_BISECT
        else:
            tau, c = pred.bisect(x_d, t, tau_prev, 0.0, cache)
            calls += c
            path = PATH_BISECT
        if tau < 0.0 and -tau <= pred.config.tsg.zero_snap_s:
            calls += 1
            if pred.verify(x_d, t, 0.0, cache):
                tau, path = 0.0, PATH_VERIFY_ZERO
        return UpdateRecord(tau, path, calls, time.perf_counter() - start)


def nn_accept_rate(updates: Iterable[UpdateRecord]) -> float | None:
    """Fraction of the updates that consulted the network (every path but "zero") whose proposal
    passed Verify and was returned (path "nn"). None when the network was never consulted.

    A proposal that passed Verify and was then snapped to 0 by the zero test counts as not
    accepted (its path is "verify-zero"); this happens at most once per mission."""
    consulted = [r.path for r in updates if r.path not in (PATH_ZERO, PATH_INITIAL)]
    return consulted.count(PATH_NN) / len(consulted) if consulted else None


def load_learned_governor(name: str, predictor: Predictor) -> LearnedGovernor:
    """The learned governor of a shipped family (``cikan``, ``grbf``, ``rswaf``, ``relu``,
    ``gelu`` -> ``models/<name>/``) or of a model directory/file. Raises ModelFileError."""
    model = load_model(name)
    label = name if name in ("cikan", "grbf", "rswaf", "relu", "gelu") else \
        f"{model.arch.family}:{Path(model.path).name}"
    return LearnedGovernor.from_model(model, predictor, label)
