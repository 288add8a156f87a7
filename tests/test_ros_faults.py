"""Faults of the running graph (real processes, real DDS, an isolated domain per test): a killed
governor, controller or recorder, SIGINT to `cikan mission`, and bad messages."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
import yaml

from cikan_ros.config import load_config
from cikan_ros.errors import CikanError
from cikan_ros.ros.graph import QOS_STREAM
from cikan_ros.ros.launch import Graph, ros_environment, run_ros_mission, write_params
from ros_helpers import (TestNode, independent_check, mcap_counts, ros_env, rosbags_messages, shifts,
                         sim_steps, stamp_ns, states)

__all__ = ["ros_env"]


def wait_until(pred: Callable[[], Any], timeout: float = 60.0, what: str = "condition") -> Any:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = pred()
        if value:
            return value
        time.sleep(0.005)
    raise AssertionError(f"timed out waiting for {what}")



def watcher(domain: int) -> TestNode:
    from nav_msgs.msg import Odometry

    node = TestNode("fault_watcher", domain)
    node.subscribe("/deputy/odom", Odometry, QOS_STREAM)
    return node.start()


def kill_at_step(node: TestNode, name: str, k: int) -> Callable[[Graph], None]:
    """on_started hook: SIGKILL the named node once the watcher has seen k deputy states."""
    def hook(graph: Graph) -> None:
        def run() -> None:
            try:
                wait_until(lambda: len(node.messages("/deputy/odom")) >= k, 120.0, f"step {k}")
            except AssertionError:
                return  # the test's own assertions then show the node was never killed
            graph.procs[name].kill()
        threading.Thread(target=run, daemon=True).start()
    return hook


def test_governor_killed_controller_holds_last_verified_shift(ros_env: int, tmp_path: Path) -> None:
    cfg = load_config(**{"mission.duration_s": 1200.0})
    node = watcher(ros_env)
    try:
        metrics = run_ros_mission(cfg, bag=tmp_path / "bag", on_started=kill_at_step(node, "governor", 20),
                                  node_params={"controller.tau_deadline_s": 2.0, "sim.max_rtf": 200.0})
    finally:
        node.close()
    assert metrics["ros"]["exit_codes"]["governor"] == -signal.SIGKILL
    assert metrics["ros"]["exit_codes"]["sim"] == 0          # the mission completed
    msgs = rosbags_messages(tmp_path / "bag")
    n_steps = 120
    published = shifts(msgs)
    assert 20 <= len(published) < n_steps                     # the governor died mid-mission
    last_tau = published[max(published)]
    assert last_tau < 0.0
    assert len(msgs["/deputy/accel_cmd"]) == n_steps          # the controller kept commanding
    holds = []
    for _, arr in msgs["/diagnostics"]:
        for st in arr.status:
            values = {kv.key: kv.value for kv in st.values}
            if st.name == "controller_node" and values.get("event") == "hold":
                holds.append((stamp_ns(arr), float(values["tau_s"])))
    assert holds and all(tau == last_tau for _, tau in holds)
    assert min(s for s, _ in holds) > max(published)          # holding started after the last shift
    assert len(holds) == n_steps - len(published)
    _, x_d = states(msgs, "/deputy/odom")
    _, x_c = states(msgs, "/chief/odom")
    h1n, h3 = independent_check(x_d, x_c)
    assert h1n <= 1e-9 and h3 <= 1e-9                         # still safe
    assert metrics["violations"] == 0


def test_controller_killed_sim_applies_zero_thrust(ros_env: int, tmp_path: Path) -> None:
    cfg = load_config(**{"mission.duration_s": 600.0})
    node = watcher(ros_env)
    try:
        metrics = run_ros_mission(cfg, bag=tmp_path / "bag", on_started=kill_at_step(node, "controller", 20),
                                  node_params={"sim.command_deadline_s": 2.0, "sim.max_rtf": 200.0})
    finally:
        node.close()
    assert metrics["ros"]["exit_codes"]["controller"] == -signal.SIGKILL
    assert metrics["ros"]["exit_codes"]["sim"] == 0
    msgs = rosbags_messages(tmp_path / "bag")
    n_cmd = len(msgs["/deputy/accel_cmd"])
    assert 19 <= n_cmd < 60
    steps = sim_steps(msgs)
    assert sorted(steps) == list(range(60))
    for k in range(60):
        expected = "command" if k < n_cmd else "zero-deadline"
        assert steps[k]["thrust"] == expected, k
        if expected != "command":
            assert [float(w) for w in steps[k]["u_kmps2"].split()] == [0.0, 0.0, 0.0]
    assert metrics["ros"]["deadline_misses"] == 60 - n_cmd
    warn = [st for _, arr in msgs["/diagnostics"] for st in arr.status
            if st.name == "sim_node" and st.level == 1 and "deadline" in st.message]
    assert len(warn) == 60 - n_cmd


def test_recorder_sigkill_leaves_bag_readable_to_last_chunk(ros_env: int, tmp_path: Path) -> None:
    cfg = load_config(**{"mission.duration_s": 3600.0})
    bag = tmp_path / "bag"
    node = watcher(ros_env)
    try:
        with pytest.raises(CikanError, match="recorder_node ended abnormally"):
            run_ros_mission(cfg, bag=bag, on_started=kill_at_step(node, "recorder", 150),
                            node_params={"recorder.chunk_bytes": 8192, "sim.max_rtf": 400.0})
    finally:
        node.close()
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    msgs = rosbags_messages(bag)
    counts = {t: len(v) for t, v in msgs.items()}
    assert mcap_counts(bag) == counts
    # metadata.yaml is rewritten right after each chunk: it may lag the file by that one chunk.
    for t in meta["topics_with_message_count"]:
        assert t["message_count"] <= counts.get(t["topic_metadata"]["name"], 0)
    assert sum(counts.values()) - meta["message_count"] <= 8192 // 100
    stamps, _ = states(msgs, "/deputy/odom")
    epoch = round(cfg.orbit.epoch_unix_s * 1e9)
    k = (stamps - epoch) // 10**10
    assert 0 < len(k) < 361 and np.array_equal(k, np.arange(len(k)))  # every step up to the chunk


def test_sigint_to_cikan_mission_ends_children_and_closes_bag(ros_env: int, tmp_path: Path) -> None:
    from mcap.reader import make_reader

    bag = tmp_path / "bag"
    cikan = Path(sys.executable).parent / "cikan"
    proc = subprocess.Popen([str(cikan), "mission", "--bag", str(bag), "--json",
                             "--set", "mission.duration_s=43200"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=dict(os.environ))
    try:
        def progress() -> bool:
            try:
                meta = yaml.safe_load((bag / "metadata.yaml").read_text())
            except (OSError, yaml.YAMLError):
                return False
            return meta["rosbag2_bagfile_information"]["message_count"] > 0
        wait_until(progress, 120.0, "recorded messages")
        children = [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit()
                    and _ppid(p) == proc.pid]
        assert len(children) == 4
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert b"interrupted" in err
    for pid in children:
        assert not Path(f"/proc/{pid}").exists() or _zombie(pid), pid
    with open(next(bag.glob("*.mcap")), "rb") as f:
        assert make_reader(f).get_summary() is not None        # closed with its summary
    counts = {t: len(v) for t, v in rosbags_messages(bag).items()}
    assert 0 < counts["/deputy/odom"] < 4321                   # interrupted mid-mission


def _ppid(p: Path) -> int:
    try:
        return int((p / "stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return -1


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


def test_bad_messages_are_rejected_with_diagnostics(ros_env: int, tmp_path: Path) -> None:
    """sim_node and controller_node with the test as governor: non-finite, out-of-range, positive
    and stale inputs are rejected with a diagnostic, and the lockstep goes on."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import AccelStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import TimeReference

    from cikan_ros.ros import convert as cv

    cfg = load_config(**{"mission.duration_s": 100.0})
    params = write_params(tmp_path / "params.yaml", cfg, {
        "graph.peers": ["sim", "controller", "governor"], "sim.command_deadline_s": 60.0,
        "controller.tau_deadline_s": 60.0})
    graph = Graph(tmp_path, ros_environment(ros_env, tmp_path / "log"), params)
    node = TestNode("bad_inputs", ros_env)
    node.subscribe("/deputy/odom", Odometry, QOS_STREAM)   # the test plays the governor
    node.subscribe("/chief/odom", Odometry, QOS_STREAM)
    node.subscribe("/diagnostics", DiagnosticArray, QOS_STREAM)
    node.subscribe("/deputy/accel_cmd", AccelStamped, QOS_STREAM)
    shift = node.node.create_publisher(TimeReference, "/tsg/time_shift", QOS_STREAM)
    accel = node.node.create_publisher(AccelStamped, "/deputy/accel_cmd", QOS_STREAM)
    node.start()
    tl = cv.Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)

    def rejected(name: str, text: str) -> Callable[[], bool]:
        return lambda: any(st.name == name and st.level == b"\x01" and text in st.message  # byte field
                           for arr in node.messages("/diagnostics") for st in arr.status)
    try:
        graph.start(["controller", "sim"])
        wait_until(lambda: node.messages("/deputy/odom"), 60.0, "state of step 0")
        wait_until(lambda: shift.get_subscription_count() >= 1 and accel.get_subscription_count() >= 1,
                   30.0, "matching")
        t0 = tl.stamp_ns(0)
        bad = cv.time_shift_msg(t0, 0.0, "test")
        bad.time_ref = cv.ns_to_time(t0 + 5 * 10**9)        # tau = +5 s
        shift.publish(bad)
        wait_until(rejected("controller_node", "must be <= 0"), 30.0, "positive shift rejected")
        nan = cv.accel_msg([0.0, 0.0, 0.0], t0)
        nan.accel.linear.x = float("nan")
        accel.publish(nan)
        wait_until(rejected("sim_node", "non-finite"), 30.0, "non-finite command rejected")
        accel.publish(cv.accel_msg([1e-3, 0.0, 0.0], t0))  # 1 m/s^2 > u_max
        wait_until(rejected("sim_node", "exceeds the thrust limit"), 30.0, "out-of-range command rejected")
        accel.publish(cv.accel_msg([0.0, 0.0, 0.0], tl.stamp_ns(7)))
        wait_until(rejected("sim_node", "stale command"), 30.0, "off-step command rejected")
        assert len(node.messages("/deputy/odom")) == 1         # nothing advanced the lockstep
        shift.publish(cv.time_shift_msg(t0, -7.5, "test"))     # a valid shift: the controller answers
        wait_until(lambda: len(node.messages("/deputy/odom")) >= 2, 30.0, "step 1")
        assert stamp_ns(node.messages("/deputy/odom")[1]) == tl.stamp_ns(1)
        shift.publish(cv.time_shift_msg(t0, -7.5, "test"))     # late: step 0 is answered
        wait_until(rejected("controller_node", "stale time shift"), 30.0, "stale shift rejected")
        assert all(p.poll() is None for p in graph.procs.values())  # nobody crashed
    finally:
        node.close()
        graph.stop(["sim", "controller"])
    assert all(p.returncode == 0 for p in graph.procs.values())


def test_bad_model_is_refused_at_run_time_and_the_mission_goes_on(ros_env: int, tmp_path: Path) -> None:
    """Switching governor.name to a missing or corrupt model while flying: refused with the reason
    (SetParameters), the running governor stays, the mission completes."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    (corrupt / "card.json").write_text("{not json")
    (corrupt / "model.safetensors").write_bytes(b"\x00" * 64)
    node = watcher(ros_env)
    client = node.node.create_client(SetParameters, "/governor_node/set_parameters")
    results: list[Any] = []

    def hook(graph: Graph) -> None:
        def run() -> None:
            try:
                assert client.wait_for_service(timeout_sec=60.0), "no parameter service"
                wait_until(lambda: len(node.messages("/deputy/odom")) >= 5, 120.0, "step 5")
                for value in (str(tmp_path / "missing"), str(corrupt)):
                    request = SetParameters.Request(parameters=[
                        Parameter("governor.name", value=value).to_parameter_msg()])
                    future = client.call_async(request)
                    wait_until(future.done, 30.0, "parameter service")
                    results.append(future.result().results[0])
            except Exception as exc:  # reported by the test, not lost in the thread
                results.append(exc)
        threading.Thread(target=run, daemon=True).start()
    try:
        # Paced (24 s wall) so the refusals, which import torch in the governor, happen in flight.
        metrics = run_ros_mission(load_config(**{"mission.duration_s": 2400.0}), bag=tmp_path / "bag",
                                  on_started=hook, node_params={"sim.max_rtf": 100.0})
    finally:
        node.close()
    assert len(results) == 2 and not any(isinstance(r, Exception) or r.successful for r in results), results
    assert all(r.reason for r in results), results
    assert metrics["ros"]["exit_codes"] == {"recorder": 0, "governor": 0, "controller": 0, "sim": 0}
    assert metrics["violations"] == 0 and metrics["governor"] == "conventional"
    msgs = rosbags_messages(tmp_path / "bag")
    refused = [st.message for _, arr in msgs["/diagnostics"] for st in arr.status
               if st.name == "governor_node" and "refused" in st.message]
    assert len(refused) == 2
    assert len(shifts(msgs)) == 240                               # the governor answered every step


def test_bad_model_at_launch_is_a_clear_error(ros_env: int, tmp_path: Path) -> None:
    with pytest.raises(CikanError, match="governor_node exited with code 2"):
        run_ros_mission(load_config(**{"mission.duration_s": 100.0}), governor=str(tmp_path / "nope"),
                        bag=tmp_path / "bag")
    meta = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())
    assert meta["rosbag2_bagfile_information"]["message_count"] == 0   # closed, empty bag
