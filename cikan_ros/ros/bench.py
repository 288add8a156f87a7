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
- Every mission flies in the launcher's default process layout (``ros_layout``,
  :data:`~cikan_ros.ros.graph_spec.DEFAULT_LAYOUT`: the simulator with the recorder, the governor
  with the controller) but ``ros_separate_*``: the same mission with one process per node, the
  comparison behind the default.
- ros_cpu_per_step_ms: CPU time (user + system, every thread) of the graph's node processes per
  lockstep step, each counted over its spin (:func:`cikan_ros.ros.profile.spin_cpu`): the
  mission's less that of a mission of :data:`SHORT_STEPS` steps (the readiness handshake and the
  acknowledgements at the end), over the difference in steps; ``ros_cpu_per_step_ms_<process>``
  the same per process (``recorder+sim``, ``governor+controller``; per node under
  ``ros_separate_``). On a machine with few cores the
  lockstep's rtf is bound by it, not only by the chain of a step (sim -> governor -> controller
  -> sim). The processes' start-up (imports, loading kernels) is not in it: counted from the
  children's rusage it was ~6 s of CPU that moved by a second between missions, half a
  millisecond per step of noise.
- The lockstep mission with the chosen executor is flown :data:`LOCKSTEP_RUNS` times: the ros_*
  figures are those of the run with the median rtf, ``ros_rtf_min`` / ``ros_rtf_max`` the
  spread (on these shared 2-core machines one run's rtf moved by a third between minutes).
- The same mission once more with the other executor (``ros_single_*``): the comparison behind
  the choice of executor (cikan_ros.ros.graph.make_executor).
- The same mission once more with the mission-control view following its bag (``ros_view_*``,
  ``cikan view BAG --follow`` in its own process, as ``cikan mission --view`` starts it): what
  watching a mission costs it; ``ros_view_follower_cpu_per_step_ms`` the view process's own CPU
  (start-up included) over the steps.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Callable

from ..config import Config
from ..errors import CikanError
from .graph_spec import DEFAULT_LAYOUT


#: Starts a process following a bag as it is recorded (the view: cikan_ros.view.live), given
#: the bag's path; returns the process (something with terminate() and wait()).
Follower = Callable[[Path], Any]

#: The steps of the short mission whose CPU is the graph's fixed cost (ros_cpu_per_step_ms).
SHORT_STEPS = 10
#: Lockstep missions flown with the chosen executor; the median one's figures are reported.
LOCKSTEP_RUNS = 3
#: The layout flown once beside the default one (``ros_separate_*``): one process per node.
SEPARATE = "separate"


def process_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) a running process has used so far (Linux /proc; NaN elsewhere)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    except OSError:
        return math.nan
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime


def step_of(k: float | None) -> int | None:
    """A control step the simulator's summary names (a float in its message), as an int."""
    return None if k is None or k != k else int(k)


def lockstep_figures(cfg: Config, executor: str, follow: Follower | None = None,
                     seed: int | None = None, layout: str = DEFAULT_LAYOUT) -> dict[str, Any]:
    """rtf, step latency and wall times of one mission (the nominal start, or Monte Carlo start
    ``seed``) with every node on ``executor``, in the processes of ``layout``, with a ``follow``
    process reading its bag when given; ``cpu_s``: the CPU seconds of each process's spin by
    process name (``sim_node``, ``recorder+sim``; the follower's not counted), ``steps``: the
    steps flown."""
    from .launch import node_environment, run_ros_mission
    from .profile import CPU_ONLY_ENV, PROFILE_ENV, spin_cpu

    tmp = Path(tempfile.mkdtemp(prefix="cikan_bench_"))
    follower = None
    try:
        with (node_environment("CIKAN_ROS_EXECUTOR", executor), node_environment(PROFILE_ENV, str(tmp / "cpu")),
              node_environment(CPU_ONLY_ENV, "1")):
            follower = follow(tmp / "bag") if follow is not None else None
            m = run_ros_mission(cfg, governor="conventional", seed=seed, bag=tmp / "bag", layout=layout)
        cpu = spin_cpu(tmp / "cpu")
        follower_cpu = process_cpu_s(follower.pid) if follower is not None else None
    finally:
        if follower is not None:
            follower.terminate()
            follower.wait()
        shutil.rmtree(tmp, ignore_errors=True)
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
            "cpu_s": cpu, "steps": int(ros["steps"]),
            **({} if follower_cpu is None else {"follower_cpu_per_step_ms": follower_cpu / int(ros["steps"]) * 1e3})}


def ros_section(cfg: Config, states: Any, _repeats: int, follow: Follower | None = None) -> dict[str, Any]:
    """ros_* figures with the chosen executor (EventsExecutor), ros_single_* with the other, and
    ros_view_* with the chosen one and ``follow`` (the view) reading the bag, when given. Each
    flies the benchmark's first start that Verify accepts (``ros_seed``: None for the nominal
    start, which robust Verify may refuse, as in LEO from ahead)."""
    seed = states.seeds[0]
    flown = sorted((lockstep_figures(cfg, "events", seed=seed) for _ in range(LOCKSTEP_RUNS)), key=lambda f: f["rtf"])
    events = flown[len(flown) // 2]
    brief = cfg.replace(**{"mission.duration_s": SHORT_STEPS * cfg.control.period_s})
    short = lockstep_figures(brief, "events", seed=seed)
    single = lockstep_figures(cfg, "single", seed=seed)
    separate = lockstep_figures(cfg, "events", seed=seed, layout=SEPARATE)
    short_separate = lockstep_figures(brief, "events", seed=seed, layout=SEPARATE)
    runs = {"ros": events, "ros_single": single, "ros_separate": separate}
    if follow is not None:
        runs["ros_view"] = lockstep_figures(cfg, "events", follow, seed=seed)
    out: dict[str, Any] = {"ros_seed": seed, "ros_layout": DEFAULT_LAYOUT, "ros_rtf_min": flown[0]["rtf"],
                           "ros_rtf_max": flown[-1]["rtf"], "ros_lockstep_runs": len(flown)}
    for prefix, figures in runs.items():
        cpu, steps = figures.pop("cpu_s"), figures.pop("steps")
        fixed = short_separate if prefix == "ros_separate" else short
        per_node = {node.removesuffix("_node"): (cpu[node] - fixed["cpu_s"].get(node, 0.0))
                    / (steps - fixed["steps"]) * 1e3 for node in cpu}
        figures["cpu_per_step_ms"] = sum(per_node.values())
        if prefix in ("ros", "ros_separate"):
            figures.update({f"cpu_per_step_ms_{node}": v for node, v in sorted(per_node.items())})
        out.update({f"{prefix}_{k}": v for k, v in figures.items() if prefix == "ros" or k != "mission_success"})
    return out
