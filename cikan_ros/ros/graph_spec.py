"""The mission graph as data: its topics (name, message type, QoS kind, who writes and who reads
each), its nodes (peer name, executable, module), the arguments of a mission and the node
parameters they set, and the exit codes of a node process.

Pure data, no rclpy: the launcher (``cikan mission``, :mod:`cikan_ros.ros.launch`), the launch
file for ROS installs (``launch/mission.launch.yaml``, checked against this by a test), the
nodes, the recorder, the bag reader and ``cikan report`` all read it. The QoS profiles a kind
names are built in :mod:`cikan_ros.ros.graph`.
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from typing import Any, Iterable

# -- topics -------------------------------------------------------------------------------------
CLOCK = "/clock"
CHIEF_ODOM = "/chief/odom"
DEPUTY_ODOM = "/deputy/odom"
TIME_SHIFT = "/tsg/time_shift"
ACCEL_CMD = "/deputy/accel_cmd"
DIAGNOSTICS = "/diagnostics"
#: The governor announces which governor flies (diagnostic_msgs/DiagnosticStatus, latched).
GOVERNOR_INFO = "/tsg/governor"
#: The truth (the simulator's own states and the thrust as applied), for the record only: the
#: governor and the controller read the measured states above.
TRUTH_CHIEF = "/truth/chief/odom"
TRUTH_DEPUTY = "/truth/deputy/odom"
TRUTH_ACCEL = "/truth/deputy/accel"
#: The readiness handshake (docs/governor_contract.md, "Start"): each peer announces itself here once it is ready
#: (diagnostic_msgs/DiagnosticStatus, name = peer, message "ready", hardware_id = node name;
#: latched). The simulator starts the lockstep once every peer of ``graph.peers`` is ready.
READY = "/graph/ready"
#: The telemetry of each control step (sensor_msgs/JointState: name[i] the key of the dictionary
#: of :mod:`cikan_ros.telemetry`, position[i] its value in its unit), published by the simulator.
TELEMETRY = "/telemetry"
#: The scene in the chief's LVLH frame (frame_id ``lvlh``; :mod:`cikan_ros.scene`), published by
#: the simulator: the deputy and the virtual target every step; the path so far every governor
#: update period; the cone, the docking port and the approach-velocity sphere at the start and
#: whenever the port axis has turned by 1 degree in LVLH. Three topics, so that a viewer that
#: seeks in a bag (it takes the last message of each topic) shows the whole scene.
SCENE_MARKERS = "/scene/markers"
SCENE_PATH = "/scene/path"
SCENE_CONSTRAINTS = "/scene/constraints"
#: The telemetry and scene topics, in the order the simulator publishes them at a step: derived
#: from the states, thrust and shifts (``cikan scene`` rebuilds them from those).
SCENE_TOPICS = (TELEMETRY, SCENE_MARKERS, SCENE_PATH, SCENE_CONSTRAINTS)

#: /tsg/time_shift source when no decision was made at this step: the last verified shift holds.
PATH_HOLD = "hold"

#: QoS kinds (:mod:`cikan_ros.ros.graph` says why each is what it is): ``stream``, RELIABLE,
#: VOLATILE, KEEP_LAST deep enough for a whole mission; ``latched``, RELIABLE, TRANSIENT_LOCAL,
#: depth 1 (a reader that joins later still gets the last message).
QOS_KINDS = ("stream", "latched")


@dataclass(frozen=True)
class Topic:
    """One topic of the graph.

    ``writers``: the peers that publish it (what a subscription waits for, see
    :func:`required_publishers`); ``readers``: the peers whose subscription a publisher waits for
    (:func:`required_readers`; the recorder comes on top for a ``recorded`` topic); ``recorded``:
    the recorder writes its messages to the bag (a bag reader finds them there).
    """

    name: str
    type: str
    qos: str
    writers: tuple[str, ...]
    readers: tuple[str, ...]
    recorded: bool = True


#: Every topic of the graph. /clock readers are not awaited: rclpy's use_sim_time subscription is
#: an implementation detail. The governor is not an awaited reader of the states: a governor may
#: read only /deputy/odom (the simulator waits for it through the readiness handshake).
#: /tsg/governor goes into the bag's metadata, not among its messages.
TOPICS: dict[str, Topic] = {t.name: t for t in (
    Topic(CLOCK, "rosgraph_msgs/msg/Clock", "stream", ("sim",), ()),
    Topic(CHIEF_ODOM, "nav_msgs/msg/Odometry", "stream", ("sim",), ("controller",)),
    Topic(DEPUTY_ODOM, "nav_msgs/msg/Odometry", "stream", ("sim",), ("controller",)),
    Topic(TIME_SHIFT, "sensor_msgs/msg/TimeReference", "stream", ("governor",), ("controller", "sim")),
    Topic(ACCEL_CMD, "geometry_msgs/msg/AccelStamped", "stream", ("controller",), ("sim",)),
    Topic(DIAGNOSTICS, "diagnostic_msgs/msg/DiagnosticArray", "stream", ("sim", "governor", "controller"), ()),
    Topic(TRUTH_CHIEF, "nav_msgs/msg/Odometry", "stream", ("sim",), ()),
    Topic(TRUTH_DEPUTY, "nav_msgs/msg/Odometry", "stream", ("sim",), ()),
    Topic(TRUTH_ACCEL, "geometry_msgs/msg/AccelStamped", "stream", ("sim",), ()),
    Topic(TELEMETRY, "sensor_msgs/msg/JointState", "stream", ("sim",), ()),
    Topic(SCENE_MARKERS, "visualization_msgs/msg/MarkerArray", "stream", ("sim",), ()),
    Topic(SCENE_PATH, "visualization_msgs/msg/MarkerArray", "stream", ("sim",), ()),
    Topic(SCENE_CONSTRAINTS, "visualization_msgs/msg/MarkerArray", "stream", ("sim",), ()),
    Topic(GOVERNOR_INFO, "diagnostic_msgs/msg/DiagnosticStatus", "latched", ("governor",), (), recorded=False),
    Topic(READY, "diagnostic_msgs/msg/DiagnosticStatus", "latched", ("recorder", "governor", "controller", "sim"),
          ("sim",), recorded=False),
)}

#: Topic -> ROS type name of every topic the recorder writes to a bag.
TOPIC_TYPES: dict[str, str] = {t.name: t.type for t in TOPICS.values() if t.recorded}


def message_class(type_name: str) -> type:
    """The Python class of a ROS type name such as ``nav_msgs/msg/Odometry``."""
    pkg, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def expected_readers(topic: str, peers: Iterable[str]) -> list[str]:
    """The peers of ``peers`` whose subscription to ``topic`` a publisher waits for."""
    t, peers = TOPICS[topic], set(peers)
    return [n for n in t.readers + (("recorder",) if t.recorded else ()) if n in peers]


def expected_writers(topic: str, peers: Iterable[str]) -> list[str]:
    """The peers of ``peers`` that publish ``topic``."""
    peers = set(peers)
    return [n for n in TOPICS[topic].writers if n in peers]


def required_readers(topic: str, peers: Iterable[str]) -> int:
    """How many readers ``topic`` has in a graph made of ``peers`` (node names)."""
    return len(expected_readers(topic, peers))


def required_publishers(topic: str, peers: Iterable[str]) -> int:
    """How many publishers a reader of ``topic`` waits for in a graph made of ``peers``: one if any
    of its writers is a peer (the governor's /diagnostics, optional in the contract, is not awaited)."""
    producers = [n for n in expected_writers(topic, peers) if not (topic == DIAGNOSTICS and n == "governor")]
    return 1 if producers else 0


# -- nodes --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GraphNode:
    """One node of the graph: its peer name, the executable (console script), its module (run
    with ``python -m``) and its node class (``module:Class``: what a container of several nodes
    builds, :mod:`cikan_ros.ros.container`)."""

    name: str
    executable: str
    module: str
    node_class: str


#: The nodes in start order: the recorder first (it must hear everything), the simulator last.
NODES: tuple[GraphNode, ...] = (
    GraphNode("recorder", "recorder_node", "cikan_ros.ros.recorder_node",
              "cikan_ros.ros.recorder_node:RecorderNode"),
    GraphNode("governor", "governor_node", "governor_node", "governor_node.node:GovernorNode"),
    GraphNode("controller", "controller_node", "controller_node", "controller_node.node:ControllerNode"),
    GraphNode("sim", "sim_node", "sim_node", "sim_node.node:SimNode"),
)
#: Peer name -> node.
NODE_BY_NAME: dict[str, GraphNode] = {n.name: n for n in NODES}


def load_object(where: str) -> Any:
    """The object ``module:attribute`` names (a node's class)."""
    module, _, attr = where.partition(":")
    return getattr(importlib.import_module(module), attr)


# -- processes ----------------------------------------------------------------------------------
#: How the nodes are grouped into processes (each group: one process, one executor; a group of
#: several runs as ``cikan_container NODE...``, :mod:`cikan_ros.ros.container`). Messages between
#: nodes of one process skip the network (Fast DDS delivers them within the process): measured
#: with ``cikan bench`` (docs/ros_graph.md, "Processes"), "paired" flies the lockstep ~1.6x
#: faster than "separate" on 2 cores for ~0.6x the CPU per step. "paired", the default: the
#: simulator with the recorder (the plant and its log: most messages of a step go from one to the
#: other) and the governor with the controller (the flight software); a governor that crashes
#: (a user's model, a foreign executable) takes the controller with it, never the plant or the
#: recording. "separate": one process per node (each fault alone; what ``cikan profile``
#: measures per node). "single": the whole graph in one process.
LAYOUTS: dict[str, tuple[tuple[str, ...], ...]] = {
    "paired": (("recorder", "sim"), ("governor", "controller")),
    "separate": (("recorder",), ("governor",), ("controller",), ("sim",)),
    "single": (("recorder", "governor", "controller", "sim"),),
}
DEFAULT_LAYOUT = "paired"


def processes(layout: str, apart: Iterable[str] = ()) -> list[tuple[str, ...]]:
    """The process groups of ``layout`` in start order (the recorder's first), with each node of
    ``apart`` (one run by another executable) in a process of its own."""
    if layout not in LAYOUTS:
        raise ValueError(f"unknown process layout {layout!r}; known: {', '.join(LAYOUTS)}")
    apart = set(apart)
    out: list[tuple[str, ...]] = []
    for group in LAYOUTS[layout]:
        rest = tuple(n for n in group if n not in apart)
        out += [(n,) for n in group if n in apart] + ([rest] if rest else [])
    return out


def as_group(nodes: str | Iterable[str]) -> tuple[str, ...]:
    """A process's node names: a name alone, or several."""
    return (nodes,) if isinstance(nodes, str) else tuple(nodes)


def layouts_text(joiner: str) -> str:
    """Every layout and its processes, for help texts: ``paired: recorder<joiner>sim | ...; ...``."""
    return "; ".join(f"{k}: {' | '.join(joiner.join(g) for g in v)}" for k, v in LAYOUTS.items())


def process_name(group: str | Iterable[str]) -> str:
    """A process's name: its node's executable, or its nodes' peer names joined by '+'."""
    group = as_group(group)
    return NODE_BY_NAME[group[0]].executable if len(group) == 1 else "+".join(group)

#: Exit code of a node started with bad input (unknown parameter, bad value, unreadable file), as `cikan`.
EXIT_BAD_INPUT = 2
#: Exit code of a node whose peers did not show up within ``graph.startup_timeout_s``.
EXIT_NO_PEERS = 1

# -- how long a node takes to end (wall; the launcher waits for them) ---------------------------
#: How long (wall) a node that ends waits, in all, for every reliable reader to acknowledge what
#: its publishers sent (:func:`cikan_ros.ros.graph.wait_acknowledged`). Live readers acknowledge
#: within a heartbeat (0.1 s, config/fastdds_udp_localhost.xml); what outlasts this is a reader
#: that died without a word (a process killed outright), whose participant Fast DDS drops only
#: when its lease ends.
ACK_BUDGET_S = 5.0

#: A node (one that ends on run_node's own SIGINT/SIGTERM handling) that has not ended this long
#: (wall) after it was asked to, or after its mission ended, writes the stack of every thread to
#: its log and exits with code 1 (:func:`cikan_ros.ros.graph.run_node`, by ``faulthandler``,
#: which works while a C call holds the GIL): the launcher, which waits ACK_BUDGET_S + 10 s
#: before its SIGKILL, then reports where it hung instead of a bare -9 (seen once in six loaded
#: runs of the suite, a governor that did not end, not reproduced since).
STOP_WATCHDOG_S = ACK_BUDGET_S + 8.0

#: On SIGINT/SIGTERM the recorder drains until no message came for ``recorder.drain_s``, at most
#: this long (wall). Its producers have stopped by then, so the stream ends; a recorder starved
#: of CPU may be far behind it, and what it still holds in its readers is part of the mission
#: (with a cap of 10 s, three bags of a loaded soak lacked the last 200-1200 steps of every topic).
MAX_DRAIN_S = 300.0

# -- a mission's arguments ----------------------------------------------------------------------
#: Arguments of a mission and their defaults: seed -1 is the nominal start; the bag is a new
#: directory ``runs/bags/<UTC start time>_<governor>`` (``{utc}`` in ``recorder.bag`` is that
#: time; ``runs/`` is ignored by git, ``bags/`` holds the committed reference bags).
ARGUMENTS: dict[str, Any] = {"governor": "conventional", "seed": -1, "scenario": "paper",
                             "approach": "behind", "bag": "runs/bags/{utc}_{governor}"}
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
