"""controller_node: saturated FTRE control toward the virtual target x_v(t) = x_c(t + tau).

For each step k it pairs /deputy/odom, /chief/odom and /tsg/time_shift by stamp, computes
u = sat(-K(nu_v)(x_d - x_v)) with x_v the measured chief propagated by tau (the library's
``ClosedLoop.command``, which anchors the chief on the state it receives) and publishes
/deputy/accel_cmd (AccelStamped, m/s^2, ECI) stamped t_k.

If the shift of a step does not come within ``controller.tau_deadline_s`` (wall; checked at a
quarter of it, :class:`~cikan_ros.ros.graph.WaitDeadline`), the controller
holds the last verified shift (still feasible by recursive feasibility), reports it in
/diagnostics, and from then on waits only ``controller.lost_deadline_s`` per step until the
governor answers again. Without any verified shift it sends no command (the simulator then
applies zero thrust). Non-finite, off-grid, positive or stale inputs are rejected with a diagnostic.
"""

from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import AccelStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import TimeReference

from cikan_ros.mission import ClosedLoop, nominal_start
from cikan_ros.ros import cdr, convert as cv
from cikan_ros.ros.graph import QOS_STREAM, Readiness, WaitDeadline, qos_for, run_node
from cikan_ros.ros.graph_spec import (PATH_HOLD, ACCEL_CMD, CHIEF_ODOM, DEPUTY_ODOM, DIAGNOSTICS, TIME_SHIFT,
                                      required_publishers, required_readers)
from cikan_ros.ros.params import NodeSpec, declare_config, declare_parameters
from cikan_ros.tsg import Predictor

NAME = "controller_node"
#: Parameters: the groups controller and graph of config/nodes.yaml, and the mission configuration.
SPEC = NodeSpec(NAME, __doc__, ("controller", "graph"))


class ControllerNode(Node):
    """The controller node (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__(NAME)
        self.readiness = Readiness(self, "controller")   # first: the /graph/ready publisher
        self.cfg = cfg = declare_config(self)
        p = declare_parameters(self, SPEC)
        deadline = float(p["controller.tau_deadline_s"])
        lost = float(p["controller.lost_deadline_s"])
        peers, timeout = [str(n) for n in p["graph.peers"]], float(p["graph.startup_timeout_s"])
        pred = Predictor.from_config(cfg)
        self.loop = ClosedLoop(pred)
        self.loop.warm_up(nominal_start(pred), pred.orbit.state(0.0))  # kernels loaded before ready
        self.timeline = cv.Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
        self.n_steps = self.loop.n_steps
        self.tau: float | None = None     # last verified shift (s)
        self.last_stamp = -1              # last step answered
        self.waiting: int | None = None   # step whose shift is awaited
        self.pending: dict[int, dict[str, Any]] = {}
        self.pub_accel = self.readiness.publisher(AccelStamped, ACCEL_CMD, QOS_STREAM)
        self.accel_out = cdr.AccelCdr()  # the publisher's own message, serialised and refilled in place
        self.pub_diag = self.readiness.publisher(DiagnosticArray, DIAGNOSTICS, qos_for(DIAGNOSTICS))
        self.wait = WaitDeadline(self, deadline, lost, self.on_deadline,
                                 ("controller.tau_deadline_s", "controller.lost_deadline_s"))
        # Raw: the states and the shift are read from their CDR bytes (cikan_ros.ros.cdr), not
        # deserialised whole.
        subs = [self.readiness.subscription(Odometry, DEPUTY_ODOM, self.on_deputy, QOS_STREAM, raw=True),
                self.readiness.subscription(Odometry, CHIEF_ODOM, self.on_chief, QOS_STREAM, raw=True),
                self.readiness.subscription(TimeReference, TIME_SHIFT, self.on_shift, QOS_STREAM, raw=True)]
        waits = [(self.pub_accel, required_readers(ACCEL_CMD, peers)),
                 (self.pub_diag, required_readers(DIAGNOSTICS, peers))]
        # Ready once the sim's states and the governor's shift are matched (the sim waits for it):
        # a governor that does not announce itself is known ready by this /tsg/time_shift match.
        self.readiness.start(waits, [(s, required_publishers(s.topic_name, peers)) for s in subs], timeout,
                             lambda: None)

    def diag(self, level: str, text: str, stamp: int, values: dict[str, Any]) -> None:
        self.pub_diag.publish(cdr.diagnostic_cdr(NAME, level, text, stamp, values))

    def stamp_or_last(self, stamp: int | None) -> int:
        """The stamp a rejection is reported at: the message's, or, when it could not be read,
        the last step answered (the epoch before any)."""
        return max(self.last_stamp, self.timeline.epoch_ns) if stamp is None else stamp

    def reject(self, text: str, stamp: int) -> None:
        self.get_logger().warning(text)
        self.diag("warn", text, stamp, {"event": "rejected"})

    def on_deputy(self, data: bytes) -> None:
        self.on_state(data, "deputy", "x")

    def on_chief(self, data: bytes) -> None:
        self.on_state(data, "chief", "xc")

    def on_state(self, data: bytes, who: str, key: str) -> None:
        """A serialised Odometry (raw subscription): the state of a step."""
        stamp = None   # unknown until the bytes are read
        try:
            stamp, frame, x_si = cdr.odom_from_cdr(data)
            k = self.timeline.step(stamp)
            x = cv.state_from_odom(frame, x_si)
        except cv.MessageError as exc:
            self.reject(f"{who} state rejected: {exc}", self.stamp_or_last(stamp))
            return
        if stamp <= self.last_stamp:
            self.reject(f"stale {who} state for step {k} rejected", stamp)
            return
        if k >= self.n_steps:
            return  # final state: no command
        self.pending.setdefault(stamp, {})[key] = x
        self.try_command(stamp)

    def on_shift(self, data: bytes) -> None:
        """A serialised TimeReference (raw subscription): the shift of a step."""
        stamp = None   # unknown until the bytes are read
        try:
            stamp, time_ref, source = cdr.shift_from_cdr(data)
            stamp, tau, source = cv.shift_from_times(stamp, time_ref, source, self.cfg.side)
            self.timeline.step(stamp)
        except cv.MessageError as exc:
            self.reject(f"time shift rejected: {exc}", self.stamp_or_last(stamp))
            return
        self.wait.heard()  # the governor is alive: wait for it again
        if stamp <= self.last_stamp:
            self.reject(f"stale time shift stamped {stamp} ns rejected (late governor)", stamp)
            return
        self.pending.setdefault(stamp, {})["tau"] = (tau, source)
        self.try_command(stamp)

    def try_command(self, stamp: int) -> None:
        entry = self.pending[stamp]
        if "x" not in entry or "xc" not in entry:
            return
        if "tau" in entry:
            self.command(stamp, entry["x"], entry["xc"], *entry["tau"])
        elif self.waiting != stamp:
            self.waiting = stamp
            self.wait.start()

    def on_deadline(self) -> None:
        """No shift came within the deadline (:class:`WaitDeadline`): hold the last verified one."""
        stamp, self.waiting = self.waiting, None
        if stamp is None or stamp <= self.last_stamp:
            return
        if self.tau is None:
            self.diag("error", "no verified time shift yet: no command", stamp, {"event": "no-shift"})
            return
        self.diag("warn", "governor missed its deadline: holding the last verified time shift", stamp,
                  {"event": "hold", "tau_s": self.tau})
        entry = self.pending[stamp]
        self.command(stamp, entry["x"], entry["xc"], self.tau, PATH_HOLD)

    def command(self, stamp: int, x_d: Any, x_c: Any, tau: float, source: str) -> None:
        """u toward x_v = x_c(t_k + tau) (x_c the measured chief), published stamped t_k. Under the
        ancillary tube a new shift's accepted rollout becomes the plan the command tracks
        (``ClosedLoop.take_effect``, the offline loop's); one whose rollout does not pass robust
        Verify here is not flown: the shift in force holds, with a diagnostic."""
        self.wait.stop()
        self.waiting = None
        k = self.timeline.step(stamp)
        self.loop.observe(k, x_c, self.tau)
        if tau != self.tau and not self.loop.take_effect(k, tau, x_d):
            text = (f"the plan of time shift {tau} s does not pass robust Verify from this step's state: "
                    "holding the shift in force")
            self.get_logger().warning(text)
            self.diag("warn", text, stamp, {"event": "plan-refused", "tau_s": tau})
            if self.tau is None:
                return
            tau = self.tau
        u = self.loop.command(k, tau, x_d, x_c)
        self.pub_accel.publish(self.accel_out(u, stamp))
        self.tau = tau
        self.last_stamp = stamp
        for s in [s for s in self.pending if s <= stamp]:
            del self.pending[s]


def main(args: list[str] | None = None) -> int:
    """Console entry point ``controller_node``."""
    return run_node(lambda _ctx: ControllerNode(), args, spec=SPEC)
