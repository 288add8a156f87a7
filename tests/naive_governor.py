"""A governor written to today's contract at its most naive (for the readiness tests): it reads
only /deputy/odom, makes its publisher and its subscription at once, never waits for a match,
never announces itself on /graph/ready, and answers each state as soon as it hears it.

Argument 1: ``pistar`` (default; the first-instant search, then bisection over [tau_prev, 0] at
each update, with the library) or ``zero`` (tau = 0 at every step: violations, reported)."""

import sys

from builtin_interfaces.msg import Time
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import TimeReference

from cikan_ros.mission import Schedule, nominal_start
from cikan_ros.ros.graph import QOS_STREAM, run_node
from cikan_ros.ros.params import declare_config
from cikan_ros.tsg import Predictor


class NaiveGovernor(Node):
    def __init__(self, mode: str) -> None:
        super().__init__("naive_governor")
        cfg = declare_config(self)
        self.declare_parameter("graph.peers", ["controller"])
        self.mode = mode
        self.pred = Predictor.from_config(cfg)
        if mode == "pistar":
            self.pred.initial_shift(nominal_start(self.pred), 0.0)   # warm-up
        self.epoch, self.period = round(cfg.orbit.epoch_unix_s * 1e9), round(cfg.control.period_s * 1e9)
        self.schedule, self.tau = Schedule(cfg), None
        self.pub = self.create_publisher(TimeReference, "/tsg/time_shift", QOS_STREAM)
        self.create_subscription(Odometry, "/deputy/odom", self.on_deputy, QOS_STREAM)

    def on_deputy(self, msg: Odometry) -> None:
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        k, t = (stamp - self.epoch) // self.period, (stamp - self.epoch) / 1e9
        if k >= self.schedule.n_steps:
            return
        p, v = msg.pose.pose.position, msg.twist.twist.linear
        x_d = [w / 1000.0 for w in (p.x, p.y, p.z, v.x, v.y, v.z)]
        first, due = self.tau is None, self.schedule.update_due(k)
        if self.mode == "zero":
            self.tau = 0.0
        elif first:
            self.tau = self.pred.initial_shift(x_d, t)[0]
        elif due:
            self.tau = self.pred.optimal_shift(x_d, t, self.tau)[0]
        sec, nsec = divmod(stamp + round(self.tau * 1e9), 10**9)
        self.pub.publish(TimeReference(header=msg.header, time_ref=Time(sec=sec, nanosec=nsec),
                                       source="naive" if first or due else "hold"))


if __name__ == "__main__":
    given = len(sys.argv) > 1 and not sys.argv[1].startswith("--")
    mode = sys.argv[1] if given else "pistar"
    sys.exit(run_node(lambda _context: NaiveGovernor(mode), sys.argv[:1] + sys.argv[1 + given:]))
