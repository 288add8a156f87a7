"""The readiness handshake (docs/governor_contract.md, "Start") and the lockstep's determinism under CPU load: a
governor that reads only /deputy/odom flies; a naive governor of today's contract (no announcement,
answers as soon as it hears a state) and a built-in governor each give identical recordings
(wall-clock fields aside) when flown twice with every core busy; a deadline that fires fails the run.
Judged by stamps and message contents only."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

from cikan_ros.config import load_config
from cikan_ros.errors import MissionError
from cikan_ros.ros.launch import lockstep_verdict, recorded_steps, run_ros_mission
from cikan_ros.ros.bag_reader import read_bag
from cikan_ros.ros.convert import diagnostic_values
from ros_helpers import ros_env, rosbags_messages, shifts

__all__ = ["ros_env"]
HERE = Path(__file__).resolve().parent
NAIVE = HERE / "naive_governor.py"
DURATION_S = 600.0   # 60 control steps, 10 decisions: short missions
#: Values of the /diagnostics records that measure wall-clock time (they differ run to run).
WALL_KEYS = {"latency_ms", "wall_s", "cpu_s", "rtf", "step_ms_p50", "step_ms_p99", "step_ms_max", "update_step_ms_max",
             "step_ms_max_k", "update_step_ms_max_k"}


@pytest.fixture
def busy_cores() -> Iterator[None]:
    """A busy-loop process on each core for the duration of the test, stopped after."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(os.cpu_count() or 2)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def plain(value: Any) -> Any:
    """A decoded message as nested tuples (for equality), numpy arrays as lists, NaN as "nan"
    (the telemetry's values that are not evaluated: NaN equals nothing, itself included)."""
    if dataclasses.is_dataclass(value):
        return tuple((f.name, plain(getattr(value, f.name))) for f in dataclasses.fields(value)
                     if f.name != "__msgtype__")
    if isinstance(value, np.ndarray):
        return tuple(plain(v) for v in value.tolist())
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    if isinstance(value, (list, tuple)):
        return tuple(plain(v) for v in value)
    return value


def payloads(bag: Path) -> dict[str, list]:
    """{topic: sorted payloads}: every message of the bag (log time = its stamp), wall-clock values
    of /diagnostics removed. Sorted, since arrival order across nodes is not part of the contract."""
    out: dict[str, list] = {}
    for topic, msgs in rosbags_messages(bag).items():
        if topic == "/diagnostics":
            items = [(t, s.name, s.level, s.message, tuple(sorted((kv.key, kv.value) for kv in s.values
                                                                  if kv.key not in WALL_KEYS)))
                     for t, arr in msgs for s in arr.status]
        else:
            items = [(t, plain(m)) for t, m in msgs]
        out[topic] = sorted(items, key=repr)
    return out


def fly(bag: Path, **kw: Any) -> dict:
    cfg = load_config(**{"mission.duration_s": DURATION_S})
    return run_ros_mission(cfg, bag=bag, **kw)


def test_deputy_only_governor_flies_to_the_end_with_its_violations_reported(ros_env: int, tmp_path: Path) -> None:
    """`cikan mission --governor-exec` with a governor that reads only /deputy/odom (no /chief/odom
    subscription, no announcement, no wait): the mission runs to T_sim and reports tau = 0's cost."""
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    out = subprocess.run([str(Path(sys.executable).parent / "cikan"), "mission", "--json", "--bag",
                          str(tmp_path / "bag"), "--set", f"mission.duration_s={DURATION_S}",
                          "--governor-exec", f"{sys.executable} {NAIVE} zero"],
                         capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 1, out.stderr                 # an unsuccessful mission, not bad input
    m = json.loads(out.stdout)
    assert m["violations"] > 0 and m["unverified_shifts"] > 0
    assert m["missing_shifts"] == 0 and m["lockstep_deadlines"] == 0 and m["ros"]["steps"] == 60
    by_stamp = shifts(rosbags_messages(tmp_path / "bag"))
    assert len(by_stamp) == 60 and set(by_stamp.values()) == {0.0}


@pytest.mark.parametrize("how", ["naive-exec", "conventional"])
def test_two_runs_under_load_record_identical_messages(how: str, busy_cores: None, ros_env: int,
                                                       tmp_path: Path) -> None:
    """Flown twice with every core busy: the same messages (stamps and contents; wall-clock values
    of /diagnostics aside), every step answered in the lockstep (no deadline fired)."""
    kw = {"governor_exec": f"{sys.executable} {NAIVE} pistar"} if how == "naive-exec" else {}
    runs = []
    for i in range(2):
        metrics = fly(tmp_path / f"bag{i}", **kw)
        assert metrics["lockstep_deadlines"] == 0 and metrics["missing_shifts"] == 0, metrics
        assert metrics["ros"]["steps"] == 60 and metrics["ros"]["rejected"] == 0
        runs.append(payloads(tmp_path / f"bag{i}"))
    a, b = runs
    assert sorted(a) == sorted(b)
    assert len(a["/tsg/time_shift"]) == 60 and len(a["/deputy/odom"]) == 61
    for topic in a:
        assert a[topic] == b[topic], topic


def test_a_deadline_that_fires_fails_the_run() -> None:
    metrics = lockstep_verdict({"success": True, "ros": {"deadline_misses": 0, "controller_holds": 2}})
    assert metrics["lockstep_deadlines"] == 2 and metrics["success"] is False
    metrics = lockstep_verdict({"success": True, "ros": {"deadline_misses": 0}})
    assert metrics["lockstep_deadlines"] == 0 and metrics["success"] is True


def copy_bag(src: Path, dst: Path, keep: Any) -> None:
    """A copy of a recorded bag with only the messages ``keep(topic, log_time)`` accepts (raw
    CDR, the same schemas and QoS): a recorder that stopped early or dropped a message."""
    import yaml
    from mcap.reader import make_reader

    from cikan_ros.ros.bag_writer import BagWriter

    writer = BagWriter(dst)
    with open(next(src.glob("*.mcap")), "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            if keep(channel.topic, message.log_time):
                writer.add_topic(channel.topic, schema.name,
                                 yaml.safe_load(channel.metadata["offered_qos_profiles"]) or [])
                writer.write(channel.topic, message.data, message.log_time)
    writer.close()


def test_soak_and_mission_check_every_bag(ros_env: int, tmp_path: Path) -> None:
    """`cikan soak`: one short mission flown and its bag checked against the mission; a bag with a
    step missing is found out. `cikan mission` checks the bag against the steps the simulator
    flew before reporting any metric: a recorder that stopped early (the last steps and the
    mission-complete record missing) or lost one message fails the mission with one line (exit
    code 1) naming what."""
    from cikan_ros.commands.soak import check_bag

    out = subprocess.run([str(Path(sys.executable).parent / "cikan"), "soak", "--runs", "1", "--json",
                          "--out", str(tmp_path / "soak"), "--set", "mission.duration_s=300"],
                         capture_output=True, text=True, env={**os.environ, "TMPDIR": str(tmp_path)}, timeout=600)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["failed"] == 0 and result["lost"] == 0 and result["runs"] == 1
    (row,) = result["table"]
    assert row["steps"] == 30 and row["lost"] == row["duplicated"] == row["off_grid"] == 0
    # the step latencies the simulator reports: p99 of the holding steps, worst of all steps
    assert 0 < row["step_ms_p99"] <= row["worst_step_ms"] == result["worst_step_ms"]
    # ... and which step it was: the simulator's own record of that step carries that latency,
    # the longest of the mission's step records
    latencies = {int(v["k"]): float(v["latency_ms"]) for v in
                 (diagnostic_values(st) for _, arr in read_bag(tmp_path / "soak" / "run_000")["/diagnostics"]
                  for st in arr.status if st.name == "sim_node")
                 if v.get("event") == "step" and "latency_ms" in v}
    assert len(latencies) == 30 and result["worst_step_run"] == 1 and result["worst_step_k"] == row["worst_step_k"]
    assert latencies[row["worst_step_k"]] == pytest.approx(row["worst_step_ms"], rel=1e-12)
    assert row["worst_step_ms"] == pytest.approx(max(latencies.values()), rel=1e-12)
    cfg = load_config(**{"mission.duration_s": 310.0})   # a mission one step longer than the bag
    # one per topic: the 5 state topics, the telemetry and the scene markers, the shift, the command,
    # the applied thrust, the sim step record
    assert check_bag(tmp_path / "soak" / "run_000", cfg)["lost"] == 11
    # What `cikan mission` does with the same bag: it flew K = 30 steps, all recorded.
    bag = tmp_path / "soak" / "run_000"
    msgs = read_bag(bag)
    cfg = load_config(**{"mission.duration_s": 300.0})
    assert recorded_steps(bag, msgs, cfg) == 30
    last = max(t for t, _ in msgs["/clock"])
    copy_bag(bag, tmp_path / "short", lambda topic, t: t < last - 5 * 10**10)   # the last 5 steps gone
    with pytest.raises(MissionError, match=r"^the bag .*short lacks the simulator's mission-complete "
                                           r"record: the recorder stopped before the mission's end") as e:
        recorded_steps(tmp_path / "short", read_bag(tmp_path / "short"), cfg)
    assert e.value.exit_code == 1
    hole = last - 20 * 10**10
    copy_bag(bag, tmp_path / "hole", lambda topic, t: not (topic == "/truth/deputy/odom" and t == hole))
    with pytest.raises(MissionError, match=r"^the bag .*hole does not hold the mission's 30 steps: 1 lost "
                                           r"\(/truth/deputy/odom 1 \(k 10\)\) \(bag kept; no metrics reported\)$"):
        recorded_steps(tmp_path / "hole", read_bag(tmp_path / "hole"), cfg)
