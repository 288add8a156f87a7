"""sim_node: flies the truth (the library's :class:`~cikan_ros.truth.Truth`: the chief and the deputy
under the configured gravity, thruster errors and disturbance, ZOH), owns the lockstep and the clock
(as fast as the graph answers, or paced by ``sim.max_rtf``).

Step k: publish the MEASURED states on /chief/odom and /deputy/odom stamped t_k (SI, ECI, with the
navigation covariance), then /clock = t_k and the true ones on /truth/chief/odom and
/truth/deputy/odom; wait for the /deputy/accel_cmd stamped t_k; apply it through the thrusters;
integrate to t_{k+1} and publish the states of step k+1; then, while the governor and the
controller work on those, log step k: the acceleration as applied (/truth/deputy/accel), the
constraint margins on the truth, the applied thrust and the truth states violating h1 or h3 at
the plant's substeps strictly between t_k and t_{k+1} (``between_violations``: the substeps are
not recorded) in /diagnostics. (The bag is a sim-time record: every message of step k is
stamped t_k, whatever the order it was sent in.) A command that does not come within ``sim.command_deadline_s`` (wall; checked at a quarter of it,
:class:`~cikan_ros.ros.graph.WaitDeadline`) is replaced by zero thrust and reported; after one miss the sim waits only ``sim.lost_deadline_s``
per step until the controller answers again. Non-finite, out-of-range, off-grid or stale
commands are rejected with a diagnostic. The process ends after T_sim (or docking, with
``sim.stop_on_dock``) with a summary diagnostic (steps, wall time, real-time factor, step latency).

Telemetry and scene: once step k has both its applied thrust and its time shift (/tsg/time_shift,
read here too; a step without one holds the last, as the controller does), the simulator
publishes its telemetry on /telemetry (:mod:`cikan_ros.telemetry`, on the truth) and its scene in
the chief's LVLH frame on /scene/markers, /scene/path and /scene/constraints
(:class:`cikan_ros.scene.SceneBuilder`). It does so after publishing the states of step k+1,
while the governor and the controller work on them.
"""

from __future__ import annotations

import time

import numpy as np
from geometry_msgs.msg import AccelStamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.task import Future
from diagnostic_msgs.msg import DiagnosticArray
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState, TimeReference
from visualization_msgs.msg import MarkerArray

from cikan_ros.constraints import margins
from cikan_ros.mission import ClosedLoop, StepJudge, nominal_start, sample_start
from cikan_ros.ros import cdr, convert as cv
from cikan_ros.ros.graph import QOS_STREAM, PeerWatch, Readiness, WaitDeadline, qos_for, run_node
from cikan_ros.ros.graph_spec import (ACCEL_CMD, CHIEF_ODOM, CLOCK, DEPUTY_ODOM, DIAGNOSTICS, SCENE_CONSTRAINTS,
                                      SCENE_MARKERS, SCENE_PATH, TELEMETRY, TIME_SHIFT, TRUTH_ACCEL,
                                      TRUTH_CHIEF, TRUTH_DEPUTY, required_publishers, required_readers)
from cikan_ros.ros.scene_stream import SceneStream
from cikan_ros.truth import Truth
from cikan_ros.ros.params import NodeSpec, declare_config, declare_parameters
from cikan_ros.tsg import Predictor

NAME = "sim_node"
#: Parameters: the groups sim and graph of config/nodes.yaml, and the mission configuration.
SPEC = NodeSpec(NAME, __doc__, ("sim", "graph"))


class SimNode(Node):
    """The simulator and lockstep master (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__(NAME)
        self.readiness = Readiness(self, "sim")   # first: the /graph/ready publisher
        self.cfg = cfg = declare_config(self)
        p = declare_parameters(self, SPEC)
        seed = int(p["sim.seed"])
        self.deadline_s = float(p["sim.command_deadline_s"])
        self.lost_deadline_s = float(p["sim.lost_deadline_s"])
        self.max_rtf = float(p["sim.max_rtf"])
        self.stop_on_dock = bool(p["sim.stop_on_dock"])
        peers, timeout = [str(n) for n in p["graph.peers"]], float(p["graph.startup_timeout_s"])
        pred = Predictor.from_config(cfg)
        self.x = nominal_start(pred) if seed < 0 else sample_start(pred, seed)
        self.timeline = cv.Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
        self.loop = ClosedLoop(pred)
        self.n_steps = self.loop.n_steps
        self.truth = Truth(cfg, None if seed < 0 else seed, self.n_steps)
        self.u_max = cfg.control.u_max_kmps2
        self.u_limit = cfg.thrust_limit_kmps2  # h2 on the truth
        self.judge = StepJudge(cfg, self.u_limit)
        self.k = 0
        self.x_c = np.zeros(6)
        self.misses = 0
        self.rejected = 0
        self.latency_ms: list[float] = []          # steps where the governor holds tau
        self.latency_update_ms: list[float] = []   # the first step and the update steps
        self.worst = [(-1.0, -1), (-1.0, -1)]     # (longest latency ms, its step): holding, deciding
        self.done = Future()
        self.pub_clock = self.readiness.publisher(ClockMsg, CLOCK, QOS_STREAM)
        self.pub_chief = self.readiness.publisher(Odometry, CHIEF_ODOM, QOS_STREAM)
        self.pub_deputy = self.readiness.publisher(Odometry, DEPUTY_ODOM, QOS_STREAM)
        self.pub_diag = self.readiness.publisher(DiagnosticArray, DIAGNOSTICS, qos_for(DIAGNOSTICS))
        self.pub_truth_chief = self.readiness.publisher(Odometry, TRUTH_CHIEF, QOS_STREAM)
        self.pub_truth_deputy = self.readiness.publisher(Odometry, TRUTH_DEPUTY, QOS_STREAM)
        self.pub_truth_accel = self.readiness.publisher(AccelStamped, TRUTH_ACCEL, QOS_STREAM)
        # Every message of a step goes out serialised (cikan_ros.ros.cdr, published raw): the
        # states and the applied thrust refilled in place, the clock and the diagnostics written whole.
        self.truth_accel = cdr.AccelCdr()
        self.serialised = {"truth_chief": cdr.OdometryCdr("chief", False),
                           "truth_deputy": cdr.OdometryCdr("deputy", False),
                           "chief": cdr.OdometryCdr("chief", True), "deputy": cdr.OdometryCdr("deputy", True)}
        # Raw: the command and the shift are read from their CDR bytes (cikan_ros.ros.cdr).
        self.sub_accel = self.readiness.subscription(AccelStamped, ACCEL_CMD, self.on_accel, QOS_STREAM, raw=True)
        self.sub_shift = self.readiness.subscription(TimeReference, TIME_SHIFT, self.on_shift, QOS_STREAM, raw=True)
        self.pub_scene = {TELEMETRY: self.readiness.publisher(JointState, TELEMETRY, QOS_STREAM)}
        self.pub_scene.update({t: self.readiness.publisher(MarkerArray, t, QOS_STREAM)
                               for t in (SCENE_MARKERS, SCENE_PATH, SCENE_CONSTRAINTS)})
        self.scene = SceneStream(cfg, pred)
        self.warm_up(pred)
        self.shifts: dict[int, float] = {}      # stamp -> tau (s) of the shifts not yet used
        self.steps: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []  # (k, x_c, x_d, u) awaiting a shift
        self.tau_held = float("nan")
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.wait = WaitDeadline(self, self.deadline_s, self.lost_deadline_s, self.on_deadline,
                                 ("sim.command_deadline_s", "sim.lost_deadline_s"))
        waits = [(p, required_readers(t, peers)) for p, t in
                 ((self.pub_deputy, DEPUTY_ODOM), (self.pub_chief, CHIEF_ODOM), (self.pub_clock, CLOCK),
                  (self.pub_diag, DIAGNOSTICS), (self.pub_truth_chief, TRUTH_CHIEF),
                  (self.pub_truth_deputy, TRUTH_DEPUTY), (self.pub_truth_accel, TRUTH_ACCEL),
                  *((pub, t) for t, pub in self.pub_scene.items()))]
        self.peers = PeerWatch(self.readiness, peers)
        self.readiness.start(waits, [(self.sub_accel, required_publishers(ACCEL_CMD, peers)),
                                     (self.sub_shift, required_publishers(TIME_SHIFT, peers))], timeout,
                             self.start, self.peers.missing)

    def warm_up(self, pred: Predictor) -> None:
        """Load every compiled kernel a step uses (the plant, the margins, the telemetry and the
        scene) once on the start state, answers discarded, before the node is ready: no step of
        the lockstep pays for loading them (measured: ~25 ms at the first step otherwise, most of it
        while the governor and the controller already work on the next). The scene's on a stream of
        its own: this one's messages begin at step 0."""
        x_c, u = self.truth.chief_state(0), np.zeros(3)
        path = self.truth.deputy_path(0, self.x, u)
        self.judge(self.x, x_c, u, path, self.truth.chief_path(0))
        stamp = self.timeline.stamp_ns(0)
        SceneStream(self.cfg, pred).step(0, stamp, self.timeline.seconds(stamp), x_c, self.x, u, 0.0)

    # -- lockstep -------------------------------------------------------------------------------
    def start(self) -> None:
        self.get_logger().info(f"lockstep start: {self.n_steps} steps of {self.cfg.control.period_s:g} s")
        self.wall0 = time.perf_counter()
        if self.publish_state():
            self.finish()

    def stamp(self) -> int:
        return self.timeline.stamp_ns(self.k)

    def publish_state(self) -> bool:
        """Publish the states of step k, then wait for its command; True when the mission ends at
        this state instead (the caller then finishes it: :meth:`finish`).

        The measured states go out first: the governor and the controller wait for them; /clock
        and the truth (for the recorder) follow while they work."""
        stamp = self.stamp()
        truth = self.truth
        self.x_c = truth.chief_state(self.k)
        x_seen, cov = truth.measure_deputy(self.k, self.x)
        states = self.serialised
        self.pub_chief.publish(states["chief"](truth.measure_chief(self.k), stamp, 0.0 * cov))
        self.pub_deputy.publish(states["deputy"](x_seen, stamp, cov))
        self.t_published = time.perf_counter()
        self.pub_clock.publish(cdr.clock_cdr(stamp))
        self.pub_truth_chief.publish(states["truth_chief"](self.x_c, stamp))
        self.pub_truth_deputy.publish(states["truth_deputy"](self.x, stamp))
        if self.loop.finished(self.k, self.x, self.x_c, self.stop_on_dock):
            return True
        self.wait.start(self.t_published)
        return False

    def on_accel(self, data: bytes) -> None:
        """A serialised AccelStamped (raw subscription): the command of a step."""
        try:
            stamp, frame, a_si = cdr.accel_from_cdr(data)
        except cv.MessageError as exc:
            self.reject(f"command rejected: {exc}", self.stamp())
            return
        if not self.wait.waiting or stamp != self.stamp():
            self.wait.heard()  # the controller is alive again; its next answer will be awaited
            self.reject(f"stale command stamped {stamp} ns (expected {self.stamp()} ns)", stamp)
            return
        try:
            u = cv.accel_from_si(frame, a_si, self.u_max)
        except cv.MessageError as exc:
            self.reject(f"command rejected: {exc}", stamp)
            return
        self.wait.heard()
        self.apply(u, "command")

    def on_deadline(self) -> None:
        """No command came within the deadline (:class:`WaitDeadline`): zero thrust."""
        self.misses += 1
        self.get_logger().warning(f"no command for t_k = {self.stamp()} ns: zero thrust")
        self.apply(np.zeros(3), "zero-deadline")

    def reject(self, text: str, stamp: int) -> None:
        self.rejected += 1
        self.get_logger().warning(text)
        self.pub_diag.publish(cdr.diagnostic_cdr(NAME, "warn", text, self.stamp(),
                                                 {"k": self.k, "event": "rejected", "stamp_ns": stamp}))

    def apply(self, u: np.ndarray, source: str) -> None:
        """Integrate step k with the applied thrust u (km/s^2) to k+1 and publish the states of
        k+1; then, while the governor and the controller work on them, log step k: the thrust as
        applied, its margins and the violations between the samples, its telemetry and scene."""
        self.wait.stop()
        ms = (time.perf_counter() - self.t_published) * 1e3
        k, x_c, x = self.k, self.x_c, self.x
        if source == "command":
            decision = k == 0 or self.loop.update_due(k)
            (self.latency_update_ms if decision else self.latency_ms).append(ms)
            if ms > self.worst[decision][0]:
                self.worst[decision] = (ms, k)
        u = self.truth.applied_thrust(u)  # through the thrusters: the acceleration as applied
        path = self.truth.deputy_path(k, x, u)
        self.steps.append((k, x_c, x, u))
        self.x = path[-1]
        self.k += 1
        pause = self.wall0 + self.k * self.cfg.control.period_s / self.max_rtf - time.perf_counter() \
            if self.max_rtf > 0 else 0.0
        if pause > 0:
            self.pace = self.create_timer(pause, lambda k=self.k: self.paced(k), clock=self.steady)
            ended = False
        else:
            ended = self.publish_state()
        stamp = self.timeline.stamp_ns(k)
        self.pub_truth_accel.publish(self.truth_accel(u, stamp))
        h1n, h2, h3, between = self.judge(x, x_c, u, path, self.truth.chief_path(k))
        level = "ok" if source == "command" else "warn"
        text = "step" if source == "command" else "controller missed its deadline: zero thrust"
        self.pub_diag.publish(cdr.diagnostic_cdr(NAME, level, text, stamp, {
            "k": k, "event": "step", "thrust": source, "u_kmps2": u,
            "h1_normalised": h1n, "h2_kmps2": h2, "h3_kmps": h3,
            "between_violations": between, "latency_ms": ms}))
        if ended:
            self.finish()
        else:
            self.publish_scene()

    # -- telemetry and scene --------------------------------------------------------------------
    def on_shift(self, data: bytes) -> None:
        """A serialised time shift (raw subscription): kept for the telemetry and the scene of its
        step (never for control)."""
        try:
            stamp, tau, _source = cv.shift_from_times(*cdr.shift_from_cdr(data), self.cfg.side)
        except cv.MessageError:
            return  # the controller reports a bad shift; the scene holds the last good one
        self.shifts.setdefault(stamp, tau)
        if self.steps:
            self.publish_scene()

    def publish_scene(self, final: bool = False) -> None:
        """Telemetry and scene of every applied step whose shift has come (and, once a later shift
        has come or the mission ended, of the steps before it that got none: the last shift holds)."""
        latest = max(self.shifts, default=-1)
        while self.steps:
            k, x_c, x_d, u = self.steps[0]
            stamp = self.timeline.stamp_ns(k)
            if stamp in self.shifts:
                self.tau_held = self.shifts.pop(stamp)
            elif stamp > latest and not final:
                return
            self.steps.pop(0)
            self.emit_scene(k, x_c, x_d, u, self.tau_held, last=final and not self.steps)
        oldest = self.timeline.stamp_ns(self.steps[0][0] if self.steps else self.k)
        for stamp in [s for s in self.shifts if s < oldest]:
            del self.shifts[stamp]  # a second shift of a step already shown

    def emit_scene(self, k: int, x_c: np.ndarray, x_d: np.ndarray, u: np.ndarray, tau: float,
                   last: bool = False) -> None:
        stamp = self.timeline.stamp_ns(k)
        for topic, msg in self.scene.step(k, stamp, self.timeline.seconds(stamp), x_c, x_d, u, tau, last):
            self.pub_scene[topic].publish(msg)

    def paced(self, k: int) -> None:
        """One-shot pacing timer of step k. A loaded executor may deliver two expiries of it
        before the first is handled (seen: step k published twice): only the first counts."""
        if self.pace is None or k != self.k:
            return
        self.destroy_timer(self.pace)
        self.pace = None
        if self.publish_state():
            self.finish()

    def finish(self) -> None:
        wall = time.perf_counter() - self.wall0
        self.steps.append((self.k, self.x_c, self.x, np.zeros(3)))  # the last state: no command
        self.publish_scene(final=True)
        m = margins(self.x, self.x_c, np.zeros(3), self.cfg.constraints, self.u_limit, self.cfg.side)
        steady = np.array(self.latency_ms)  # steps where the governor only holds tau
        sim_s = self.k * self.cfg.control.period_s
        values = {"k": self.k, "event": "complete", "steps": self.k, "wall_s": wall,
                  "rtf": sim_s / wall if wall > 0 else float("inf"),
                  "step_ms_p50": float(np.percentile(steady, 50)) if steady.size else float("nan"),
                  "step_ms_p99": float(np.percentile(steady, 99)) if steady.size else float("nan"),
                  "step_ms_max": float(steady.max()) if steady.size else float("nan"),
                  "update_step_ms_max": max(self.latency_update_ms, default=float("nan")),
                  "step_ms_max_k": self.worst[False][1], "update_step_ms_max_k": self.worst[True][1],
                  "deadline_misses": self.misses, "rejected": self.rejected,
                  "h1_normalised": m.h1_normalised[0], "h3_kmps": m.h3[0]}
        self.pub_diag.publish(cdr.diagnostic_cdr(NAME, "ok", "mission complete", self.stamp(), values))
        self.get_logger().info(f"mission complete: {self.k} steps in {wall:.2f} s "
                               f"(rtf {values['rtf']:.0f}), {self.misses} deadline misses")
        self.done.set_result(True)

def main(args: list[str] | None = None) -> int:
    """Console entry point ``sim_node``."""
    return run_node(lambda _ctx: SimNode(), args, spec=SPEC)
