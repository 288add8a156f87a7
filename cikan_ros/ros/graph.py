"""What every node process of the graph shares at run time: the QoS profiles of the topic table's
kinds, readiness (:class:`Readiness`, :class:`PeerWatch`), the executor, the deadline of a
lockstep wait (:class:`WaitDeadline`), the acknowledgement wait and the Jazzy shutdown pattern
(:func:`run_node`). The topics themselves (names, types, who
writes and reads each) are plain data in :mod:`cikan_ros.ros.graph_spec`; node parameters are
declared from data by :mod:`cikan_ros.ros.params` (``config/nodes.yaml``).

QoS, chosen on purpose:

- Every topic of the graph is RELIABLE, VOLATILE, KEEP_LAST 4000 on both sides. Lockstep needs
  every state, shift and command (a lost one would stall a step until a deadline); a late joiner
  must not act on old states, so no durability. The depth is for the recorder, which is not
  part of the lockstep: reliable KEEP_LAST does not throttle a publisher, so a writer history of
  10 let a recorder starved of CPU (a torch governor on 2 cores) lose states; 1000 samples per
  topic let it fall 1000 steps behind and catch up, until the truth's three topics made nine for
  it to drain (a fresh clone's run lost truth states once with a governor that answers at once);
  4000 (about 3 MB per topic, more than the 1441 steps of a 4-h mission) lets it fall behind a
  whole mission. KEEP_ALL was not chosen: it
  blocks publishers when a reader dies without being noticed, which would stall the lockstep.
- ``/clock`` offered the same way: compatible with rclpy's own best-effort /clock subscription,
  and the recorder and replay keep every tick.
- ``/graph/ready`` (the readiness handshake) likewise RELIABLE, TRANSIENT_LOCAL, depth 1 per
  writer: a simulator that starts after a peer still hears its announcement. Its reader is
  deeper (:data:`QOS_READY_READER`): one reader history holds every writer's announcement.
- ``/tsg/governor`` (the governor's announcement of which governor flies): RELIABLE,
  TRANSIENT_LOCAL, depth 1, so a recorder that joins later still hears the last one.
"""

from __future__ import annotations

import faulthandler
import gc
import math
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterable

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..errors import CikanError, ConfigError
from .profile import NodeProfile
from . import graph_spec
from .graph_spec import (ACK_BUDGET_S, CHIEF_ODOM, DEPUTY_ODOM, EXIT_BAD_INPUT, EXIT_NO_PEERS, READY, TIME_SHIFT,
                         TOPICS, expected_readers, expected_writers)
from .params import command_line_names, parse_node_args, plain, ros_section, unknown_overrides

# -- QoS ----------------------------------------------------------------------------------------
QOS_STREAM = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=4000,
                        reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
#: /tsg/governor: the last announcement reaches readers that join later (transient local, depth 1).
QOS_LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: The profile of each QoS kind of the topic table (:data:`cikan_ros.ros.graph_spec.QOS_KINDS`).
QOS_PROFILES: dict[str, QoSProfile] = {"stream": QOS_STREAM, "latched": QOS_LATCHED}

#: The reader of /graph/ready: transient local like its writers, but deep. A keyless topic's
#: reader history is shared by all writers, so at depth 1 a peer's announcement that arrives
#: before the executor took another's replaces it (seen: the controller's lost, the sim waited).
QOS_READY_READER = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=64, reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)


def qos_for(topic: str) -> QoSProfile:
    """The QoS a node of the graph offers or requests on ``topic``: its kind's (the same for all
    writers and readers, but the reader of /graph/ready, :data:`QOS_READY_READER`)."""
    return QOS_PROFILES[TOPICS[topic].qos]


# -- executor and process lifecycle -------------------------------------------------------------
#: Executor of every node process, chosen by measurement (``cikan bench``, 4-h lockstep mission,
#: 2 loaded cores): rclpy.experimental.EventsExecutor gave step p50 0.7-0.9 ms, p99 5.0-5.4 ms,
#: rtf 4200-5600; SingleThreadedExecutor p50 1.6-2.2 ms, p99 6.9-8.8 ms, rtf 2500-3400. With the
#: rclpy 7.1.6 wheels the EventsExecutor fires timers only inside a spin with a timeout
#: (spin() and spin_until_future_complete() without one never fire them, and ignore SIGINT), so
#: :func:`run_node` spins it in 0.5-s slices. ``CIKAN_ROS_EXECUTOR=single`` selects the other.
EXECUTORS = ("events", "single")


def executor_kind() -> str:
    """Which of :data:`EXECUTORS` this process spins (``CIKAN_ROS_EXECUTOR``, default events)."""
    kind = os.environ.get("CIKAN_ROS_EXECUTOR", "events")
    if kind not in EXECUTORS:
        raise ConfigError(f"CIKAN_ROS_EXECUTOR must be one of {EXECUTORS}, got {kind!r}")
    return kind


def make_executor(context: Any = None) -> Any:
    """The process's one executor (see :data:`EXECUTORS`)."""
    if executor_kind() == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor(context=context)
    from rclpy.executors import SingleThreadedExecutor

    return SingleThreadedExecutor(context=context)


class Readiness:
    """The readiness handshake every node of the graph takes part in (docs/governor_contract.md, "Start").

    Construct it first thing in the node: it creates the node's /graph/ready publisher (latched:
    RELIABLE, TRANSIENT_LOCAL, depth 1) before any other endpoint, so a peer that discovers one
    of the node's topics has already discovered that the node will announce itself. Then, once
    the node has loaded, warmed up and made its publishers and subscriptions, :meth:`start` polls
    (on a steady timer, never blocking) until

    - each of its publishers is matched (writer side) to its required readers and to every reader
      of that topic discovered on the domain (``waits``),
    - each of its subscriptions is matched to its required publishers (``reads``),
    - its /graph/ready writer is matched to the simulator's reader (and to every reader of
      /graph/ready discovered on the domain),
    - ``check()`` (if given) reports nothing missing,

    then calls ``prepare`` (if given: what the node does once its peers are known and before the
    lockstep can start, such as the recorder registering its topics), announces ``ready`` on
    /graph/ready (DiagnosticStatus: name = peer name, hardware_id = node name, values ``reads``,
    ``writes`` and ``wall_ns``) and calls ``on_ready`` once. It logs
    what it waits for; after ``timeout_s`` it logs one error line naming what is missing and ends
    the node with :data:`EXIT_NO_PEERS` (through the node's ``done`` future, see
    :func:`run_node`); a ``timeout_s`` of ``inf`` waits for ever (the recorder).

    The announcement waits for its own writer's match so that it goes to a reader the writer
    knows, as live data, rather than relying on the latched copy a late-matched reader is owed.
    (A loaded soak, 2 of 30 missions, once saw the simulator never receive one peer's
    announcement; the cause measured since was Fast DDS's shared-memory transport, which graphs
    no longer use: :func:`cikan_ros.ros.launch.dds_environment`, docs/ros_soak.md.)
    """

    def __init__(self, node: Any, peer: str) -> None:
        from diagnostic_msgs.msg import DiagnosticStatus

        self.node, self.peer = node, peer
        self.ready = False
        self._timer = self._drop = None
        self.pub = self.publisher(DiagnosticStatus, READY, QOS_LATCHED)

    def publisher_events(self) -> Any:
        """Event callbacks for the node's publishers: a matched event re-checks at once."""
        from rclpy.event_handler import PublisherEventCallbacks

        return PublisherEventCallbacks(matched=lambda _status: self.poke())

    def subscription_events(self) -> Any:
        """Event callbacks for the node's subscriptions: a matched event re-checks at once."""
        from rclpy.event_handler import SubscriptionEventCallbacks

        return SubscriptionEventCallbacks(matched=lambda _status: self.poke())

    def publisher(self, msg_type: Any, topic: str, qos: Any) -> Any:
        """``node.create_publisher`` with :meth:`publisher_events`: a publisher readiness watches."""
        return self.node.create_publisher(msg_type, topic, qos, event_callbacks=self.publisher_events())

    def subscription(self, msg_type: Any, topic: str, callback: Callable[[Any], None], qos: Any,
                     **kwargs: Any) -> Any:
        """``node.create_subscription`` with :meth:`subscription_events` (``kwargs``: e.g. raw)."""
        return self.node.create_subscription(msg_type, topic, callback, qos,
                                             event_callbacks=self.subscription_events(), **kwargs)

    def poke(self) -> None:
        """Re-check now (a matched event, an announcement): between polls of the timer."""
        done = getattr(self.node, "done", None)
        if self._timer is not None and not self.ready and not (done is not None and done.done()):
            self._poll()

    def start(self, waits: list[tuple[Any, int]], reads: list[tuple[Any, int]], timeout_s: float,
              on_ready: Callable[[], None], check: Callable[[], list[str]] | None = None,
              prepare: Callable[[], None] | None = None) -> None:
        from rclpy.clock import Clock, ClockType

        peers = plain(self.node.get_parameter("graph.peers").value) if self.node.has_parameter("graph.peers") \
            else []
        # The announcement's own writer too (see the class docstring): matched to the simulator's reader.
        waits = [*waits, (self.pub, 1 if "sim" in peers else 0)]
        self.waits, self.reads, self.timeout_s, self.on_ready, self.check = waits, reads, timeout_s, \
            on_ready, check
        self.prepare = prepare
        self._clock = Clock(clock_type=ClockType.STEADY_TIME)
        self._t0 = self._clock.now()
        self._said = False
        # Matched events (rclpy's PublisherEventCallbacks / SubscriptionEventCallbacks, measured to
        # fire with both executors) and announcements re-check at once; this poll covers what has
        # no event (discovery of other nodes' endpoints) and the timeout.
        self._timer = self.node.create_timer(0.1, self._poll, clock=self._clock)

    def missing(self) -> list[str]:
        """One text per endpoint not yet matched (how many, from whom, who is there), then check()'s."""
        peers = set(plain(self.node.get_parameter("graph.peers").value)) \
            if self.node.has_parameter("graph.peers") else set()
        out = []
        for pub, n in self.waits:
            topic = pub.topic_name
            count = pub.get_subscription_count()
            readers = self.node.get_subscriptions_info_by_topic(topic)
            if count >= max(n, len(readers)):
                continue
            expected = expected_readers(topic, peers) if topic in TOPICS else []
            there = sorted({i.node_name for i in readers})
            out.append(f"{topic}: {count} of {max(n, len(readers))} readers matched (expected "
                       f"{', '.join(expected) or '-'}" + (f"; discovered {', '.join(there)})" if there else ")"))
        for sub, n in self.reads:
            count = sub.get_publisher_count()
            if count < n:
                out.append(f"{sub.topic_name}: {count} of {n} publishers matched "
                           f"(expected {', '.join(expected_writers(sub.topic_name, peers) if sub.topic_name in TOPICS else []) or '-'})")
        if self.check is not None:
            out.extend(self.check())
        return out

    def _poll(self) -> None:
        missing = self.missing()
        waited = (self._clock.now() - self._t0).nanoseconds / 1e9
        if missing and waited < self.timeout_s:
            if not self._said and waited >= 0.5:
                self._said = True
                self.node.get_logger().info(
                    f"waiting up to {self.timeout_s:g} s (graph.startup_timeout_s) for " + "; ".join(missing))
            return
        self._timer.cancel()
        self.node.destroy_timer(self._timer)
        self._timer = None
        if missing:
            self.node.get_logger().error(
                f"giving up after {waited:.1f} s (graph.startup_timeout_s): not ready: " + "; ".join(missing)
                + " (start those nodes on this ROS_DOMAIN_ID, or set graph.peers)")
            self.node.exit_code = EXIT_NO_PEERS
            self.node.done.set_result(False)
            return
        if self.prepare is not None:
            self.prepare()
        self.announce()
        self.on_ready()
        if executor_kind() == "single":
            # From a timer of its own, not here: this may run in the callback of one of the handlers
            # it drops (a matched event), and dropped from there the executor ran badly in about
            # half of the missions (measured, robust Verify: step p99 6-13 ms against 2.6-3.1).
            self._drop = self.node.create_timer(0.05, self._drop_event_handlers, clock=self._clock)

    def _drop_event_handlers(self) -> None:
        self._drop.cancel()
        self.node.destroy_timer(self._drop)
        drop_event_handlers(self.node)

    def announce(self) -> None:
        from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

        # Logged before it is said: the process's first rclpy log line costs 20-25 ms (rclpy finds
        # the caller with inspect, which maps every loaded module to its file once), and said
        # first it landed in the lockstep's first step (measured: step 0 at 22-32 ms against 5).
        self.node.get_logger().info("ready: announcing it on /graph/ready")
        self.ready = True
        values = {"reads": ",".join(s.topic_name for s, _ in self.reads),
                  "writes": ",".join(p.topic_name for p, _ in self.waits if p is not self.pub),
                  "wall_ns": str(time.time_ns())}
        self.pub.publish(DiagnosticStatus(
            level=DiagnosticStatus.OK, name=self.peer, message="ready",
            hardware_id=self.node.get_fully_qualified_name(),
            values=[KeyValue(key=k, value=v) for k, v in values.items()]))


def drop_event_handlers(node: Any) -> int:
    """Take the QoS event handlers of every publisher and subscription ``node`` has now out of
    its wait set (the matched events :class:`Readiness` watches, and rclpy's default
    incompatible-QoS and incompatible-type warnings); returns how many. Once a node is ready
    nothing needs them (an endpoint that joins later with an incompatible QoS or type still gets
    its warning, on its side), and under the SingleThreadedExecutor each costs every wait: a
    Python waitable, three per endpoint, 40 % of the controller's executor CPU (profiled). The
    handles are left to the collector, not destroyed: the wait in progress may still take an
    event of theirs. The events executor pays nothing for them and keeps them."""
    count = 0
    for endpoint in [*node.publishers, *node.subscriptions]:
        for handler in endpoint.event_handlers:
            node.remove_waitable(handler)
            count += 1
        endpoint.event_handlers = []
    return count


class WaitDeadline:
    """The wall-clock deadline of a wait that repeats every step (the simulator waiting for a
    command, the controller for a shift): ``on_miss`` runs once a wait begun by :meth:`start`
    has lasted ``deadline_s`` without :meth:`stop`; after a miss the next waits get only
    ``lost_deadline_s`` (the peer is presumed gone) until :meth:`heard` says it answered again.

    Checked by timers that run on their own, at a quarter of the deadline (a miss is seen within
    1 to 1.25 deadlines): no timer is re-armed or cancelled per step. The events executor wakes
    its timer thread at every reset or cancel, and the two per step of the simulator and of the
    controller cost the lockstep ~6 % of its CPU (measured with ``cikan bench``'s missions).
    """

    #: Checks per deadline.
    CHECKS = 4

    def __init__(self, node: Any, deadline_s: float, lost_deadline_s: float, on_miss: Callable[[], None],
                 names: tuple[str, str] = ("deadline", "lost deadline")) -> None:
        """``names``: the parameters the two deadlines come from (bad input names them)."""
        from rclpy.clock import Clock, ClockType

        self.deadline_s, self.lost_deadline_s = float(deadline_s), float(lost_deadline_s)
        for name, value in zip(names, (self.deadline_s, self.lost_deadline_s)):
            if not 0.0 < value < math.inf:
                raise ConfigError(f"{name} must be a positive number of seconds, got {value!r}")
        self.on_miss = on_miss
        self.lost = False
        self.since: float | None = None   # perf_counter at the start of the wait, None: not waiting
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._normal = node.create_timer(self.deadline_s / self.CHECKS, self._check, clock=steady)
        self._lost = node.create_timer(self.lost_deadline_s / self.CHECKS, self._check, clock=steady,
                                       autostart=False)   # runs only while the peer is presumed gone

    @property
    def waiting(self) -> bool:
        return self.since is not None

    def start(self, since: float | None = None) -> None:
        """A wait begins (at ``since``, a ``time.perf_counter()`` reading; default now)."""
        self.since = time.perf_counter() if since is None else since

    def stop(self) -> None:
        """The wait is over (answered, or given up)."""
        self.since = None

    def heard(self) -> None:
        """The peer answered: the next waits get the full deadline again."""
        if self.lost:
            self.lost = False
            self._lost.cancel()

    def _check(self) -> None:
        limit = self.lost_deadline_s if self.lost else self.deadline_s
        if self.since is None or time.perf_counter() - self.since < limit:
            return
        self.since = None
        if not self.lost:
            self.lost = True
            self._lost.reset()
        self.on_miss()


class PeerWatch:
    """What the simulator waits for before the lockstep (docs/governor_contract.md, "Start"): the /graph/ready
    announcement of every peer of ``graph.peers``; a governor that does not announce itself
    (today's contract) counts as ready once a node that has no /graph/ready publisher publishes
    /tsg/time_shift and reads a state topic (its readers and publishers then being matched by the
    checks of the simulator's own endpoints and the announcements of the controller and the
    recorder, whose /tsg/time_shift subscriptions must be matched to it)."""

    def __init__(self, readiness: Readiness, peers: Iterable[str]) -> None:
        from diagnostic_msgs.msg import DiagnosticStatus

        self.node, self.readiness = readiness.node, readiness
        self.peers = [p for p in peers if p != "sim"]
        self.announced: dict[str, str] = {}
        self.sub = self.node.create_subscription(DiagnosticStatus, READY, self.on_ready, QOS_READY_READER)

    def on_ready(self, msg: Any) -> None:
        if msg.message == "ready" and msg.name not in self.announced:
            self.announced[msg.name] = msg.hardware_id
            wall = {kv.key: kv.value for kv in msg.values}.get("wall_ns", "")
            lag = f", {(time.time_ns() - int(wall)) / 1e9:.3f} s after it was said" if wall.isdigit() else ""
            self.node.get_logger().info(f"{msg.name} ready ({msg.hardware_id}{lag})")
            self.readiness.poke()

    def silent_governor(self) -> str | None:
        """The node name of a governor that keeps today's contract without announcing itself and is
        ready by the graph (see the class docstring), or None."""
        def key(i: Any) -> str:
            return f"{i.node_namespace.rstrip('/')}/{i.node_name}"

        announcing = {key(i) for i in self.node.get_publishers_info_by_topic(READY)}
        readers = {key(i) for t in (DEPUTY_ODOM, CHIEF_ODOM) for i in self.node.get_subscriptions_info_by_topic(t)}
        for info in self.node.get_publishers_info_by_topic(TIME_SHIFT):
            if key(info) not in announcing and key(info) in readers:
                return key(info)
        return None

    def missing(self) -> list[str]:
        out = []
        for peer in self.peers:
            if peer in self.announced:
                continue
            if peer == "governor":
                name = self.silent_governor()
                if name is not None:
                    if name not in getattr(self, "_inferred", set()):
                        self._inferred = {name}
                        self.node.get_logger().info(f"governor {name} does not announce itself: ready by "
                                                    "its matched /tsg/time_shift publisher and state subscription")
                    continue
                out.append("governor: no announcement on /graph/ready, and no other node both publishes "
                           "/tsg/time_shift and reads /deputy/odom or /chief/odom")
            else:
                out.append(f"{peer}: no announcement on /graph/ready")
        if out:
            out.append(f"(/graph/ready: {self.sub.get_publisher_count()} writers matched)")
        return out


def _rcl_message(exc: BaseException) -> str:
    """rcl's error text without its source locations (``..., at /path/file.c:123``)."""
    return str(exc).split(", at /")[0]




def wait_acknowledged(node: Any, budget_s: float = ACK_BUDGET_S) -> list[str]:
    """Wait until every reader matched to each of ``node``'s publishers has acknowledged all it
    was sent, at most ``budget_s`` in all; return (and log) the topics not acknowledged in time
    (should a live reader be one of them, the launcher's bag check fails the mission).
    Reliable samples a reader has not acknowledged die with their writer: measured, a loaded
    soak's bag lacked the controller's last commands (155 of 1440) that the controller, stopped
    right after the simulator ended, had sent but the recorder had not yet received. A reader's
    middleware threads acknowledge on reception, however far behind its executor is."""
    from rclpy.duration import Duration

    end = time.monotonic() + budget_s
    late = []
    for pub in list(node.publishers):
        try:
            if not pub.wait_for_all_acked(Duration(seconds=max(0.0, end - time.monotonic()))):
                late.append(pub.topic_name)
        except Exception:   # the context is gone (shut down from outside): nothing more to wait for
            break
    if late:
        node.get_logger().warning(f"not every reader acknowledged the last messages on {', '.join(late)} "
                                  f"within {budget_s:g} s")
    return late


def run_node(factory: Callable[[Any], Any], args: list[str] | None = None,
             signal_handlers: bool = True, spec: Any = None, exit_process: bool = True) -> int:
    """Run one node in this process: init, executor, spin, and the Jazzy shutdown pattern
    (:func:`run_nodes` with one node).

    ``args``: the command line with the program name first (default ``sys.argv``). With a
    :class:`~cikan_ros.ros.params.NodeSpec`, ``--help`` prints the node's usage and parameters
    and returns 0 without starting rclpy. ``factory(context)`` builds the node.
    """
    argv = list(sys.argv if args is None else args)
    if spec is not None:
        try:
            if not parse_node_args(spec, argv[1:]):
                return 0
        except ConfigError as exc:
            print(f"{spec.name}: error: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
    name = spec.name if spec is not None else Path(argv[0] if argv else "node").name
    return run_nodes([factory], argv, signal_handlers, name, exit_process)


def run_nodes(factories: list[Callable[[Any], Any]], argv: list[str], signal_handlers: bool = True,
              name: str = "node", exit_process: bool = True, process: str | None = None,
              help_hint: str | None = None) -> int:
    """Run the nodes ``factories`` build in this process, on one executor, with the Jazzy
    shutdown pattern; ``argv``: the command line, the program name first (its ``--ros-args``
    part is rclpy's; every node reads the same parameters).

    Each node's ``open()``, if it has one, runs once the parameters are checked (an override
    none of the nodes declares is bad input). The mission lasts until every node with a ``done``
    future of its own has completed it (the simulator; a node without one, as the governor,
    runs until told to stop), or until SIGINT or SIGTERM (``signal_handlers``; else the node
    installs its own, as a recorder alone in its process does to drain). Then a node that drains
    (one with ``request_stop``: the recorder) is asked to, and spun until its ``done``: it keeps
    what the others sent until the stream ends. Then each node waits for its readers'
    acknowledgements (:func:`wait_acknowledged`), calls its ``close()`` if it has one, and is
    destroyed; with ``signal_handlers``, should that take more than
    :data:`~cikan_ros.ros.graph_spec.STOP_WATCHDOG_S`, the stack of every thread goes to stderr
    and the process exits with code 1 (a draining recorder is not hurried: the watchdog starts
    once it has drained). Returns the exit code: the first node's non-zero ``exit_code`` (0
    unless one gave up), :data:`EXIT_BAD_INPUT` for bad input (unknown parameter, bad value,
    unreadable params file or model) with one line on stderr, which starts with ``name`` and
    names ``help_hint`` (default ``name --help``) for the parameters. ``process``: the name the
    process's spin CPU is filed under (:class:`~cikan_ros.ros.profile.NodeProfile`; default ``name``).
    """
    import rclpy
    from rclpy.exceptions import ParameterException
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    def bad_input(text: str) -> int:
        print(f"{name}: error: {text}", file=sys.stderr)
        return EXIT_BAD_INPUT

    try:
        # rclpy's own handlers would shut the context down at once, and a publisher of a shut-down
        # context can no longer wait for its readers: SIGINT/SIGTERM end the spin instead.
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as exc:  # rclpy's RCLError / UnknownROSArgsError: a malformed --ros-args part
        return bad_input(_rcl_message(exc))
    stopping: list[int] = []
    drainers: list[Any] = []
    watching: list[bool] = []

    def watch_the_stop() -> None:
        # graph_spec.STOP_WATCHDOG_S read now, so a test can shorten it in its own process
        if signal_handlers and not watching:
            watching.append(True)
            faulthandler.dump_traceback_later(graph_spec.STOP_WATCHDOG_S, exit=True)

    def on_signal(signum: int, frame: Any) -> None:
        if not stopping and not drainers:
            watch_the_stop()
        stopping.append(signum)
        for d in drainers:
            d.request_stop(signum, frame)

    def install_handlers() -> None:
        if signal_handlers:
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, on_signal)

    install_handlers()
    nodes: list[Any] = []
    executor = None
    code = 0
    try:
        for factory in factories:
            nodes.append(factory(None))
        # rclpy keeps the overrides a node received and the parameters it declared only privately.
        declared = {k for n in nodes for k in n._parameters}
        overrides = {k for n in nodes for k in n._parameter_overrides}
        problems = unknown_overrides(declared, overrides, command_line_names(ros_section(argv[1:])[1]))
        if problems:
            raise ConfigError(f"unknown parameter{'s' if len(problems) > 1 else ''} {', '.join(problems)}"
                              f" (the parameters of {name}: {help_hint or name + ' --help'})")
        for node in nodes:
            if getattr(node, "open", None) is not None:
                node.open()  # what a node creates only once its parameters are known to be right
        drainers[:] = [n for n in nodes if getattr(n, "request_stop", None) is not None]
        install_handlers()   # again: a recorder's open() installed its own, which a container's replaces
        executor = make_executor()
        for node in nodes:
            executor.add_node(node)
        # What the node loaded and built (modules, compiled kernels, messages, models) lives for the
        # whole process: out of the collector's sight, a step's allocations are all a collection scans.
        gc.collect()
        gc.freeze()
        ends = [n.done for n in nodes if n not in drainers and getattr(n, "done", None) is not None]
        forever = Future()   # what a process whose nodes never end by themselves spins on

        def signalled() -> bool:
            return bool(stopping) or any(d.stopping for d in drainers)

        # In 0.5-s slices: the EventsExecutor (rclpy 7.1.6 wheels) fires timers only inside a spin
        # with a timeout, and a signal's handler runs between them.
        with NodeProfile(process or name):  # cikan profile: CIKAN_PROFILE_DIR set (cikan_ros.ros.profile)
            while rclpy.ok() and not signalled():
                pending = [f for f in ends if not f.done()]
                if ends and not pending:
                    break
                executor.spin_until_future_complete(pending[0] if pending else forever, timeout_sec=0.5)
            for d in drainers:
                if not d.stopping:
                    d.request_stop(0, None)   # the mission ended: drain what the others sent
                while rclpy.ok() and not d.done.done():
                    executor.spin_until_future_complete(d.done, timeout_sec=0.5)
        code = next((c for c in (int(getattr(n, "exit_code", 0)) for n in nodes) if c), 0)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (CikanError, ParameterException) as exc:
        code = bad_input(str(exc))
    finally:
        watch_the_stop()   # the mission ended (and any recorder drained): the process ends from here
        for node in nodes:
            if rclpy.ok():
                wait_acknowledged(node)
        for node in nodes:
            close = getattr(node, "close", None)
            if close is not None:
                close()
            node.destroy_node()
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        context = rclpy.get_default_context()
        rclpy.try_shutdown()
        # The participant goes now, telling the others (their writers stop waiting on this
        # process's readers at once), not at the lease's end: end_process skips the destructors.
        context.destroy()
    faulthandler.cancel_dump_traceback_later()
    if exit_process:   # the node executables: the process ends here (see end_process)
        end_process(code)
    return code


def end_process(code: int) -> None:
    """End this process now with ``code``, after the atexit handlers and flushing stdio, without
    the interpreter's teardown: with numba and Fast DDS loaded that takes 0.3-1.7 s (measured),
    and a node must end promptly when its launcher stops it or dies. Everything that matters
    (bag closed, node destroyed, rclpy shut down) is done before."""
    import atexit

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)
