"""governor_node: answers every state pair of the lockstep with a time shift.

For each step k it pairs /chief/odom and /deputy/odom by stamp (arrival order is never assumed),
then: k = 0 (or the first pair it sees) -> ``Governor.initial``; every P_upd -> ``Governor.update``
with its previous shift; otherwise it holds. It publishes /tsg/time_shift (TimeReference stamped
t_k, time_ref = t_k + tau, source = decision path, "hold" between updates) and a /diagnostics
record of every decision (tau, path, Verify calls, wall time).

Which governor runs is the parameter ``governor.name`` (conventional, a shipped model family, or
a model path); it may be changed while running: a model that fails to load is refused with the
reason and the running governor stays. A governor that raises during a mission is reported and
the last verified shift is held: a bad model never crashes a running mission.
"""

from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import TimeReference

from cikan_ros.governor import warm_up
from cikan_ros.mission import ClosedLoop, nominal_start
from cikan_ros.registry import make_governor
from cikan_ros.ros import cdr, convert as cv
from cikan_ros.ros.graph import QOS_LATCHED, QOS_STREAM, Readiness, qos_for, run_node
from cikan_ros.ros.graph_spec import (PATH_HOLD, CHIEF_ODOM, DEPUTY_ODOM, DIAGNOSTICS, GOVERNOR_INFO, TIME_SHIFT,
                                      required_publishers, required_readers)
from cikan_ros.ros.params import NodeSpec, declare_config, declare_parameters
from cikan_ros.tsg import Predictor

NAME = "governor_node"
#: Parameters: the groups governor and graph of config/nodes.yaml, and the mission configuration.
SPEC = NodeSpec(NAME, __doc__, ("governor", "graph"), dynamic=("governor.name",))


class GovernorNode(Node):
    """The governor node (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__(NAME)
        self.readiness = Readiness(self, "governor")   # first: the /graph/ready publisher
        self.cfg = cfg = declare_config(self)
        p = declare_parameters(self, SPEC)
        name = str(p["governor.name"])
        peers, timeout = [str(n) for n in p["graph.peers"]], float(p["graph.startup_timeout_s"])
        self.predictor = Predictor.from_config(cfg)
        self.governor = make_governor(name, cfg, self.predictor)
        self.loop = ClosedLoop(self.predictor)
        self.warm_up(self.governor)
        self.timeline = cv.Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
        self.n_steps = self.loop.n_steps
        self.tau: float | None = None
        self.last_k = -1
        self.pending: dict[int, dict[str, Any]] = {}
        self.pub_tau = self.readiness.publisher(TimeReference, TIME_SHIFT, QOS_STREAM)
        self.pub_diag = self.readiness.publisher(DiagnosticArray, DIAGNOSTICS, qos_for(DIAGNOSTICS))
        self.requested = name
        self.add_on_set_parameters_callback(self.on_parameters)
        # Raw: the states are read from their CDR bytes (cdr.odom_from_cdr), not deserialised whole.
        subs = [self.readiness.subscription(Odometry, t, lambda m, w=w: self.on_odom(w, m), QOS_STREAM, raw=True)
                for t, w in ((CHIEF_ODOM, "chief"), (DEPUTY_ODOM, "deputy"))]
        waits = [(self.pub_tau, required_readers(TIME_SHIFT, peers)),
                 (self.pub_diag, required_readers(DIAGNOSTICS, peers))]
        # Loaded and warmed up, subscribed: ready once these are matched (the sim waits for it).
        self.readiness.start(waits, [(s, required_publishers(s.topic_name, peers)) for s in subs], timeout,
                             lambda: self.get_logger().info(f"ready: governor {self.governor.name}"))

    def on_parameters(self, params: list[Any]) -> SetParametersResult:
        for p in params:
            if p.name == "governor.name":
                try:
                    new = make_governor(str(p.value), self.cfg, self.predictor)
                    self.warm_up(new)
                except Exception as exc:  # a bad model must not reach the running mission
                    self.diag("warn", f"governor {p.value!r} refused: {exc}", {"event": "refused"})
                    return SetParametersResult(successful=False, reason=str(exc))
                self.governor = new
                self.announce(str(p.value))
                self.diag("ok", f"governor switched to {new.name}", {"event": "switched"})
        return SetParametersResult(successful=True)

    def open(self) -> None:
        """Once the parameters are checked (see run_node): announce the governor."""
        self.pub_announce = self.create_publisher(DiagnosticStatus, GOVERNOR_INFO, QOS_LATCHED)
        self.announce(self.requested)

    def announce(self, requested: str) -> None:
        """Say which governor flies from now on, on the latched GOVERNOR_INFO topic (the recorder
        writes it into the bag's metadata): its name and, for a learned one, the model directory
        and the SHA-256 of its weights."""
        values = {"governor": self.governor.name, "requested": requested,
                  "scenario": self.cfg.scenario.name, "approach": self.cfg.mission.approach}
        model_dir = getattr(self.governor, "model_dir", None)
        if model_dir is not None:
            values.update(model=str(model_dir.resolve()), weights_sha256=str(self.governor.weights_sha256))
        if getattr(self.governor, "foreign", None):
            values["foreign_model"] = str(self.governor.foreign)
            self.get_logger().warning(f"flying a foreign model: {self.governor.foreign}")
        self.pub_announce.publish(cv.governor_info(NAME, values))
        self.get_logger().info(f"flying governor {self.governor.name}"
                               + (f" (model {values['model']})" if "model" in values else ""))

    def warm_up(self, governor: Any) -> None:
        """Load and run every kernel (and a learned governor's network) once, on the nominal start,
        before the governor decides in the mission: the node joins the graph (and the sim starts)
        only after this, so no decision of the mission pays for compilation or loading."""
        warm_up(governor, nominal_start(self.predictor), self.predictor.orbit.state(0.0))

    def diag(self, level: str, text: str, values: dict[str, Any], stamp: int | None = None) -> None:
        stamp = self.timeline.stamp_ns(max(self.last_k, 0)) if stamp is None else stamp
        self.pub_diag.publish(cdr.diagnostic_cdr(NAME, level, text, stamp, {"governor": self.governor.name,
                                                                              **values}))

    def on_odom(self, which: str, data: bytes) -> None:
        stamp = None   # unknown until the bytes are read
        try:
            stamp, frame, x_si = cdr.odom_from_cdr(data)
            k = self.timeline.step(stamp)
            x = cv.state_from_odom(frame, x_si)
        except cv.MessageError as exc:
            self.get_logger().warning(f"{which} state rejected: {exc}")
            self.diag("warn", f"{which} state rejected: {exc}", {"event": "rejected"}, stamp)
            return
        if k <= self.last_k:
            self.diag("warn", f"stale {which} state for step {k} (last answered {self.last_k}) rejected",
                      {"event": "rejected"}, stamp)
            return
        if k >= self.n_steps:
            return  # the final state of the mission: nothing left to decide
        entry = self.pending.setdefault(stamp, {})
        entry[which] = x
        if len(entry) == 2:
            for s in [s for s in self.pending if s <= stamp]:
                del self.pending[s]
            self.decide(k, stamp, entry["deputy"], entry["chief"])

    def decide(self, k: int, stamp: int, x_d: Any, x_c: Any) -> None:
        self.last_k = k
        try:
            rec = self.loop.decide(self.governor, k, x_d, x_c, self.tau)
            if rec is None:
                self.pub_tau.publish(cdr.time_shift_cdr(stamp, self.tau, PATH_HOLD))
                return
            msg = cdr.time_shift_cdr(stamp, rec.tau_s, rec.path)
        except Exception as exc:  # a failing governor must not end the mission: hold the last tau
            self.get_logger().error(f"governor failed at step {k}: {exc}")
            self.diag("error", f"governor failed: {exc}; holding the last verified shift",
                      {"event": "failed", "k": k}, stamp)
            if self.tau is not None:
                self.pub_tau.publish(cdr.time_shift_cdr(stamp, self.tau, PATH_HOLD))
            return
        self.tau = rec.tau_s
        self.pub_tau.publish(msg)
        self.diag("ok", "update", {"event": "update", "k": k, "tau_s": rec.tau_s, "path": rec.path,
                                   "verify_calls": rec.verify_calls, "wall_s": rec.wall_s,
                                   "cpu_s": rec.cpu_s}, stamp)


def main(args: list[str] | None = None) -> int:
    """Console entry point ``governor_node``."""
    return run_node(lambda _ctx: GovernorNode(), args, spec=SPEC)
