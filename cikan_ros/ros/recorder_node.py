"""recorder_node: records the topics of ``recorder.topics`` (default: every topic of the graph), as
received (raw CDR), to a rosbag2 MCAP bag.

Messages are logged at their own stamp (header.stamp, the Clock's time, or a MarkerArray's first
marker's): the bag is a sim-time record in which the messages of step k share t_k, whatever
their arrival order.
Chunks are flushed every ``recorder.flush_period_s`` (wall) or ``recorder.chunk_bytes``, so a
crash loses at most the chunk in progress (see :mod:`cikan_ros.ros.bag_writer`), each in a thread
of the bag's own (``BagWriter(background=True)``): the executor, which in the default process
layout also runs the simulator, never waits for a flush; the process then hands the GIL from
thread to thread every :data:`SWITCH_INTERVAL_S` instead of Python's 5 ms. SIGINT/SIGTERM: the
recorder keeps taking messages until none came for ``recorder.drain_s`` (at most
:data:`MAX_DRAIN_S`), then closes the bag.
The governor's announcements (/tsg/governor, latched) go into the bag's metadata (custom_data
``cikan_ros.governor``: the governors that flew, in order; ``cikan_ros.governor_announcements``).
The telemetry dictionary of the mission's configuration (:mod:`cikan_ros.telemetry`) goes into the
bag when it opens (:meth:`~cikan_ros.ros.bag_writer.BagWriter.add_telemetry`).
"""

from __future__ import annotations

import json
import signal
import sys
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.task import Future

from . import convert as cv
from .cdr import cdr_stamp_ns
from ..errors import ConfigError
from .bag_writer import BagWriter, qos_dict
from .graph import Readiness, qos_for, run_node
from .graph_spec import GOVERNOR_INFO, MAX_DRAIN_S, TOPIC_TYPES, UTC_FORMAT, message_class, required_publishers
from .params import NodeSpec, declare_config, declare_parameters, plain
from ..telemetry import dictionary, to_json

NAME = "recorder_node"
#: The process's GIL switch interval (s) once the recorder flushes in the background: the
#: longest a callback of the executor waits while the flush thread runs Python.
SWITCH_INTERVAL_S = 0.0002
#: Parameters: the groups recorder and graph of config/nodes.yaml, and the mission configuration
#: (for the bag).
SPEC = NodeSpec(NAME, __doc__, ("recorder", "graph"))


class RecorderNode(Node):
    """The recorder (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__(NAME)
        self.readiness = Readiness(self, "recorder")   # first: the /graph/ready publisher
        p = declare_parameters(self, SPEC)
        self.peers = [str(n) for n in plain(p["graph.peers"])]
        utc = datetime.now(timezone.utc).strftime(UTC_FORMAT)
        self.bag_dir = Path(str(p["recorder.bag"]).replace("{utc}", utc))
        self.topics = [str(t) for t in p["recorder.topics"]]
        self.recorded = set(self.topics)
        self.flush_period_s = float(p["recorder.flush_period_s"])
        self.chunk_bytes = int(p["recorder.chunk_bytes"])
        self.drain_s = float(p["recorder.drain_s"])
        if not str(p["recorder.bag"]):
            raise ConfigError("recorder.bag (the bag directory) must be set")
        if self.bag_dir.exists() and (not self.bag_dir.is_dir() or any(self.bag_dir.iterdir())):
            raise ConfigError(f"recorder.bag: {self.bag_dir} exists and is not an empty directory")
        unknown = [t for t in self.topics if t not in TOPIC_TYPES]
        if unknown:
            raise ConfigError(f"recorder.topics: unknown topic {unknown[0]!r}; known: {list(TOPIC_TYPES)}")
        # The bag carries what it takes to analyse it: the configuration, and the governor that
        # flew as the governor announces it (GOVERNOR_INFO), never a default of the recorder's.
        self.cfg = declare_config(self)
        self.bag: BagWriter | None = None
        self.announced: list[dict[str, str]] = []
        self.done = Future()
        self.stopping = False
        self.last_message = time.monotonic()
        self.stop_requested_at = 0.0

    def open(self) -> None:
        """Create the bag and subscribe (called once the node's parameters are checked)."""
        self.bag = BagWriter(self.bag_dir, self.chunk_bytes,
                             {"cikan_ros.config": json.dumps(self.cfg.flat(), sort_keys=True)}, background=True)
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        self.bag.add_telemetry(to_json(dictionary(self.cfg), self.cfg))
        # As a peer of the graph it reads every topic: the other peers wait for it as a reader of
        # each (graph.required_readers) before they are ready; it writes recorder.topics.
        read = list(TOPIC_TYPES) if "recorder" in self.peers else self.topics
        subs = [self.readiness.subscription(message_class(TOPIC_TYPES[topic]), topic,
                                            lambda data, t=topic: self.on_message(t, data), qos_for(topic),
                                            raw=True)
                for topic in read]
        self.create_subscription(DiagnosticStatus, GOVERNOR_INFO, self.on_governor, qos_for(GOVERNOR_INFO))
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(self.flush_period_s, self.bag.flush, clock=steady)
        self.create_timer(0.05, self.check_stop, clock=steady)
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self.request_stop)
        self.get_logger().info(f"recording {len(self.topics)} topics to {self.bag_dir}")
        # Ready (announced on /graph/ready) once each topic is matched to a publisher of a peer:
        # the sim then starts; the recorder itself never gives up waiting.
        self.readiness.start([], [(s, required_publishers(s.topic_name, self.peers)) for s in subs],
                             float("inf"), lambda: None, prepare=self.register_topics)

    def register_topics(self) -> None:
        """Register in the bag every recorded topic that has a publisher now, with their QoS (before
        the announcement: the ~1 ms per topic of schema, type hash and QoS text then costs the
        lockstep nothing; measured at its first step on 2 cores). A topic whose publisher comes
        later is registered at its first message."""
        for topic in self.topics:
            qos = self.offered_qos(topic)
            if qos:
                self.bag.add_topic(topic, TOPIC_TYPES[topic], qos)

    def offered_qos(self, topic: str) -> list[dict[str, Any]]:
        """The QoS profiles the publishers of ``topic`` known now offer (rosbag2's form)."""
        return [qos_dict(info.qos_profile) for info in self.get_publishers_info_by_topic(topic)]

    def on_governor(self, msg: DiagnosticStatus) -> None:
        """The governor's announcement: into the bag's metadata (every governor that flew, in order)."""
        info = cv.governor_from_info(msg)
        if self.announced and self.announced[-1] == info:
            return
        self.announced.append(info)
        self.bag.settle()   # a flush in the background reads custom_data
        self.bag.custom_data["cikan_ros.governor"] = " -> ".join(a["governor"] for a in self.announced)
        self.bag.custom_data["cikan_ros.governor_announcements"] = json.dumps(self.announced)
        self.bag.write_metadata()
        self.get_logger().info(f"governor announced: {info['governor']}")

    def on_message(self, topic: str, data: bytes) -> None:
        self.last_message = time.monotonic()
        if topic not in self.recorded:
            return
        if topic not in self.bag.channels:  # its publisher came after the announcement
            self.bag.add_topic(topic, TOPIC_TYPES[topic], self.offered_qos(topic))
        try:
            stamp = cdr_stamp_ns(data, TOPIC_TYPES[topic])
        except cv.MessageError:
            stamp = time.time_ns()
        self.bag.write(topic, data, stamp)   # which flushes every recorder.chunk_bytes

    def request_stop(self, signum: int, _frame: Any) -> None:
        """Signal handler: start draining (runs between callbacks, never inside one)."""
        if not self.stopping:
            self.stopping = True
            self.stop_requested_at = time.monotonic()

    def check_stop(self) -> None:
        if not self.stopping or self.done.done():
            return
        now = time.monotonic()
        if now - self.last_message >= self.drain_s or now - self.stop_requested_at > MAX_DRAIN_S:
            self.done.set_result(True)

    def close(self) -> None:
        if self.bag is None:
            return
        self.bag.close()
        self.get_logger().info(f"bag closed: {sum(self.bag.counts.values())} messages in {self.bag.dir}")


def main(args: list[str] | None = None) -> int:
    """Console entry point ``recorder_node``."""
    return run_node(lambda _ctx: RecorderNode(), args, signal_handlers=False, spec=SPEC)


if __name__ == "__main__":
    sys.exit(main())
