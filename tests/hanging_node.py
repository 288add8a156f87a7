"""A node that hangs while it ends (for the stop-watchdog test): its close() never returns. It
prints "spinning" once its executor runs; the stop watchdog is shortened to 1 s in this process."""

import sys
import time

from rclpy.node import Node

from cikan_ros.ros import graph_spec
from cikan_ros.ros.graph import run_node


class HangingNode(Node):
    def __init__(self) -> None:
        super().__init__("hanging_node")
        self.started = self.create_timer(0.05, self.say_spinning)

    def say_spinning(self) -> None:
        self.started.cancel()
        print("spinning", flush=True)

    def close(self) -> None:
        time.sleep(600.0)   # a teardown that never comes back


if __name__ == "__main__":
    graph_spec.STOP_WATCHDOG_S = 1.0
    sys.exit(run_node(lambda _context: HangingNode(), sys.argv))
