"""A rogue governor: tau = 0 at every step, never verified. It keeps the topic contract (stamps,
types, QoS) and breaks the safety one; `cikan mission` flies it to the end and reports what it did:
    cikan mission --governor-exec "python examples/custom_governor/rogue_governor.py"
"""
import sys

from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import TimeReference

from cikan_ros.ros.graph import run_node


class RogueGovernor(Node):
    def __init__(self) -> None:
        super().__init__("rogue_governor")
        self.pub = self.create_publisher(TimeReference, "/tsg/time_shift", 1000)   # reliable, volatile
        self.wait = self.create_timer(0.02, self.join)

    def join(self) -> None:
        if self.pub.get_subscription_count() >= 2:   # the controller and the recorder of `cikan mission`
            self.wait.cancel()
            self.create_subscription(Odometry, "/deputy/odom", self.on_deputy, 1000)

    def on_deputy(self, msg: Odometry) -> None:
        """tau = 0: time_ref = stamp (the final state's answer is ignored by the controller)."""
        self.pub.publish(TimeReference(header=msg.header, time_ref=msg.header.stamp, source="rogue"))


if __name__ == "__main__":
    sys.exit(run_node(lambda _context: RogueGovernor()))   # the nodes' own init/spin/shutdown
