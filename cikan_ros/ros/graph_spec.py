"""The mission graph as data: which nodes, which executables, which node parameters and which
arguments (governor, seed, bag). Pure (no rclpy): the launcher (``cikan mission``) and the
launch file for ROS installs (``launch/mission.launch.yaml``, checked against this by a test)
describe the same graph.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class GraphNode:
    """One node of the graph: its peer name, the executable (console script) and its module."""

    name: str
    executable: str
    module: str


#: The nodes in start order: the recorder first (it must hear everything), the simulator last.
NODES: tuple[GraphNode, ...] = (
    GraphNode("recorder", "recorder_node", "cikan_ros.ros.recorder"),
    GraphNode("governor", "governor_node", "governor_node"),
    GraphNode("controller", "controller_node", "controller_node"),
    GraphNode("sim", "sim_node", "sim_node"),
)

#: Arguments of a mission and their defaults: seed -1 is the nominal start; the bag is a new
#: directory ``bags/<UTC start time>_<governor>`` (``{utc}`` in ``recorder.bag`` is that time).
ARGUMENTS: dict[str, Any] = {"governor": "conventional", "seed": -1, "scenario": "paper",
                             "approach": "behind", "bag": "bags/{utc}_{governor}"}
#: The format of ``{utc}``.
UTC_FORMAT = "%Y%m%dT%H%M%SZ"


def node_parameters(governor: str = "conventional", seed: int | None = -1, bag: str | os.PathLike = "",
                    stop_on_dock: bool = False, approach: str = "behind") -> dict[str, Any]:
    """The node parameters every node of the graph gets (beside the mission configuration and
    its scenario file); ``graph.peers`` makes each node wait for all the others, the recorder
    included."""
    return {"governor.name": str(governor), "sim.seed": -1 if seed is None else int(seed),
            "mission.approach": str(approach),
            "sim.stop_on_dock": bool(stop_on_dock), "recorder.bag": str(bag),
            "graph.peers": [n.name for n in NODES]}
