"""cikan profile: a lockstep step's CPU per node process and stage (cikan_ros.ros.profile)."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest

from cikan_ros.ros.profile import (CPU_ONLY_ENV, STAGES, NodeProfile, PROFILE_ENV, markdown, node_stages, profile_table,
                                  spin_cpu, stage_of)


@pytest.mark.parametrize("filename, function, stage", [
    ("~", "<built-in method rclpy._rclpy_pybind11.publish>", "publish"),
    (".venv/lib/python3.11/site-packages/rclpy/publisher.py", "publish", "publish"),
    ("~", "<built-in method rclpy._rclpy_pybind11.spin_until_future_complete>", "rclpy"),
    (".venv/lib/python3.11/site-packages/rclpy/executors.py", "_take_subscription", "rclpy"),
    ("/x/cikan_ros/ros/bag_writer.py", "write", "record"),
    (".venv/lib/python3.11/site-packages/mcap/writer.py", "add_message", "record"),
    ("/x/cikan_ros/ros/convert.py", "odom_msg", "messages"),
    (".venv/lib/python3.11/site-packages/nav_msgs/msg/_odometry.py", "__init__", "messages"),
    ("/x/cikan_ros/tsg.py", "optimal_shift", "compute"),
    ("/x/controller_node/node.py", "command", "compute"),
    ("/usr/lib/python3.11/logging/__init__.py", "info", "other"),
])
def test_each_function_belongs_to_one_stage(filename, function, stage):
    assert stage_of(filename, function) == stage


def busy_for(seconds: float) -> float:
    """Work on this thread for ``seconds`` of its CPU clock."""
    t = time.thread_time() + seconds
    x = 0.0
    while time.thread_time() < t:
        x += sum(i * i for i in range(200))
    return x


def test_a_profile_splits_the_main_threads_cpu_by_stage(tmp_path, monkeypatch):
    """A real profile of busy work in this process: its stages sum to what cProfile timed, and
    the table divides by the steps (microseconds per step)."""
    monkeypatch.setenv(PROFILE_ENV, str(tmp_path))
    with NodeProfile("busy_node"):
        busy_for(0.05)
    stages = node_stages(tmp_path / "busy_node.prof")
    assert set(stages) == set(STAGES) and sum(stages.values()) > 0.04
    table = profile_table(tmp_path, steps=10)
    row = table["busy_node"]
    assert row["process"] >= row["main"] > 0.04 / 10 * 1e6 * 0.9
    assert sum(row[s] for s in STAGES) == pytest.approx(sum(stages.values()) / 10 * 1e6)


def test_cpu_only_counts_the_spin_without_a_profile(tmp_path, monkeypatch):
    """With CIKAN_PROFILE_CPU_ONLY a node only counts its CPU: no cProfile file, the seconds of
    the block (all threads, at least the main thread's 0.05 s of work), and profile_table's
    ``flown`` column is that over the steps."""
    monkeypatch.setenv(PROFILE_ENV, str(tmp_path / "cpu"))
    monkeypatch.setenv(CPU_ONLY_ENV, "1")
    with NodeProfile("busy_node"):
        busy_for(0.05)
    assert not list((tmp_path / "cpu").glob("*.prof"))
    flown = spin_cpu(tmp_path / "cpu")
    assert set(flown) == {"busy_node"} and 0.045 < flown["busy_node"] < 1.0
    monkeypatch.delenv(CPU_ONLY_ENV)
    monkeypatch.setenv(PROFILE_ENV, str(tmp_path / "prof"))
    with NodeProfile("busy_node"):
        busy_for(0.05)
    table = profile_table(tmp_path / "prof", steps=10, flown=flown)
    assert table["busy_node"]["flown"] == pytest.approx(flown["busy_node"] / 10 * 1e6)
    page = markdown(table, 10, 1.0, "cikan profile", flown_wall_s=0.5)
    assert "| flown |" in page and "0.50 s of lockstep wall time" in page
    assert "| flown |" not in markdown(profile_table(tmp_path / "prof", steps=10), 10, 1.0, "cikan profile")
    assert "One lockstep mission of 10 steps in process layout `separate`" in markdown(
        table, 10, 1.0, "cikan profile", 0.5, "separate")


def test_no_profile_without_the_environment_variable(tmp_path, monkeypatch):
    monkeypatch.delenv(PROFILE_ENV, raising=False)
    with NodeProfile("quiet_node"):
        sum(range(1000))
    assert not list(tmp_path.iterdir())


def test_cikan_profile_reports_every_node_of_the_graph():
    out = subprocess.run([sys.executable, "-m", "cikan_ros.cli", "profile", "--json",
                          "--set", "mission.duration_s=600"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    assert doc["steps"] == 60
    table = doc["us_per_step"]
    assert set(table) == {"sim_node", "governor_node", "controller_node", "recorder_node"}
    for row in table.values():
        assert row["process"] >= row["main"] > 0
        assert sum(row[s] for s in STAGES) <= row["main"] * 1.05
        assert 0 < row["flown"] < float("inf")  # the same mission flown before without the profiler
    assert table["sim_node"]["publish"] > 0 and table["recorder_node"]["record"] > 0
