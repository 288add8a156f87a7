"""recorder_node: records every topic of the graph, as received (raw CDR), to a rosbag2 MCAP bag.

Messages are logged at their own stamp (header.stamp, or the Clock's time): the bag is a
sim-time record in which the messages of step k share t_k, whatever their arrival order.
Chunks are flushed every ``recorder.flush_period_s`` (wall) or ``recorder.chunk_bytes``, so a
crash loses at most the chunk in progress (see :mod:`cikan_ros.ros.bag`). SIGINT/SIGTERM: the
recorder keeps taking messages until none came for ``recorder.drain_s``, then closes the bag.
"""

from __future__ import annotations

import json
import signal
import time
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.task import Future

from . import convert as cv
from .bag import BagWriter, qos_dict
from .graph import QOS_RECORD, TOPIC_TYPES, declare, declare_config, message_class, run_node

NAME = "recorder_node"


class RecorderNode(Node):
    """The recorder (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__(NAME)
        bag = str(declare(self, "recorder.bag", "", "bag directory to create (must not exist or be empty)"))
        topics = declare(self, "recorder.topics", list(TOPIC_TYPES),
                         "topics to record (types from the graph's topic table)")
        self.flush_period_s = float(declare(self, "recorder.flush_period_s", 1.0,
                                            "wall seconds between chunk flushes"))
        self.chunk_bytes = int(declare(self, "recorder.chunk_bytes", 256 * 1024,
                                       "message bytes after which a chunk is flushed"))
        self.drain_s = float(declare(self, "recorder.drain_s", 0.3,
                                     "on SIGINT/SIGTERM: close once no message came for this long"))
        if not bag:
            from ..errors import ConfigError

            raise ConfigError("recorder.bag (the bag directory) must be set")
        # The bag carries what it takes to analyse it: the configuration and the governor's name.
        cfg = declare_config(self)
        governor = str(declare(self, "governor.name", "conventional",
                               "governor of the recorded mission (stored in the bag's metadata)"))
        self.bag = BagWriter(bag, self.chunk_bytes, {
            "cikan_ros.config": json.dumps(cfg.flat(), sort_keys=True), "cikan_ros.governor": governor})
        self.done = Future()
        self.stopping = False
        self.last_message = time.monotonic()
        self.stop_requested_at = 0.0
        for topic in topics:
            if topic not in TOPIC_TYPES:
                from ..errors import ConfigError

                raise ConfigError(f"recorder.topics: unknown topic {topic!r}; known: {list(TOPIC_TYPES)}")
            self.create_subscription(message_class(TOPIC_TYPES[topic]), topic,
                                     lambda data, t=topic: self.on_message(t, data), QOS_RECORD, raw=True)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(self.flush_period_s, self.bag.flush, clock=steady)
        self.create_timer(0.05, self.check_stop, clock=steady)
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self.request_stop)
        self.get_logger().info(f"recording {len(topics)} topics to {bag}")

    def on_message(self, topic: str, data: bytes) -> None:
        self.last_message = time.monotonic()
        if topic not in self.bag.channels:
            qos = [qos_dict(info.qos_profile) for info in self.get_publishers_info_by_topic(topic)]
            self.bag.add_topic(topic, TOPIC_TYPES[topic], qos)
        try:
            stamp = cv.cdr_stamp_ns(data)
        except cv.MessageError:
            stamp = time.time_ns()
        self.bag.write(topic, data, stamp)
        if self.bag.unflushed_bytes >= self.chunk_bytes:
            self.bag.flush()

    def request_stop(self, signum: int, _frame: Any) -> None:
        """Signal handler: start draining (runs between callbacks, never inside one)."""
        if not self.stopping:
            self.stopping = True
            self.stop_requested_at = time.monotonic()

    def check_stop(self) -> None:
        if not self.stopping or self.done.done():
            return
        now = time.monotonic()
        if now - self.last_message >= self.drain_s or now - self.stop_requested_at > 10.0:
            self.done.set_result(True)

    def close(self) -> None:
        self.bag.close()
        self.get_logger().info(f"bag closed: {sum(self.bag.counts.values())} messages in {self.bag.dir}")


def main(args: list[str] | None = None) -> int:
    """Console entry point ``recorder_node``."""
    return run_node(lambda _ctx: RecorderNode(), args, signal_handlers=False)


if __name__ == "__main__":
    import sys

    sys.exit(main())
