"""ROS section of ``cikan bench``: one full lockstep mission of the graph (conventional governor).

- ros_rtf: simulated seconds per wall second of the lockstep (sim_node's own clock, from its
  first published state to the final one; process start-up excluded, reported separately).
- ros_step_ms_p50 / p99: wall time from sim_node publishing the states of a step to it receiving
  that step's command, over the steps where the governor holds tau (governor compute excluded);
  ros_update_step_ms_max: the same at update steps (governor compute included).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from ..config import Config


def ros_section(cfg: Config, _states: Any, _repeats: int) -> dict[str, Any]:
    """Figures of one 4-hour (cfg.mission.duration_s) lockstep mission as separate processes."""
    from .graph import make_executor  # noqa: F401  (fails early without the ROS wheels)
    from .launch import run_ros_mission

    tmp = Path(tempfile.mkdtemp(prefix="cikan_bench_"))
    try:
        m = run_ros_mission(cfg, governor="conventional", bag=tmp / "bag")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    ros = m["ros"]
    return {
        "ros_executor": os.environ.get("CIKAN_ROS_EXECUTOR", "single"),
        "ros_rtf": ros["rtf"],
        "ros_step_ms_p50": ros["step_ms_p50"],
        "ros_step_ms_p99": ros["step_ms_p99"],
        "ros_update_step_ms_max": ros["update_step_ms_max"],
        "ros_lockstep_wall_s": ros["wall_s"],
        "ros_mission_wall_s": ros["launch_wall_s"],
        "ros_mission_success": m["success"],
    }
