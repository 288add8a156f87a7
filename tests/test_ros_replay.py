"""`cikan replay`: a subscriber in another process receives every recorded message, in order,
with /clock (real processes, real DDS, isolated domain)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cikan_ros.config import load_config
from cikan_ros.ros.graph_spec import TOPIC_TYPES, message_class
from cikan_ros.ros.launch import run_ros_mission
from ros_helpers import TestNode, ros_env, rosbags_messages, stamp_ns

__all__ = ["ros_env"]


def _key(topic: str, msg: object) -> tuple:
    """What identifies a message: its stamp and its payload fields (compared decoded, not as bytes)."""
    if topic == "/clock":
        return (msg.clock.sec, msg.clock.nanosec)
    if topic.endswith("odom"):
        p, v = msg.pose.pose.position, msg.twist.twist.linear
        return (stamp_ns(msg), p.x, p.y, p.z, v.x, v.y, v.z)
    if topic in ("/deputy/accel_cmd", "/truth/deputy/accel"):
        a = msg.accel.linear
        return (stamp_ns(msg), a.x, a.y, a.z)
    if topic == "/tsg/time_shift":
        return (stamp_ns(msg), msg.time_ref.sec, msg.time_ref.nanosec, msg.source)
    if topic == "/telemetry":
        return (stamp_ns(msg), tuple(msg.name), tuple(np.nan_to_num(msg.position, nan=-1e300)))
    if topic.startswith("/scene/"):
        return tuple((stamp_ns(m), m.ns, m.id, m.pose.position.x, m.pose.position.y, m.pose.position.z,
                      tuple((p.x, p.y, p.z) for p in m.points)) for m in msg.markers)
    return (stamp_ns(msg), tuple((st.name, st.message, tuple((kv.key, kv.value) for kv in st.values))
                                 for st in msg.status))


@pytest.mark.parametrize("mode", [["--fast"], ["--rate", "400"]])
def test_replay_republishes_every_message_in_order(mode: list[str], ros_env: int, tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    run_ros_mission(load_config(**{"mission.duration_s": 600.0}), bag=bag)
    recorded = rosbags_messages(bag)
    node = TestNode("replay_sink", ros_env)
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
    for topic, type_name in TOPIC_TYPES.items():
        node.subscribe(topic, message_class(type_name), keep_all)
    node.start()
    try:
        cikan = Path(sys.executable).parent / "cikan"
        out = subprocess.run([str(cikan), "replay", str(bag), *mode, "--wait-subscribers", "1", "--json"],
                             capture_output=True, text=True, timeout=120, env=dict(os.environ))
        assert out.returncode == 0, out.stderr
        counts = json.loads(out.stdout)
        import time

        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and any(
                len(node.messages(t)) < len(recorded[t]) for t in recorded):
            time.sleep(0.05)
    finally:
        node.close()
    assert counts == {t: len(v) for t, v in recorded.items()}
    for topic, msgs in recorded.items():
        got = [_key(topic, m) for m in node.messages(topic)]
        assert got == [_key(topic, m) for _, m in msgs], topic      # every message, in order
    assert len(node.messages("/clock")) == len(recorded["/clock"]) > 0


SHIPPED = Path(__file__).resolve().parent.parent / "bags" / "nominal_conventional"
CIKAN = Path(sys.executable).parent / "cikan"


def test_fast_replay_of_the_shipped_bag_reaches_a_keep_all_subscriber_process(ros_env: int) -> None:
    """Every one of the bag's time shifts, in order, at a reliable KEEP_ALL reader of /tsg/time_shift
    in its own process (the issue's case)."""
    recorded = rosbags_messages(SHIPPED)
    expected = [stamp_ns(m) for _, m in recorded["/tsg/time_shift"]]
    assert len(expected) == 1440
    sink = subprocess.Popen([sys.executable, str(Path(__file__).parent / "replay_sink.py"), "1440", "300",
                             "0", "/tsg/time_shift"], stdout=subprocess.PIPE, text=True, env=dict(os.environ))
    try:
        assert sink.stdout.readline().strip() == "ready"
        out = subprocess.run([str(CIKAN), "replay", str(SHIPPED), "--fast", "--wait-subscribers",
                              "/tsg/time_shift=1", "--json"], capture_output=True, text=True, timeout=300,
                             env=dict(os.environ))
        assert out.returncode == 0, out.stderr
        assert "playing without" not in out.stderr                                  # the sink was there
        assert "KEEP_LAST(N) reader" in out.stderr                                  # the note of --fast
        got = json.loads(sink.communicate(timeout=300)[0].strip().splitlines()[-1])
    finally:
        if sink.poll() is None:
            sink.kill()
            sink.wait()
    assert json.loads(out.stdout)["/tsg/time_shift"] == 1440
    assert got["shift_stamps"] == expected                       # all 1440, in the recorded order


@pytest.mark.parametrize("make, problem", [
    (lambda d: d / "missing", "bag not found"),
    (lambda d: (d / "x.mcap").write_bytes(b"not an mcap file at all") and d / "x.mcap", "is not an MCAP file"),
    (lambda d: (d / "empty").mkdir() or d / "empty", "no .mcap file in bag directory"),
])
def test_wrong_path_is_one_line_and_exit_code_2(make, problem: str, tmp_path: Path) -> None:
    out = subprocess.run([str(CIKAN), "replay", str(make(tmp_path)), "--fast"], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1 and problem in out.stderr, out.stderr


def test_waits_say_what_they_wait_for(ros_env: int) -> None:
    out = subprocess.run([str(CIKAN), "replay", str(SHIPPED), "--fast", "--wait-subscribers", "1",
                          "--wait-timeout", "1"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "waiting up to 1 s for subscribers: 1 on " in out.stderr and "1 on /tsg/time_shift" in out.stderr
    assert "playing without all subscribers after 1 s; missing on: " in out.stderr
    assert "/tsg/time_shift (0/1)" in out.stderr
    assert "\r" not in out.stderr                                  # no progress bar when not a TTY
    out = subprocess.run([str(CIKAN), "replay", str(SHIPPED), "--fast", "--discovery", "0.5"],
                         capture_output=True, text=True, timeout=120)
    assert "waiting 0.5 s for DDS to discover running subscribers" in out.stderr


@pytest.mark.parametrize("spec", ["0", "x", "/no/such/topic=1", "/tsg/time_shift=0"])
def test_bad_wait_is_one_line_and_exit_code_2(spec: str) -> None:
    out = subprocess.run([str(CIKAN), "replay", str(SHIPPED), "--wait-subscribers", spec],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1 and "--wait-subscribers" in out.stderr, out.stderr


@pytest.mark.parametrize("quiet", [False, True])
def test_progress_bar_on_a_terminal_unless_quiet(quiet: bool, ros_env: int) -> None:
    import fcntl
    import pty
    import struct
    import termios

    controller, terminal = pty.openpty()
    fcntl.ioctl(terminal, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))   # a 100x24 terminal
    proc = subprocess.Popen([str(CIKAN), "replay", str(SHIPPED), "--fast", "--discovery", "0",
                             *(["--quiet"] if quiet else [])],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=terminal)
    os.close(terminal)
    seen = b""
    while True:
        try:
            chunk = os.read(controller, 4096)
        except OSError:   # the terminal closed: the process has ended
            break
        if not chunk:
            break
        seen += chunk
    os.close(controller)
    assert proc.wait(timeout=120) == 0
    text = seen.decode(errors="replace")
    if quiet:
        assert text.strip() == ""
    else:
        assert "replay: " in text and "8884/8884" in text, text[-500:]
