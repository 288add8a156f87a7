"""`cikan replay`: a subscriber in another process receives every recorded message, in order,
with /clock (real processes, real DDS, isolated domain)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cikan_ros.config import load_config
from cikan_ros.ros.graph import TOPIC_TYPES, message_class
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
    if topic == "/deputy/accel_cmd":
        a = msg.accel.linear
        return (stamp_ns(msg), a.x, a.y, a.z)
    if topic == "/tsg/time_shift":
        return (stamp_ns(msg), msg.time_ref.sec, msg.time_ref.nanosec, msg.source)
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
