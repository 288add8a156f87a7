"""Benchmarks behind ``cikan bench``: time governors on the same recorded update states.

States come from conventional-TSG missions (the nominal start and Monte Carlo seeds 1..N-1).
Only active-phase updates are timed (tau_prev < 0: the states where a governor decides
something, SPEC §9); the first-instant search is timed separately. Each state is timed
``repeats`` times and its median kept. Update times are the CPU time of the calling thread
(``time.thread_time``): on a shared machine wall time also counts the time the process waits for
a core, which made single updates look 20x slower under load (measured); the computation is
what the figures compare. Ratios between governors are taken in one run on the same states.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from .config import Config
from .governor import ConventionalGovernor, Governor, UpdateRecord
from .mission import UpdateState, nominal_start, run_mission, sample_start
from .tsg import Predictor
from .units import through_si


@dataclass
class BenchStates:
    """Update states of a fixed set of conventional missions, plus their start states."""

    updates: list[UpdateState]
    starts: list[NDArray]
    mission_wall_s: list[float]
    #: Conventional TSG per-state wall times (s), filled by ``conventional_section`` (runs first)
    #: so later sections report speed-ups measured in the same run on the same states.
    conventional_walls: NDArray | None = None
    conventional_taus: NDArray | None = None


def collect_states(cfg: Config, n_missions: int = 6) -> BenchStates:
    """Run ``n_missions`` conventional missions (nominal, then MC seeds 1, 2, ...) and keep the
    inputs of every active update."""
    gov = ConventionalGovernor.from_config(cfg)
    pred = gov.predictor
    run_mission(gov, nominal_start(pred))  # compile (or load cached) kernels before timing
    updates: list[UpdateState] = []
    starts: list[NDArray] = []
    walls: list[float] = []
    for i in range(n_missions):
        x0 = nominal_start(pred) if i == 0 else sample_start(pred, i)
        start = time.perf_counter()
        res = run_mission(gov, x0)
        walls.append(time.perf_counter() - start)
        starts.append(x0)
        updates += res.update_states()
    return BenchStates(updates, starts, walls)


def timed_update(governor: Governor, s: UpdateState) -> tuple[UpdateRecord, float]:
    """One update at state s and its CPU time (s) in this thread."""
    start = time.thread_time()
    rec = governor.update(s.x_d, s.x_c, s.t, s.tau_prev)
    return rec, time.thread_time() - start


def time_updates(governor: Governor, states: list[UpdateState], repeats: int = 3
                 ) -> tuple[NDArray, NDArray, list[str], NDArray]:
    """Per state: median CPU time (s) of ``repeats`` updates, tau, path, Verify calls."""
    walls = np.empty(len(states))
    taus = np.empty(len(states))
    calls = np.empty(len(states))
    paths: list[str] = []
    for i, s in enumerate(states):
        runs = [timed_update(governor, s) for _ in range(repeats)]
        walls[i] = statistics.median(cpu for _, cpu in runs)
        taus[i] = runs[0][0].tau_s
        calls[i] = runs[0][0].verify_calls
        paths.append(runs[0][0].path)
    return walls, taus, paths, calls


def conventional_section(cfg: Config, states: BenchStates, repeats: int) -> dict[str, Any]:
    """Conventional TSG: active-phase update times, Verify cost, first-instant search, mission wall."""
    pred = Predictor.from_config(cfg)
    gov = ConventionalGovernor(pred)
    walls, taus, _, calls = time_updates(gov, states.updates, repeats)
    states.conventional_walls, states.conventional_taus = walls, taus
    init = []
    for x0 in states.starts:
        runs = []
        for _ in range(repeats):
            start = time.thread_time()
            pred.initial_shift(through_si(x0), 0.0)
            runs.append(time.thread_time() - start)
        init.append(statistics.median(runs))
    verify = []
    for s in states.updates:
        start = time.thread_time()
        pred.verify(s.x_d, s.t, s.tau_prev)  # tau_prev is feasible: a full rollout to the terminal set
        verify.append(time.thread_time() - start)
    return {
        "n_missions": len(states.starts),
        "n_update_states": len(states.updates),
        "conventional_update_ms_mean": float(walls.mean() * 1e3),
        "conventional_update_ms_p50": float(np.median(walls) * 1e3),
        "conventional_update_ms_max": float(walls.max() * 1e3),
        "conventional_verify_calls_mean": float(calls.mean()),
        "verify_ms_mean": float(np.mean(verify) * 1e3),
        "conventional_initial_ms_mean": float(np.mean(init) * 1e3),
        "conventional_initial_ms_max": float(np.max(init) * 1e3),
        "offline_mission_s_mean": float(np.mean(states.mission_wall_s)),
    }


#: Sections of the benchmark report, each (cfg, states, repeats) -> {name: figure}.
SECTIONS: list[Callable[[Config, BenchStates, int], dict[str, Any]]] = [conventional_section]


def learned_section(cfg: Config, states: BenchStates, repeats: int) -> dict[str, Any]:
    """Learned governors of ``models/`` and the dataset rate (``cikan_ros.learn.bench``)."""
    from .learn.bench import learned_section as section

    return section(cfg, states, repeats)


SECTIONS.append(learned_section)


def ros_section(cfg: Config, states: BenchStates, repeats: int) -> dict[str, Any]:
    """The ROS graph's lockstep figures (cikan_ros.ros.bench); imported lazily (needs rclpy)."""
    from .ros.bench import ros_section as section

    return section(cfg, states, repeats)


SECTIONS.append(ros_section)


def run_bench(cfg: Config, n_missions: int = 6, repeats: int = 3) -> dict[str, Any]:
    """All benchmark figures in one run (ratios are comparable only within one run)."""
    states = collect_states(cfg, n_missions)
    out: dict[str, Any] = {}
    for section in SECTIONS:
        out.update(section(cfg, states, repeats))
    return out
