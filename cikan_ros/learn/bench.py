"""The learned governors' section of ``cikan bench`` (after ``cikan_ros.bench``'s sections).

Per shipped model ``<m>`` in ``models/``, on the same active-phase update states as the
conventional TSG and in the same run, under the default update rule (``learned.algorithm``,
"keep" unless configured otherwise):

- ``<m>_update_ms_mean`` / ``<m>_update_ms_max``: wall time of one whole update (network,
  Verify, any bisection; CPU time of the thread, see ``cikan_ros.bench``), median of
  ``repeats`` per state, then mean / max over states;
- ``<m>_speedup_mean`` = conventional mean / learned mean, ``<m>_speedup_worst`` = conventional
  max / learned max, the conventional TSG being timed again in this section, interleaved state
  by state with the learned ones (``learned_conventional_update_ms_mean`` / ``_max``);
- ``<m>_nn_accept_rate``: share of these updates whose network proposal passed Verify and was
  returned (path "nn"); ``<m>_hold_rate``: share answered with tau_{k-1} itself;
  ``<m>_no_search_rate``: share answered without any bisection (paths "nn" and "keep");
- ``<m>_verify_calls_mean`` / ``<m>_verify_calls_max``, ``<m>_forward_us_mean`` (features +
  network alone), ``<m>_rmse_tau_s``: RMSE of the answer against pi* at the same state (same
  tau_prev, same anchored chief: the conventional TSG's answer in the same rounds);
- ``<m>_paper_update_ms_mean`` / ``_max``, ``<m>_paper_speedup_mean`` / ``_worst``,
  ``<m>_paper_verify_calls_mean``: the same network under the other rule (the paper's
  Algorithm 1 when the default is "keep"), timed in the same interleaved rounds;
- under a non-nominal truth or robust Verify, the same figures on the states of missions flown
  under it, every timed update anchoring the chief as the mission did (``cikan_ros.timing``);
- the per-state figures above time the network's path: the keep rule's trust (a mission starts
  searching like the conventional TSG until the network earns trust) is granted before each
  timed update. What missions cost as flown, trust included: ``<m>_mission_update_ms_mean``
  (CPU time of the active updates of the governor's own missions from the benchmark's starts),
  ``<m>_mission_speedup_mean``: the mean over the benchmark's starts of the speed-up of the
  whole mission (the conventional TSG's active CPU from the same start, flown in turn with it,
  over the governor's), ``<m>_mission_speedup_worst`` (the worst single mission),
  ``<m>_mission_cpu_speedup`` (all starts' CPU pooled), ``<m>_flown_update_speedup`` (the ratio
  per active update as flown: it flatters a governor that lags π* and flies more of the cheap
  updates near τ = 0),
  ``<m>_mission_verify_calls_mean``, ``<m>_search_rate``: the share of those updates answered by
  searching (:data:`cikan_ros.governor.SEARCHING_PATHS`), and ``<m>_mission_nn_accept_rate``
  (:func:`mission_figures`); ``cikan bench`` shows these first;
- ``learned_foreign_models``: the models flown with ``learned.foreign_model`` (made for another
  scenario, side or Verify: :func:`cikan_ros.learn.governor.load_learned_governor`) and why;
  without it such models are refused and listed in ``learned_models_missing``;
- ``dataset_labels_per_s``: label generation rate of ``cikan dataset`` in this process (one core,
  kernels warm), over a fixed set of missions.
"""

from __future__ import annotations

import json
import os
import statistics
import time
from typing import Any

import numpy as np

from ..config import Config
from ..governor import PATH_KEEP, PATH_NN, ConventionalGovernor
from ..mission import rmse
from ..registry import LEARNED_NAMES
from ..timing import BenchStates, median_thread_time, timed_update
from ..tsg import Predictor
from .errors import ModelFileError
from .modelfile import MODELS_DIR

_PREDICTOR: dict[str, Predictor] = {}
#: Paths that answer without any bisection.
NO_SEARCH_PATHS = (PATH_NN, PATH_KEEP)


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
    """Per governor: per-state median CPU time (s), tau, path, Verify calls, with the governors
    timed in turn on each state (round-robin, ``repeats`` rounds) so a change of machine load
    during the run hits all of them alike. Each timed update starts from the chief anchor the
    mission's governor held before it (``cikan_ros.timing``), so re-anchoring is paid each time."""
    n = len(states.updates)
    walls = [np.empty(n) for _ in governors]
    taus = [np.empty(n) for _ in governors]
    calls = [np.empty(n) for _ in governors]
    paths: list[list[str]] = [[] for _ in governors]
    for i, (s, prior, progress) in enumerate(zip(states.updates, states.priors, states.progress)):
        runs: list[list[Any]] = [[] for _ in governors]
        for _ in range(repeats):
            for g, gov in enumerate(governors):
                if hasattr(gov, "trust"):
                    gov.trust.grant()   # time the network's path (mission_figures: as flown)
                runs[g].append(timed_update(gov, s, prior, progress))
        for g in range(len(governors)):
            walls[g][i] = statistics.median(cpu for _, cpu in runs[g])
            rec = runs[g][0][0]
            taus[g][i], calls[g][i] = rec.tau_s, rec.verify_calls
            paths[g].append(rec.path)
    for gov in governors:
        gov.anchor.current = gov.anchor.base
    return list(zip(walls, taus, paths, calls))


def _rule_figures(prefix: str, walls: np.ndarray, taus: np.ndarray, paths: list[str],
                  calls: np.ndarray, conv_walls: np.ndarray, errors: np.ndarray,
                  tau_prev: np.ndarray) -> dict[str, Any]:
    return {
        f"{prefix}_update_ms_mean": float(walls.mean() * 1e3),
        f"{prefix}_update_ms_max": float(walls.max() * 1e3),
        f"{prefix}_speedup_mean": float(conv_walls.mean() / walls.mean()),
        f"{prefix}_speedup_worst": float(conv_walls.max() / walls.max()),
        f"{prefix}_nn_accept_rate": paths.count(PATH_NN) / len(paths),
        f"{prefix}_hold_rate": float(np.mean(taus == tau_prev)),
        f"{prefix}_no_search_rate": sum(p in NO_SEARCH_PATHS for p in paths) / len(paths),
        f"{prefix}_verify_calls_mean": float(calls.mean()),
        f"{prefix}_verify_calls_max": int(calls.max()),
        f"{prefix}_rmse_tau_s": rmse(errors),
    }


def learned_section(cfg: Config, states: BenchStates, repeats: int) -> dict[str, Any]:
    """Figures of every shipped learned governor on the benchmark's update states, under the
    configured rule and under the other one.

    The conventional TSG is timed again here, interleaved state by state with the learned
    governors (:func:`interleaved_times`); the speed-ups use those times. The conventional
    section's own figures stay as they are."""
    from .governor import load_learned_governor

    pred = _predictor(cfg)
    other = "paper" if cfg.learned.algorithm != "paper" else "keep"
    pred_other = _predictor(cfg.replace(**{"learned.algorithm": other}))
    govs: list[Any] = []
    govs_other: list[Any] = []
    out: dict[str, Any] = {"learned_algorithm": cfg.learned.algorithm, "learned_algorithm_other": other}
    missing = []
    for name in LEARNED_NAMES:
        try:
            govs.append(load_learned_governor(name, pred))
            govs_other.append(load_learned_governor(name, pred_other))
        except ModelFileError as exc:
            # relative to the project (the JSON goes into docs/results: no machine paths)
            missing.append(f"{name}: {exc}".replace(f"{MODELS_DIR.parent}{os.sep}", ""))
            continue
        if govs[-1].foreign:   # flown with learned.foreign_model: what it was made for, in the report
            out.setdefault("learned_foreign_models", {})[name] = govs[-1].foreign
    results = interleaved_times([ConventionalGovernor(pred)] + govs + govs_other, states, repeats)
    conv_walls, conv_taus = results[0][0], results[0][1]
    tau_prev = np.array([s.tau_prev for s in states.updates])
    out["learned_conventional_update_ms_mean"] = float(conv_walls.mean() * 1e3)
    out["learned_conventional_update_ms_max"] = float(conv_walls.max() * 1e3)
    n = len(govs)
    for i, gov in enumerate(govs):
        name = gov.name
        for prefix, (walls, taus, paths, calls) in ((name, results[1 + i]),
                                                    (f"{name}_{other}", results[1 + n + i])):
            # pi* at each state from the same tau_prev and anchored chief: the conventional
            # TSG's answer, timed above (its update is pi*, SPEC §5).
            out.update(_rule_figures(prefix, walls, taus, paths, calls, conv_walls,
                                     taus - conv_taus, tau_prev))
        fwd = [median_thread_time(gov.proposal, s.x_d, s.x_c, s.tau_prev, repeats=repeats)[0]
               for s in states.updates]
        out[f"{name}_forward_us_mean"] = float(np.mean(fwd) * 1e6)
    out.update(mission_figures(ConventionalGovernor(pred), govs, states))
    if missing:
        out["learned_models_missing"] = missing
    out.update(dataset_rate(cfg, pred))
    return out


def mission_figures(conventional: Any, governors: list[Any], states: BenchStates) -> dict[str, Any]:
    """Whole missions as flown, trust, audits and stall rule included: the active updates of
    missions from the benchmark's starts (nominal start, then seeds 1, 2, ...; truth seed = start
    seed), each learned governor flown in turn with the conventional TSG, start by start.

    ``mission_conventional_update_ms_mean`` and ``..._verify_calls_mean``: the conventional
    TSG's active updates (CPU time, Verify calls); per governor ``<m>``: its
    ``_mission_update_ms_mean``; the speed-up of whole missions, each mission's active CPU
    (the conventional TSG's from the same start over the governor's): ``_mission_speedup_mean``
    (the mean over the starts), ``_mission_speedup_worst`` (the worst mission) and
    ``_mission_cpu_speedup`` (all starts' CPU pooled); ``_flown_update_speedup`` (the ratio of the
    pooled mean CPU per active update: it flatters a governor that lags pi* and flies more of the
    cheap updates near tau = 0, so it is second), ``_mission_verify_calls_mean`` (per active
    update), ``_search_rate`` (share of its active updates answered by searching:
    :data:`cikan_ros.governor.SEARCHING_PATHS`) and ``_mission_nn_accept_rate`` (share answered
    with the network's proposal, :func:`cikan_ros.learn.governor.nn_accept_rate`, pooled)."""
    from ..mission import run_mission
    from ..governor import SEARCHING_PATHS
    from .governor import nn_accept_rate

    # per governor, per start: the active updates of its mission
    flown: dict[str, list[list[Any]]] = {g.name: [] for g in [conventional] + governors}
    for seed, x0 in zip(states.seeds, states.starts):
        for gov in [conventional] + governors:
            gov.anchor.current, gov.anchor.re_anchors = gov.anchor.base, 0
            flown[gov.name].append([u for u in run_mission(gov, x0, seed).updates if u.active])

    def pooled(name: str) -> list[Any]:
        return [u for start in flown[name] for u in start]

    def cpu_mean(updates: list[Any]) -> float:
        return float(np.mean([u.cpu_s for u in updates]))

    def cpu_total(updates: list[Any]) -> float:
        return float(sum(u.cpu_s for u in updates))

    def calls_mean(updates: list[Any]) -> float:
        return float(np.mean([u.verify_calls for u in updates]))

    conv_updates = pooled(conventional.name)
    conv, conv_total = cpu_mean(conv_updates), cpu_total(conv_updates)
    out: dict[str, Any] = {"mission_conventional_update_ms_mean": conv * 1e3,
                           "mission_conventional_verify_calls_mean": calls_mean(conv_updates)}
    for gov in governors:
        g, updates = gov.name, pooled(gov.name)
        mean = cpu_mean(updates)
        out[f"{g}_mission_update_ms_mean"] = mean * 1e3
        # whole missions: each start's active CPU, conventional over the governor's
        ratios = [cpu_total(c) / cpu_total(m) for c, m in zip(flown[conventional.name], flown[g]) if c and m]
        out[f"{g}_mission_speedup_mean"] = float(np.mean(ratios))
        out[f"{g}_mission_speedup_worst"] = min(ratios)
        out[f"{g}_mission_cpu_speedup"] = conv_total / cpu_total(updates)
        out[f"{g}_flown_update_speedup"] = conv / mean
        out[f"{g}_mission_verify_calls_mean"] = calls_mean(updates)
        out[f"{g}_search_rate"] = sum(u.path in SEARCHING_PATHS for u in updates) / len(updates)
        out[f"{g}_mission_nn_accept_rate"] = nn_accept_rate(updates)
    return out
