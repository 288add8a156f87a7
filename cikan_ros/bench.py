"""The conventional TSG's sections of ``cikan bench``: time it on recorded update states.

``cikan bench`` (``cikan_ros.commands.bench``) runs these sections, then the learned governors'
(``cikan_ros.learn.bench``) and the ROS graph's (``cikan_ros.ros.bench``), on the same states.

States come from conventional-TSG missions flown under the configuration benchmarked (the
nominal start and Monte Carlo seeds 1..N-1, each with its truth seed; ``cikan_ros.timing``).
Only active-phase updates are timed (tau_prev < 0: the states where a governor decides
something, SPEC §9); the first-instant search is timed separately. Each state is timed
``repeats`` times and its median kept; each timed update anchors the chief as the mission's did
(``cikan_ros.timing``: re-anchoring and the new chief table are paid in every repeat). Update
times are the CPU time of the calling thread (``time.thread_time``): on a shared machine wall
time also counts the time the process waits for a core, which made single updates look 20x
slower under load (measured); the computation is what the figures compare. Ratios between
governors are taken in one run on the same states.

The ceiling (``oracle_*``, :func:`ceiling_figures`): beside each state's conventional update, the
CPU of an oracle governor that knows pi* and verifies it once (nothing where pi* = tau_prev). A
learned governor that tracks pi* and verifies what it flies pays at least that (its network, a
missed proposal and any search come on top), so the oracle's speed-up bounds what any network
can buy under Algorithm 1 in this configuration: where it is below a target, no training
reaches the target by tracking pi*.

Under a non-nominal truth or robust Verify the run also flies and times the conventional TSG
under the nominal configuration (nominal truth, nominal Verify) on its own nominal states
(``nominal_*``, :func:`nominal_section`), so that the cost of the truth and of robust Verify
reads as a ratio from one run; and it reports what re-anchoring the chief costs
(``timing.anchoring_figures``). Under the nominal configuration the report's keys are those of
the benchmark before the truth model, and the ceiling's.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from .config import Config
from .errors import CikanError
from .governor import ConventionalGovernor
from .timing import (BenchStates, anchoring_figures, collect_states, is_nominal, median_thread_time,
                     nominal_config, prime, thread_timed, time_updates)
from .tsg import Predictor
from .units import through_si


def conventional_section(cfg: Config, states: BenchStates, repeats: int) -> dict[str, Any]:
    """Conventional TSG: active-phase update times, Verify cost, first-instant search, mission
    wall; under a non-nominal configuration also the truth, the chief re-anchors and their cost."""
    pred = Predictor.from_config(cfg)
    gov = ConventionalGovernor(pred)
    oracle = np.zeros(len(states.updates))

    def time_oracle(i: int, rec: Any) -> None:
        oracle[i] = oracle_time(gov, states, i, rec.tau_s, repeats)

    walls, taus, _, calls, re_anchored = time_updates(gov, states, repeats, then=time_oracle)
    states.conventional_walls, states.conventional_taus = walls, taus
    init = [median_thread_time(pred.initial_shift, through_si(x0), 0.0, repeats=repeats)[0]
            for x0 in states.first_seen]
    # tau_prev is feasible: a full rollout to the terminal set
    verify = [thread_timed(pred.verify, s.x_d, s.t, s.tau_prev)[1] for s in states.updates]
    worst = int(np.argmax(walls))
    out: dict[str, Any] = {
        "n_missions": len(states.starts),
        "n_update_states": len(states.updates),
        "conventional_update_ms_mean": float(walls.mean() * 1e3),
        "conventional_update_ms_p50": float(np.median(walls) * 1e3),
        "conventional_update_ms_p99": float(np.percentile(walls, 99) * 1e3),
        "conventional_update_ms_max": float(walls.max() * 1e3),
        # What the slowest update was: where in its mission, from which shift, with how many Verify calls.
        "conventional_update_max_t_s": float(states.updates[worst].t),
        "conventional_update_max_tau_prev_s": float(states.updates[worst].tau_prev),
        "conventional_update_max_verify_calls": int(calls[worst]),
        "conventional_verify_calls_mean": float(calls.mean()),
        "verify_ms_mean": float(np.mean(verify) * 1e3),
        "conventional_initial_ms_mean": float(np.mean(init) * 1e3),
        "conventional_initial_ms_max": float(np.max(init) * 1e3),
        "offline_mission_s_mean": float(np.mean(states.mission_wall_s)),
        **ceiling_figures(walls, oracle, states.mission[:len(walls)]),
    }
    if is_nominal(cfg):
        return out
    out.update({
        "truth": cfg.truth.name,
        "truth_scale": cfg.truth.scale,
        "robust": cfg.tsg.robust,
        "n_missions_infeasible": len(states.infeasible_seeds),
        "conventional_verify_calls_max": int(calls.max()),
        "conventional_re_anchor_rate": float(re_anchored.mean()),
        "mission_re_anchors_mean": float(np.mean(states.mission_re_anchors)),
        "mission_anchor_calls_mean": float(np.mean(states.mission_anchor_calls)),
    })
    out.update(anchoring_figures(gov, states, repeats))  # verify_ms_mean: on the anchored chief
    out["re_anchor_cost_ms_mean"] = (out["conventional_update_ms_mean"]
                                     - out["conventional_update_anchored_ms_mean"])
    return out


def oracle_time(gov: ConventionalGovernor, states: BenchStates, i: int, tau_star: float, repeats: int) -> float:
    """CPU time (s) at benchmark state i of an *oracle* governor that knows pi* (``tau_star``, the
    conventional TSG's answer) and verifies it once: its anchoring and one Verify of pi* (median
    of ``repeats``, the anchor primed as for the timed updates); 0 where pi* is tau_prev, which
    it holds without a prediction (recursive feasibility, SPEC §5). Timed right after the
    conventional update of the same state (:func:`conventional_section`), so that the ratio
    sees the same machine."""
    s = states.updates[i]
    if tau_star == s.tau_prev:
        return 0.0

    def verify_pi_star() -> bool:
        return gov.anchor(s.x_c, s.t).verify(s.x_d, s.t, tau_star)

    cpu, passed = median_thread_time(verify_pi_star, repeats=repeats,
                                     setup=functools.partial(prime, gov, states.priors[i], states.progress[i]))
    if not passed:
        raise CikanError(f"cikan bench: the oracle's pi* = {tau_star} s at t = {s.t} s failed its own Verify")
    return cpu


def ceiling_figures(walls: np.ndarray, oracle: np.ndarray, mission: list[int]) -> dict[str, Any]:
    """What any governor that moves tau to pi* could reach at most, from per-state CPU times (s)
    of the conventional TSG (``walls``) and of the oracle (:func:`oracle_time`), states grouped
    by ``mission``: the ceiling of a learned governor that tracks pi* and verifies what it flies.
    ``oracle_mission_speedup_mean`` / ``_worst``: each mission's conventional CPU over its
    oracle's (mean over missions, worst mission), ``oracle_cpu_speedup``: all states pooled,
    ``oracle_update_ms_mean``: the oracle's CPU per state, ``oracle_hold_rate``: the share of
    states where pi* = tau_prev (free to the oracle)."""
    ids = np.asarray(mission)
    conv, ora = np.bincount(ids, weights=walls), np.bincount(ids, weights=oracle)   # per mission
    ratios = [float(c / o) for c, o in zip(conv, ora) if o > 0.0]
    return {
        "oracle_mission_speedup_mean": float(np.mean(ratios)) if ratios else math.nan,
        "oracle_mission_speedup_worst": min(ratios) if ratios else math.nan,
        "oracle_cpu_speedup": float(walls.sum() / oracle.sum()) if oracle.sum() > 0.0 else math.nan,
        "oracle_update_ms_mean": float(oracle.mean() * 1e3),
        "oracle_hold_rate": float(np.mean(oracle == 0.0)),
    }


def nominal_section(cfg: Config, states: BenchStates, repeats: int) -> dict[str, Any]:
    """Under a non-nominal configuration: the conventional section under the nominal one
    (:func:`timing.nominal_config`), flown on its own states (same starts, same number of
    missions) in this run, as ``nominal_<key>``, and the ratios of the configured conventional
    TSG's update times to it (``conventional_update_ms_ratio_to_nominal``, ``..._max_ratio_...``).
    Nothing under the nominal configuration."""
    if is_nominal(cfg):
        return {}
    ncfg = nominal_config(cfg)
    nominal = conventional_section(ncfg, collect_states(ncfg, states.n_missions), repeats)
    out = {f"nominal_{k}": v for k, v in nominal.items()}
    ours = states.conventional_walls
    assert ours is not None, "the conventional section runs first"
    out["conventional_update_ms_ratio_to_nominal"] = (
        float(ours.mean() * 1e3) / nominal["conventional_update_ms_mean"])
    out["conventional_update_ms_max_ratio_to_nominal"] = (
        float(ours.max() * 1e3) / nominal["conventional_update_ms_max"])
    return out
