"""ROS section of ``cikan bench``: full lockstep missions of the graph (conventional governor).

- ros_rtf: simulated seconds per wall second of the lockstep (sim_node's own clock, from its
  first published state to the final one; process start-up excluded, reported separately).
- ros_step_ms_p50 / p99 / max: wall time from sim_node publishing the states of a step to it
  receiving that step's command, over the steps where the governor holds tau (governor compute
  excluded);
  ros_update_step_ms_max: the same at the first step and the update steps (governor compute
  included; the governor loads and runs its kernels before the lockstep starts, so the first
  decision is as fast as the others); ros_step_ms_max_k / ros_update_step_ms_max_k: the control
  step where each longest step fell (0: the first-instant search).
- ros_decision_ms_max: the longest governor decision of the mission (first-instant search or
  update), as governor_node timed it.
- ros_cpu_per_step_ms: CPU time (user + system) of all the graph's processes per lockstep step:
  the mission's less that of a mission of :data:`SHORT_STEPS` steps (start-up, warm-up and
  shut-down), over the difference in steps. On a machine with few cores the lockstep's rtf is
  bound by it, not only by the chain of a step (sim -> governor -> controller -> sim).
- The same mission once more with the other executor (``ros_single_*``): the comparison behind
  the choice of executor (cikan_ros.ros.graph.make_executor).
- The same mission once more with the mission-control view following its bag (``ros_view_*``,
  ``cikan view BAG --follow`` in its own process, as ``cikan mission --view`` starts it): what
  watching a mission costs it.
"""

from __future__ import annotations

import resource
import shutil
import tempfile
from pathlib import Path
from typing import Any, Callable

from ..config import Config
from ..errors import CikanError


#: Starts a process following a bag as it is recorded (the view: cikan_ros.view.live), given
#: the bag's path; returns the process (something with terminate() and wait()).
Follower = Callable[[Path], Any]

#: The steps of the short mission whose CPU is the graph's fixed cost (ros_cpu_per_step_ms).
SHORT_STEPS = 10


def children_cpu_s() -> float:
    """CPU seconds (user + system) of this process's children that ended and were waited for."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def step_of(k: float | None) -> int | None:
    """A control step the simulator's summary names (a float in its message), as an int."""
    return None if k is None or k != k else int(k)


def lockstep_figures(cfg: Config, executor: str, follow: Follower | None = None,
                     seed: int | None = None) -> dict[str, Any]:
    """rtf, step latency and wall times of one mission (the nominal start, or Monte Carlo start
    ``seed``) with every node on ``executor``, with a ``follow`` process reading its bag when
    given; ``cpu_s``: the CPU of all its processes (the follower's too), ``steps``: the steps
    flown."""
    from .launch import node_environment, run_ros_mission

    tmp = Path(tempfile.mkdtemp(prefix="cikan_bench_"))
    follower = None
    cpu0 = children_cpu_s()
    try:
        with node_environment("CIKAN_ROS_EXECUTOR", executor):
            follower = follow(tmp / "bag") if follow is not None else None
            m = run_ros_mission(cfg, governor="conventional", seed=seed, bag=tmp / "bag")
    finally:
        if follower is not None:
            follower.terminate()
            follower.wait()
        shutil.rmtree(tmp, ignore_errors=True)
    cpu = children_cpu_s() - cpu0
    ros = m["ros"]
    missing = [k for k in ("rtf", "step_ms_p50", "step_ms_p99", "update_step_ms_max", "wall_s", "steps")
               if k not in ros]
    if missing:  # the simulator's closing summary (a /diagnostics message) is not in the bag
        raise CikanError(f"the ROS benchmark mission ({executor} executor) recorded no lockstep "
                         f"summary of sim_node (missing {', '.join(missing)}): no ROS figures")
    return {"rtf": ros["rtf"], "step_ms_p50": ros["step_ms_p50"], "step_ms_p99": ros["step_ms_p99"],
            "step_ms_max": ros.get("step_ms_max", float("nan")), "step_ms_max_k": step_of(ros.get("step_ms_max_k")),
            "update_step_ms_max": ros["update_step_ms_max"],
            "update_step_ms_max_k": step_of(ros.get("update_step_ms_max_k")),
            "decision_ms_max": max(m["initial_ms"], m["update_ms_max"]), "lockstep_wall_s": ros["wall_s"],
            "mission_wall_s": ros["launch_wall_s"], "mission_success": m["success"],
            "cpu_s": cpu, "steps": int(ros["steps"])}


def ros_section(cfg: Config, states: Any, _repeats: int, follow: Follower | None = None) -> dict[str, Any]:
    """ros_* figures with the chosen executor (EventsExecutor), ros_single_* with the other, and
    ros_view_* with the chosen one and ``follow`` (the view) reading the bag, when given. Each
    flies the benchmark's first start that Verify accepts (``ros_seed``: None for the nominal
    start, which robust Verify may refuse, as in LEO from ahead)."""
    seed = states.seeds[0]
    events = lockstep_figures(cfg, "events", seed=seed)
    # After a full mission, so that its fixed cost is the graph's, not the first compilation's.
    short = lockstep_figures(cfg.replace(**{"mission.duration_s": SHORT_STEPS * cfg.control.period_s}), "events",
                             seed=seed)
    single = lockstep_figures(cfg, "single", seed=seed)
    runs = {"ros": events, "ros_single": single}
    if follow is not None:
        runs["ros_view"] = lockstep_figures(cfg, "events", follow, seed=seed)
    out: dict[str, Any] = {"ros_seed": seed}
    for prefix, figures in runs.items():
        cpu, steps = figures.pop("cpu_s"), figures.pop("steps")
        figures["cpu_per_step_ms"] = (cpu - short["cpu_s"]) / (steps - short["steps"]) * 1e3
        out.update({f"{prefix}_{k}": v for k, v in figures.items() if prefix == "ros" or k != "mission_success"})
    return out
