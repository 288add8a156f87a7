"""A governor written from the contract in docs/governor_contract.md: pi* (bisection over [tau_prev,
0]) at each update, with the cikan_ros library. Fly it: cikan mission --governor-exec "python THIS_FILE" """
import rclpy
from builtin_interfaces.msg import Time
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import TimeReference

from cikan_ros.mission import Schedule, nominal_start
from cikan_ros.ros.params import declare_config
from cikan_ros.tsg import Predictor


class CustomGovernor(Node):
    def __init__(self) -> None:
        super().__init__("custom_governor")
        cfg = declare_config(self)                     # the mission's configuration (params file)
        peers = self.declare_parameter("graph.peers", ["controller"]).value
        self.readers = sum(p in peers for p in ("controller", "recorder", "sim"))
        self.pred = Predictor.from_config(cfg)
        self.pred.initial_shift(nominal_start(self.pred), 0.0)   # warm-up: compiled kernels load now
        self.epoch, self.period = round(cfg.orbit.epoch_unix_s * 1e9), round(cfg.control.period_s * 1e9)
        self.schedule, self.tau = Schedule(cfg), None
        self.pub = self.create_publisher(TimeReference, "/tsg/time_shift", 1000)  # reliable, volatile
        self.wait = self.create_timer(0.02, self.join)

    def join(self) -> None:                            # subscribe once the shift's readers match
        # pi* needs the deputy's state only: the chief's orbit is the prediction model's
        if self.pub.get_subscription_count() >= self.readers:
            self.wait.cancel()
            self.create_subscription(Odometry, "/deputy/odom", self.on_deputy, 1000)

    def on_deputy(self, msg: Odometry) -> None:
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        k, t = (stamp - self.epoch) // self.period, (stamp - self.epoch) / 1e9
        if k >= self.schedule.n_steps:
            return                                     # the final state needs no shift
        p, v = msg.pose.pose.position, msg.twist.twist.linear
        x_d = [w / 1000.0 for w in (p.x, p.y, p.z, v.x, v.y, v.z)]   # m -> km
        first, due = self.tau is None, self.schedule.update_due(k)
        if first:
            self.tau = self.pred.initial_shift(x_d, t)[0]
        elif due:
            self.tau = self.pred.optimal_shift(x_d, t, self.tau)[0]
        sec, nsec = divmod(stamp + round(self.tau * 1e9), 10**9)   # time_ref = t_k + tau, whole ns
        self.pub.publish(TimeReference(header=msg.header, time_ref=Time(sec=sec, nanosec=nsec),
                                       source="custom:first" if first else "custom:pi*" if due else "hold"))


if __name__ == "__main__":
    rclpy.init()
    node = CustomGovernor()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
