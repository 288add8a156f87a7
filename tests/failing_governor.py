"""A governor that fails mid-mission (for the fault tests): it answers tau = 0 for the states of
the first N steps (argument 1), then logs an error and exits with code 3."""

import sys

from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import TimeReference

from cikan_ros.ros.graph import QOS_STREAM, run_node


class FailingGovernor(Node):
    def __init__(self, steps: int) -> None:
        super().__init__("failing_governor")
        self.left = steps
        self.exit_code = 0
        self.done = Future()
        self.pub = self.create_publisher(TimeReference, "/tsg/time_shift", QOS_STREAM)
        self.wait = self.create_timer(0.02, self.join)

    def join(self) -> None:
        if self.pub.get_subscription_count() >= 2:   # the controller and the recorder
            self.wait.cancel()
            self.create_subscription(Odometry, "/chief/odom", lambda _: None, QOS_STREAM)
            self.create_subscription(Odometry, "/deputy/odom", self.on_deputy, QOS_STREAM)

    def on_deputy(self, msg: Odometry) -> None:
        if self.left == 0:
            self.get_logger().error("failing governor: giving up as planned")
            self.exit_code = 3
            self.done.set_result(True)
            return
        self.left -= 1
        self.pub.publish(TimeReference(header=msg.header, time_ref=msg.header.stamp, source="failing"))


if __name__ == "__main__":
    sys.exit(run_node(lambda _context: FailingGovernor(int(sys.argv[1])), sys.argv[:1] + sys.argv[2:]))
