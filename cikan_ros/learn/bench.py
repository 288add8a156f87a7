"""The learned governors' section of ``cikan bench`` (appended to ``cikan_ros.bench.SECTIONS``).

Per shipped model ``<m>`` in ``models/``, on the same active-phase update states as the
conventional TSG and in the same run:

- ``<m>_update_ms_mean`` / ``<m>_update_ms_max``: wall time of one whole update (network,
  Verify, any bisection), median of ``repeats`` per state, then mean / max over states;
- ``<m>_speedup_mean`` = conventional mean / learned mean, ``<m>_speedup_worst`` = conventional
  max / learned max, the conventional TSG being timed again in this section, interleaved state
  by state with the learned ones (``learned_conventional_update_ms_mean`` / ``_max``);
- ``<m>_nn_accept_rate``: fraction of these updates whose network proposal passed Verify and was
  returned (path "nn"; every state here consults the network since tau_prev < 0);
- ``<m>_verify_calls_mean``, ``<m>_forward_us_mean`` (features + network alone),
  ``<m>_rmse_tau_s``: RMSE of the learned answer against pi* at the same state (both from the same
  tau_prev);
- ``dataset_labels_per_s``: label generation rate of ``cikan dataset`` in this process (one core,
  kernels warm), over a fixed set of missions.
"""

from __future__ import annotations

import json
import statistics
import time
from typing import Any

import numpy as np

from ..bench import BenchStates
from ..config import Config
from ..governor import LEARNED_NAMES, PATH_NN, ConventionalGovernor
from ..tsg import Predictor
from .errors import ModelFileError

_PREDICTOR: dict[str, Predictor] = {}


def _predictor(cfg: Config) -> Predictor:
    key = json.dumps(cfg.flat(), sort_keys=True)
    if key not in _PREDICTOR:
        _PREDICTOR[key] = Predictor.from_config(cfg)
    return _PREDICTOR[key]


def dataset_rate(cfg: Config, pred: Predictor, missions: int = 8) -> dict[str, Any]:
    """Labels per second of the generator in this process (first mission excluded: warm-up)."""
    from . import dataset

    key = json.dumps(cfg.flat(), sort_keys=True)
    dataset._PREDICTORS[key] = pred
    spec = dataset.DatasetSpec(seed=0)
    dataset.label_missions(key, spec, [0])
    start = time.perf_counter()
    out = dataset.label_missions(key, spec, list(range(1, missions + 1)))
    wall = time.perf_counter() - start
    n = sum(r["n"] for r in out)
    return {"dataset_labels_per_s": n / wall, "dataset_bench_labels": n, "dataset_bench_workers": 1}


def interleaved_times(governors: list[Any], states: BenchStates, repeats: int
                      ) -> list[tuple[np.ndarray, np.ndarray, list[str], np.ndarray]]:
    """Per governor: per-state median wall time (s), tau, path, Verify calls, with the governors
    timed in turn on each state (round-robin, ``repeats`` rounds) so a change of machine load
    during the run hits all of them alike."""
    n = len(states.updates)
    walls = [np.empty(n) for _ in governors]
    taus = [np.empty(n) for _ in governors]
    calls = [np.empty(n) for _ in governors]
    paths: list[list[str]] = [[] for _ in governors]
    for i, s in enumerate(states.updates):
        runs: list[list[Any]] = [[] for _ in governors]
        for _ in range(repeats):
            for g, gov in enumerate(governors):
                runs[g].append(gov.update(s.x_d, s.x_c, s.t, s.tau_prev))
        for g in range(len(governors)):
            walls[g][i] = statistics.median(r.wall_s for r in runs[g])
            taus[g][i] = runs[g][0].tau_s
            calls[g][i] = runs[g][0].verify_calls
            paths[g].append(runs[g][0].path)
    return list(zip(walls, taus, paths, calls))


def learned_section(cfg: Config, states: BenchStates, repeats: int) -> dict[str, Any]:
    """Figures of every shipped learned governor on the benchmark's update states.

    The conventional TSG is timed again here, interleaved state by state with the learned
    governors (:func:`interleaved_times`); the speed-ups use those times. The conventional
    section's own figures stay as they are."""
    from .governor import load_learned_governor

    pred = _predictor(cfg)
    govs: list[Any] = []
    out: dict[str, Any] = {}
    missing = []
    for name in LEARNED_NAMES:
        try:
            govs.append(load_learned_governor(name, pred))
        except ModelFileError as exc:
            missing.append(f"{name}: {exc}")
    results = interleaved_times([ConventionalGovernor(pred)] + govs, states, repeats)
    conv_walls, conv_taus = results[0][0], results[0][1]
    out["learned_conventional_update_ms_mean"] = float(conv_walls.mean() * 1e3)
    out["learned_conventional_update_ms_max"] = float(conv_walls.max() * 1e3)
    for gov, (walls, taus, paths, calls) in zip(govs, results[1:]):
        name = gov.name
        fwd = []
        for s in states.updates:
            runs = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                gov.proposal(s.x_d, s.x_c)
                runs.append(time.perf_counter() - t0)
            fwd.append(statistics.median(runs))
        out.update({
            f"{name}_update_ms_mean": float(walls.mean() * 1e3),
            f"{name}_update_ms_max": float(walls.max() * 1e3),
            f"{name}_speedup_mean": float(conv_walls.mean() / walls.mean()),
            f"{name}_speedup_worst": float(conv_walls.max() / walls.max()),
            f"{name}_nn_accept_rate": paths.count(PATH_NN) / len(paths),
            f"{name}_verify_calls_mean": float(calls.mean()),
            f"{name}_forward_us_mean": float(np.mean(fwd) * 1e6),
            f"{name}_rmse_tau_s": float(np.sqrt(np.mean((taus - conv_taus) ** 2))),
        })
    if missing:
        out["learned_models_missing"] = missing
    out.update(dataset_rate(cfg, pred))
    return out
