"""Helpers of the ROS tests: an isolated domain per test, a test-side rclpy node spinning in a
thread, hooks that act on a running graph at a given step (kill a node, set a parameter), and
bag reading with the independent readers (rosbags, mcap)."""

from __future__ import annotations

import contextlib
import os
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import pytest


def _shm_files() -> set[Path]:
    shm = Path("/dev/shm")
    return set(shm.glob("fastrtps_*")) | set(shm.glob("sem.fastrtps_*"))


@contextlib.contextmanager
def isolated_ros(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[int]:
    """An isolated ROS domain (id returned), leased for the test as the launcher leases one
    (:mod:`cikan_ros.ros.domain`: no other test session or graph of the machine is on it; the
    graphs the test launches fly on it): env for this process and launched graphs, a private log
    dir, and removal of the Fast DDS shared-memory files left behind (e.g. by SIGKILL)."""
    from cikan_ros.ros.domain import lease_domain
    from cikan_ros.ros.launch import dds_environment

    monkeypatch.delenv("CIKAN_ROS_DOMAIN_ID", raising=False)
    lease = lease_domain()
    domain = lease.domain
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("CIKAN_ROS_DOMAIN_ID", str(domain))
    for name, value in dds_environment().items():   # as the launcher's graphs: loopback UDP only
        monkeypatch.setenv(name, value)
    monkeypatch.setenv("ROS_LOG_DIR", str(tmp_path / "ros_log"))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))   # launcher work dirs (kept on failure)
    before = _shm_files()
    try:
        yield domain
    finally:
        lease.release()
        for f in _shm_files() - before:
            try:
                f.unlink()
            except OSError:
                pass


@pytest.fixture
def ros_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[int]:
    """:func:`isolated_ros` for one test."""
    with isolated_ros(tmp_path, monkeypatch) as domain:
        yield domain


class TestNode:
    """A node of the test process with its own context and executor spinning in a thread."""

    __test__ = False

    def __init__(self, name: str, domain: int) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.received: dict[str, list[Any]] = defaultdict(list)
        self.lock = threading.Lock()
        self.thread = threading.Thread(target=self._spin, daemon=True)

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def subscribe(self, topic: str, msg_type: type, qos: Any) -> None:
        def cb(msg: Any) -> None:
            with self.lock:
                self.received[topic].append(msg)

        self.node.create_subscription(msg_type, topic, cb, qos)

    def messages(self, topic: str) -> list[Any]:
        with self.lock:
            return list(self.received[topic])

    def start(self) -> "TestNode":
        self.thread.start()
        return self

    def close(self) -> None:
        import rclpy

        self.executor.shutdown(timeout_sec=2)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self.thread.join(timeout=5)


def wait_until(pred: Callable[[], Any], timeout: float = 60.0, what: str = "condition") -> Any:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = pred()
        if value:
            return value
        time.sleep(0.005)
    raise AssertionError(f"timed out waiting for {what}")


def watcher(domain: int) -> TestNode:
    """A started test node that keeps every /deputy/odom it hears (the mission's progress)."""
    from nav_msgs.msg import Odometry

    from cikan_ros.ros.graph import QOS_STREAM

    node = TestNode("fault_watcher", domain)
    node.subscribe("/deputy/odom", Odometry, QOS_STREAM)
    return node.start()


def at_step(node: TestNode, k: int, action: Callable[[Any], None]) -> Callable[[Any], None]:
    """on_started hook of ``run_ros_mission``: ``action(graph)`` in a thread once the watcher has
    seen k deputy states (never, if it does not: the test's own assertions then show it)."""
    def hook(graph: Any) -> None:
        def run() -> None:
            try:
                wait_until(lambda: len(node.messages("/deputy/odom")) >= k, 120.0, f"step {k}")
            except AssertionError:
                return
            action(graph)
        threading.Thread(target=run, daemon=True).start()
    return hook


def kill_at_step(node: TestNode, name: str, k: int) -> Callable[[Any], None]:
    """on_started hook: SIGKILL the named node once the watcher has seen k deputy states."""
    return at_step(node, k, lambda graph: graph.procs[name].kill())


def set_in_flight(node: TestNode, service: str, name: str, values: list[Any], k: int,
                  results: list[Any]) -> Callable[[Any], None]:
    """on_started hook: once the watcher has seen k deputy states, set the parameter ``name`` to
    each of ``values`` in turn through ``service`` (a SetParameters service); each result, or
    the exception that stopped it, is appended to ``results``."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    client = node.node.create_client(SetParameters, service)

    def set_all(_graph: Any) -> None:
        try:
            assert client.wait_for_service(timeout_sec=60.0), f"no service {service}"
            for value in values:
                future = client.call_async(SetParameters.Request(
                    parameters=[Parameter(name, value=value).to_parameter_msg()]))
                wait_until(future.done, 120.0, service)
                results.append(future.result().results[0])
        except Exception as exc:  # reported by the test, not lost in the thread
            results.append(exc)
    return at_step(node, k, set_all)


def rosbags_messages(bag: Path) -> dict[str, list[tuple[int, Any]]]:
    """{topic: [(log_time, decoded msg)]} read by rosbags' AnyReader (with the bag's schemas)."""
    from rosbags.highlevel import AnyReader

    out: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    with AnyReader([Path(bag)]) as reader:
        for conn, t, raw in reader.messages():
            out[conn.topic].append((t, reader.deserialize(raw, conn.msgtype)))
    return out


def mcap_counts(bag: Path) -> dict[str, int]:
    """Messages per topic decoded by mcap's reader with the ROS 2 decoder."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    counts: dict[str, int] = defaultdict(int)
    (path,) = sorted(Path(bag).glob("*.mcap"))
    with open(path, "rb") as f:
        for _s, ch, _m, decoded in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            assert decoded is not None
            counts[ch.topic] += 1
    return dict(counts)


def stamp_ns(msg: Any) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def odom_km(msg: Any) -> np.ndarray:
    p, v = msg.pose.pose.position, msg.twist.twist.linear
    return np.array([p.x, p.y, p.z, v.x, v.y, v.z]) / 1000.0


def states(msgs: dict[str, list[tuple[int, Any]]], topic: str) -> tuple[np.ndarray, np.ndarray]:
    """(stamps ns, states km) of an odometry topic, sorted by stamp."""
    pairs = sorted((stamp_ns(m), odom_km(m)) for _, m in msgs[topic])
    return np.array([s for s, _ in pairs]), np.array([x for _, x in pairs])


def shifts(msgs: dict[str, list[tuple[int, Any]]]) -> dict[int, float]:
    """{stamp ns: tau s} of /tsg/time_shift."""
    out = {}
    for _, m in msgs["/tsg/time_shift"]:
        ref = m.time_ref.sec * 10**9 + m.time_ref.nanosec
        out[stamp_ns(m)] = (ref - stamp_ns(m)) / 1e9
    return out


def sim_steps(msgs: dict[str, list[tuple[int, Any]]]) -> dict[int, dict[str, str]]:
    """{k: values} of the simulator's per-step diagnostics."""
    out = {}
    for _, arr in msgs["/diagnostics"]:
        for st in arr.status:
            v = {kv.key: kv.value for kv in st.values}
            if st.name == "sim_node" and v.get("event") == "step":
                out[int(v["k"])] = v
    return out


def diagnostics(msgs: dict, node: str, event: str) -> list[tuple[int, dict[str, str], Any]]:
    """(stamp, values, status) of a node's /diagnostics records of one event, in bag order."""
    return [(stamp_ns(arr), {kv.key: kv.value for kv in st.values}, st) for _, arr in msgs["/diagnostics"]
            for st in arr.status
            if st.name == node and {kv.key: kv.value for kv in st.values}.get("event") == event]


def commands_by_stamp(msgs: dict) -> dict[int, np.ndarray]:
    """{stamp: first commanded acceleration (m/s^2)} of /deputy/accel_cmd."""
    out: dict[int, np.ndarray] = {}
    for _, m in msgs["/deputy/accel_cmd"]:
        out.setdefault(stamp_ns(m), np.array([m.accel.linear.x, m.accel.linear.y, m.accel.linear.z]))
    return out


def controller_record(msgs: dict) -> tuple[dict[int, float], set[int], dict[int, float], dict[int, np.ndarray]]:
    """What the controller had and did, from a bag: (the published shifts {stamp: tau}, the stamps
    of the shifts it rejected as stale, its holds {stamp: tau held}, its commands {stamp: m/s^2})."""
    stale = {s for s, _, st in diagnostics(msgs, "controller_node", "rejected") if "stale time shift" in st.message}
    holds = {s: float(v["tau_s"]) for s, v, _ in diagnostics(msgs, "controller_node", "hold")}
    return shifts(msgs), stale, holds, commands_by_stamp(msgs)


def independent_check(x_d: np.ndarray, x_c: np.ndarray, alpha_deg: float = 20.0,
                      gamma=(5.0, 20.0, 1e-3), port: float = 1.0) -> tuple[float, float]:
    """Worst normalised h1 and worst h3 (SPEC §4) computed here with numpy, not the library;
    ``port`` +1: the docking port faces -v_c (approach from behind), -1: +v_c (from ahead)."""
    p = x_d[:, :3] - x_c[:, :3]
    v = x_d[:, 3:] - x_c[:, 3:]
    vc = x_c[:, 3:]
    pn = np.linalg.norm(p, axis=1)
    vcn = np.linalg.norm(vc, axis=1)
    ok = pn > 1e-3
    h1n = (port * np.sum(vc * p, axis=1)[ok] + np.cos(np.radians(alpha_deg)) * vcn[ok] * pn[ok]) / (vcn[ok] * pn[ok])
    near = pn <= gamma[0]
    h3 = np.linalg.norm(v, axis=1)[near] - gamma[1] * pn[near] - gamma[2]
    return float(h1n.max()) if h1n.size else -np.inf, float(h3.max()) if h3.size else -np.inf


def tau_history(msgs: dict, n: int, stamps: np.ndarray) -> np.ndarray:
    """tau in force at each recorded step (held forward where none was published)."""
    by_stamp = shifts(msgs)
    out = np.empty(n)
    for k in range(n):
        out[k] = by_stamp.get(int(stamps[k]), out[k - 1] if k else np.nan)
    return out
