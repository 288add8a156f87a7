"""Faults of the running graph (real processes, real DDS, an isolated domain per test): a killed
governor, controller or recorder, SIGINT or SIGKILL to `cikan mission`, and bad messages.

Judged by stamps and message contents, never by wall-clock counts: what each node did at each
step must follow from what it received for that step, whatever the machine's load."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
import yaml

from cikan_ros.config import load_config
from cikan_ros.errors import CikanError, MissionError
from cikan_ros.ros.graph import QOS_STREAM
from cikan_ros.ros.graph_spec import DEFAULT_LAYOUT, processes
from cikan_ros.ros.launch import Graph, ros_environment, run_ros_mission, write_params
from ros_helpers import (TestNode, commands_by_stamp, controller_record, diagnostics, independent_check,
                         kill_at_step, mcap_counts, ros_env, rosbags_messages, set_in_flight, shifts, sim_steps,
                         stamp_ns, states, wait_until, watcher)

__all__ = ["ros_env"]


def test_governor_killed_controller_holds_last_verified_shift(ros_env: int, tmp_path: Path) -> None:
    """One process per node (the default layout runs the governor with the controller). Judged by
    stamps and contents: every step is commanded once, with the shift published for it or, where
    none came in time, the shift in force before (a hold); after the governor died only holds;
    each command is the FTRE law toward the shift it names; the plant stays safe."""
    from cikan_ros.mission import ClosedLoop
    from cikan_ros.ros.convert import Timeline
    from cikan_ros.tsg import Predictor

    cfg = load_config(**{"mission.duration_s": 1200.0})
    node = watcher(ros_env)
    try:   # paced (12 s wall) so that the kill at step 10 lands mid-mission even on a loaded machine
        metrics = run_ros_mission(cfg, bag=tmp_path / "bag", on_started=kill_at_step(node, "governor", 10),
                                  node_params={"controller.tau_deadline_s": 2.0, "sim.max_rtf": 100.0},
                                  layout="separate")
    finally:
        node.close()
    assert metrics["ros"]["exit_codes"]["governor"] == -signal.SIGKILL
    assert metrics["ros"]["exit_codes"]["sim"] == 0          # the mission completed
    msgs = rosbags_messages(tmp_path / "bag")
    loop = ClosedLoop(Predictor.from_config(cfg))
    tl = Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
    published, stale, holds, commands = controller_record(msgs)
    stamps, x_d = states(msgs, "/deputy/odom")
    steps = sim_steps(msgs)
    # Steps before the controller's first command (a first message lost while the readers of a
    # starting graph complete discovery, seen once under load): no command, zero thrust.
    first = tl.step(min(commands))
    assert all(steps[k]["thrust"] == "zero-deadline" and tl.stamp_ns(k) not in holds for k in range(first))
    assert len(msgs["/deputy/accel_cmd"]) == len(commands) == loop.n_steps - first   # one per step
    last_published = max(published)
    assert first < 10 and last_published < tl.stamp_ns(loop.n_steps - 1)   # it died mid-mission
    tau_used: list[float] = []
    period_ns = tl.stamp_ns(1) - tl.stamp_ns(0)
    lost: int | None = None
    for k in range(first, loop.n_steps):
        s = tl.stamp_ns(k)
        if s in holds:                                         # no shift in time: the last one holds
            # (the killed governor's last shift may reach the recorder and not the controller:
            # SIGKILL ends its reliable delivery midway; seen once in a fresh clone under load)
            assert s not in published or s in stale or s == last_published, k
            assert k > first and holds[s] == tau_used[-1], k
            tau_used.append(holds[s])
        elif s in published:
            assert s not in stale, k
            tau_used.append(published[s])
        else:
            # The other side of that race: the killed governor's last shift reached the controller
            # and not the recorder (seen once in CI). It can only be the shift after the last one
            # recorded, and the next step holds it, so the hold names its value.
            assert lost is None and s == last_published + period_ns and k + 1 < loop.n_steps, k
            assert tl.stamp_ns(k + 1) in holds, k
            lost = s
            tau_used.append(holds[tl.stamp_ns(k + 1)])
        if s > last_published and s != lost:
            assert s in holds, k
        assert stamps[k] == s
        u = loop.command(k, tau_used[-1], x_d[k], loop.predictor.orbit.state(loop.time(k)))  # the FTRE law
        np.testing.assert_array_equal(commands[s], u * 1e3)    # as the controller sent it (m/s^2)
    assert tau_used[-1] < 0.0
    _, x_c = states(msgs, "/chief/odom")
    h1n, h3 = independent_check(x_d, x_c)
    assert h1n <= 1e-9 and h3 <= 1e-9                         # still safe
    assert metrics["violations"] == 0


@pytest.mark.parametrize("layout", ["paired", "separate"])
def test_controller_killed_sim_applies_zero_thrust(ros_env: int, tmp_path: Path, layout: str) -> None:
    """The controller's process killed (in the default layout the flight software's: the governor
    and the controller). Judged by stamps and contents: each step's thrust is the controller's
    command stamped for it, or zero where none came in time (a missed deadline, reported); after
    the controller died only zeros; the plant and its recording fly on."""
    cfg = load_config(**{"mission.duration_s": 1200.0})
    node = watcher(ros_env)
    try:   # paced (12 s wall) so that the kill at step 10 lands mid-mission even on a loaded machine
        metrics = run_ros_mission(cfg, bag=tmp_path / "bag", on_started=kill_at_step(node, "controller", 10),
                                  node_params={"sim.command_deadline_s": 2.0, "sim.max_rtf": 100.0}, layout=layout)
    finally:
        node.close()
    assert metrics["ros"]["exit_codes"]["controller"] == -signal.SIGKILL
    assert metrics["ros"]["exit_codes"]["governor"] == (-signal.SIGKILL if layout == "paired" else 0)
    assert metrics["ros"]["exit_codes"]["recorder"] == 0
    assert metrics["ros"]["exit_codes"]["sim"] == 0
    msgs = rosbags_messages(tmp_path / "bag")
    commands = commands_by_stamp(msgs)
    stale = {int(v["stamp_ns"]) for _, v, st in diagnostics(msgs, "sim_node", "rejected")
             if "stale command" in st.message}
    steps = sim_steps(msgs)
    stamps, _ = states(msgs, "/deputy/odom")
    n_steps = 120
    assert sorted(steps) == list(range(n_steps))
    zeros = [k for k in range(n_steps) if steps[k]["thrust"] == "zero-deadline"]
    assert zeros and zeros[-1] == n_steps - 1                  # the controller died mid-mission
    lost: int | None = None
    for k in range(n_steps):
        u = np.array([float(w) for w in steps[k]["u_kmps2"].split()])
        if k in zeros:
            assert list(u) == [0.0, 0.0, 0.0]
            # none in time (the killed controller's last command may reach the recorder and not
            # the simulator: SIGKILL ends its reliable delivery midway)
            assert int(stamps[k]) not in commands or int(stamps[k]) in stale \
                or int(stamps[k]) == max(commands), k
        elif int(stamps[k]) in commands:
            assert steps[k]["thrust"] == "command"
            np.testing.assert_array_equal(u, commands[int(stamps[k])] / 1e3)   # the command stamped t_k
        else:   # the other side of that race: the last command reached the simulator, not the recorder
            assert steps[k]["thrust"] == "command" and lost is None, k
            assert k > 0 and int(stamps[k]) == max(commands) + int(stamps[k] - stamps[k - 1]), k
            lost = int(stamps[k])
    assert all(k in zeros for k in range(n_steps) if stamps[k] > max(commands) and stamps[k] != lost)
    assert metrics["ros"]["deadline_misses"] == len(zeros)
    warn = [st for _, arr in msgs["/diagnostics"] for st in arr.status
            if st.name == "sim_node" and st.level == 1 and "deadline" in st.message]
    assert len(warn) == len(zeros)


@pytest.mark.parametrize("layout, failure", [("separate", "recorder_node ended abnormally"),
                                             ("paired", r"sim_node \(in recorder\+sim\) exited with code -9")])
def test_recorder_sigkill_leaves_bag_readable_to_last_chunk(ros_env: int, tmp_path: Path, layout: str,
                                                            failure: str) -> None:
    """The recorder's process killed outright (in the default layout the simulator's too): the
    mission fails with one line naming it, and the bag reads back up to its last flushed chunk."""
    cfg = load_config(**{"mission.duration_s": 3600.0})
    bag = tmp_path / "bag"
    node = watcher(ros_env)
    try:
        with pytest.raises(MissionError, match=failure):
            run_ros_mission(cfg, bag=bag, on_started=kill_at_step(node, "recorder", 150),
                            node_params={"recorder.chunk_bytes": 8192, "sim.max_rtf": 400.0}, layout=layout)
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


#: Steps of the missions the tests interrupt: 5 days of sim time, a minute or more of wall time
#: even on an idle machine, so the signal lands mid-mission however slowly the test runs.
LONG_STEPS = 43200


def launch_cikan(bag: Path) -> tuple[subprocess.Popen, list[int]]:
    """`cikan mission` (:data:`LONG_STEPS` steps) as a process, once its bag holds messages:
    (process, the pids of its four node processes)."""
    cikan = Path(sys.executable).parent / "cikan"
    # As from a terminal: SIGINT at its default (rclpy in this test process may have left it
    # ignored, and an ignored SIGINT is inherited: Python would then not raise KeyboardInterrupt).
    proc = subprocess.Popen([str(cikan), "mission", "--bag", str(bag), "--json",
                             "--set", f"mission.duration_s={10 * LONG_STEPS}"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=dict(os.environ),
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))

    def progress() -> bool:
        try:
            meta = yaml.safe_load((bag / "metadata.yaml").read_text())
        except (OSError, yaml.YAMLError):
            return False
        return meta["rosbag2_bagfile_information"]["message_count"] > 0
    try:
        wait_until(progress, 120.0, "recorded messages")
    except BaseException:
        proc.kill()
        proc.communicate()
        raise
    children = [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit() and _ppid(p) == proc.pid]
    return proc, children


def assert_closed_mid_mission(bag: Path) -> None:
    """The bag is closed with its summary (the recorder finished it) and stops mid-mission."""
    from mcap.reader import make_reader

    with open(next(bag.glob("*.mcap")), "rb") as f:
        assert make_reader(f).get_summary() is not None
    counts = {t: len(v) for t, v in rosbags_messages(bag).items()}
    assert 0 < counts["/deputy/odom"] < LONG_STEPS + 1


def test_sigint_to_cikan_mission_ends_children_and_closes_bag(ros_env: int, tmp_path: Path) -> None:
    proc, children = launch_cikan(tmp_path / "bag")
    try:
        assert len(children) == len(processes(DEFAULT_LAYOUT))
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, err
    assert b"interrupted" in err
    for pid in children:
        assert not Path(f"/proc/{pid}").exists() or _zombie(pid), pid
    assert_closed_mid_mission(tmp_path / "bag")


def test_sigkill_to_cikan_mission_ends_children_and_closes_bag(ros_env: int, tmp_path: Path) -> None:
    """The launcher cannot clean up after SIGKILL: the kernel signals its children (parent-death
    signal SIGTERM), which end as on Ctrl-C; the recorder closes the bag."""
    proc, children = launch_cikan(tmp_path / "bag")
    try:
        assert len(children) == len(processes(DEFAULT_LAYOUT))
        proc.kill()
        proc.communicate()
        wait_until(lambda: all(not Path(f"/proc/{pid}").exists() or _zombie(pid) for pid in children),
                   60.0, "the launcher's children to end")
    except BaseException:
        for pid in children:   # the test failed: do not leave the orphans running
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        raise
    assert_closed_mid_mission(tmp_path / "bag")


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
        "graph.peers": ["sim", "controller", "governor"], "sim.command_deadline_s": 3600.0,
        "controller.tau_deadline_s": 3600.0})
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
    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    (corrupt / "card.json").write_text("{not json")
    (corrupt / "model.safetensors").write_bytes(b"\x00" * 64)
    node = watcher(ros_env)
    results: list[Any] = []
    hook = set_in_flight(node, "/governor_node/set_parameters", "governor.name",
                         [str(tmp_path / "missing"), str(corrupt)], 5, results)
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
    refused = [(stamp_ns(arr), st.message) for _, arr in msgs["/diagnostics"] for st in arr.status
               if st.name == "governor_node" and "refused" in st.message]
    assert len(refused) == 2
    final = max(stamp_ns(m) for _, m in msgs["/deputy/odom"])
    assert all(s < final for s, _ in refused)                     # refused while the mission flew
    assert len(shifts(msgs)) == 240                               # the governor answered every step


def test_a_governor_failing_mid_mission_is_one_line_and_the_bag_stays_readable(ros_env: int,
                                                                               tmp_path: Path) -> None:
    """A governor that exits with an error (code 3) after 10 steps: the mission fails with one
    line naming it and its last error; what was recorded is kept, closed and readable."""
    from mcap.reader import make_reader

    script = Path(__file__).resolve().parent / "failing_governor.py"
    with pytest.raises(CikanError, match=r"governor \(exec:.*\) exited with code 3: .*giving up as planned"
                                         r".*bag kept in") as failure:
        run_ros_mission(load_config(**{"mission.duration_s": 1200.0}), bag=tmp_path / "bag",
                        governor_exec=f"{sys.executable} {script} 10")
    assert "\n" not in str(failure.value) and failure.value.exit_code == 1   # a failed mission
    with open(next((tmp_path / "bag").glob("*.mcap")), "rb") as f:
        assert make_reader(f).get_summary() is not None         # closed by the recorder
    msgs = rosbags_messages(tmp_path / "bag")
    assert [stamp_ns(m) for _, m in msgs["/tsg/time_shift"]] == [stamp_ns(m) for _, m in msgs["/deputy/odom"]][:10]


def test_a_governor_failing_at_start_says_where_the_bag_is(ros_env: int, tmp_path: Path) -> None:
    """A --governor-exec that exits at once: the failure line says what became of the bag, and
    says it truly (the recorder may or may not have opened it before it was stopped)."""
    bag = tmp_path / "bag"
    with pytest.raises(CikanError, match=r"governor \(exec:.*\) exited with code 3") as failure:
        run_ros_mission(load_config(**{"mission.duration_s": 100.0}), bag=bag,
                        governor_exec=f'{sys.executable} -c "import sys; sys.exit(3)"')
    text = str(failure.value)
    assert "\n" not in text
    if f"bag kept in {bag}" in text:
        assert (bag / "metadata.yaml").exists()
    else:
        assert ("no bag was written" in text or "removed the empty bag" in text) and not bag.exists()


def test_bad_model_at_launch_is_one_line_and_a_rerun_may_reuse_the_bag(ros_env: int, tmp_path: Path) -> None:
    cfg = load_config(**{"mission.duration_s": 100.0})
    # the default layout runs the governor with the controller: the line names the node and its process
    with pytest.raises(CikanError, match=r"governor_node \(in governor\+controller\) exited with code 2: .*nope") \
            as failure:
        run_ros_mission(cfg, governor=str(tmp_path / "nope"), bag=tmp_path / "bag")
    assert "\n" not in str(failure.value) and "removed the empty bag" in str(failure.value)
    assert failure.value.exit_code == 2                # the node refused its input: bad input
    assert not (tmp_path / "bag").exists()             # nothing was recorded: nothing left behind
    metrics = run_ros_mission(cfg, bag=tmp_path / "bag")   # the same --bag again
    assert metrics["ros"]["steps"] == 10 and len(rosbags_messages(tmp_path / "bag")["/deputy/odom"]) == 11
