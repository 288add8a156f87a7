"""User paths through the running graph that the other ROS tests do not take: switching the
governor while flying, a governor that raises, a governor that misses its deadline and comes
back, the recorder's topic selection, and the GEO scenario as a graph.

Real processes, real DDS, an isolated domain per test. Judged by stamps and message contents
(never by wall-clock counts), so the verdicts hold on a loaded machine."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from cikan_ros.config import load_config
from cikan_ros.governor import (PATH_AUDIT, PATH_BISECT, PATH_INITIAL, PATH_KEEP, PATH_NN, PATH_NN_BISECT,
                                PATH_PROBE, PATH_SEARCH, PATH_STALL, PATH_VERIFY_ZERO, PATH_ZERO, warm_up)
from cikan_ros.mission import ClosedLoop, nominal_start, run_mission
from cikan_ros.registry import make_governor
from cikan_ros.ros.convert import Timeline
from cikan_ros.ros.graph_spec import NODES, PATH_HOLD
from cikan_ros.ros.launch import Graph, exec_environment, ros_environment, run_ros_mission, write_params
from cikan_ros.tsg import Predictor
from ros_helpers import (at_step, controller_record, diagnostics, independent_check, mcap_counts, ros_env,
                         rosbags_messages, set_in_flight, shifts, stamp_ns, states, watcher)

__all__ = ["ros_env"]
HERE = Path(__file__).resolve().parent
PEERS = [n.name for n in NODES]   # start order: the recorder first, the simulator last
#: Decision paths only the conventional TSG takes, and those only a learned governor takes.
CONVENTIONAL_PATHS = {PATH_INITIAL, PATH_BISECT, PATH_VERIFY_ZERO, PATH_ZERO}
LEARNED_ONLY_PATHS = {PATH_NN, PATH_NN_BISECT, PATH_KEEP, PATH_PROBE, PATH_SEARCH, PATH_AUDIT, PATH_STALL}


def sources(msgs: dict) -> dict[int, str]:
    """{stamp ns: source (the decision path, or 'hold')} of /tsg/time_shift."""
    return {stamp_ns(m): m.source for _, m in msgs["/tsg/time_shift"]}


def bag_governor(bag: Path) -> str:
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return meta["custom_data"]["cikan_ros.governor"]


def test_governor_switched_while_flying(ros_env: int, tmp_path: Path) -> None:
    """`ros2 param set /governor_node governor.name cikan` mid-mission: the switch is accepted,
    announced (the bag names both governors, in order), and from the next decision on every
    update is the learned governor's: its decision paths, its names in the decision records, and
    the shifts the library's cikan governor gives on the recorded states; one shift per step,
    each verified (moving only toward 0), the plant safe."""
    cfg = load_config(**{"mission.duration_s": 600.0})
    node = watcher(ros_env)
    results: list[Any] = []
    hook = set_in_flight(node, "/governor_node/set_parameters", "governor.name", ["cikan"], 5, results)
    # Paced (6 s wall) so that the switch lands mid-mission; the controller waits for the governor
    # while it loads the model (its executor is busy with the switch: torch, the warm-up), so that
    # on a loaded machine no hold races the lockstep to the mission's end meanwhile.
    try:
        metrics = run_ros_mission(cfg, bag=tmp_path / "bag", on_started=hook,
                                  node_params={"sim.max_rtf": 100.0, "controller.tau_deadline_s": 60.0})
    finally:
        node.close()
    assert len(results) == 1 and not isinstance(results[0], Exception) and results[0].successful, results
    assert metrics["ros"]["exit_codes"] == {"recorder": 0, "governor": 0, "controller": 0, "sim": 0}
    assert metrics["lockstep_deadlines"] == 0
    assert bag_governor(tmp_path / "bag") == "conventional -> cikan"
    msgs = rosbags_messages(tmp_path / "bag")
    (switched,) = [s for s, _, _ in diagnostics(msgs, "governor_node", "switched")]
    updates = {s: v for s, v, _ in diagnostics(msgs, "governor_node", "update")}
    tl = Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
    loop = ClosedLoop(Predictor.from_config(cfg))
    before = {s: v for s, v in updates.items() if s <= switched}
    after = {s: v for s, v in updates.items() if s > switched}
    assert before and after, (switched, sorted(updates))
    assert {v["governor"] for v in before.values()} == {"conventional"}
    assert {v["governor"] for v in after.values()} == {"cikan"}
    assert {v["path"] for v in before.values()} <= CONVENTIONAL_PATHS
    assert {v["path"] for v in after.values()} & LEARNED_ONLY_PATHS
    # One shift per step, on the grid; between updates the shift in force holds.
    published, source = shifts(msgs), sources(msgs)
    assert sorted(published) == [tl.stamp_ns(k) for k in range(loop.n_steps)]
    tau = [published[tl.stamp_ns(k)] for k in range(loop.n_steps)]
    assert all(t <= 0.0 for t in tau) and all(b >= a for a, b in zip(tau, tau[1:]))   # toward 0 only
    for k in range(1, loop.n_steps):
        s = tl.stamp_ns(k)
        assert (source[s] == PATH_HOLD) == (not loop.update_due(k)), k
        if source[s] != PATH_HOLD:
            assert updates[s]["path"] == source[s] and float(updates[s]["tau_s"]) == published[s], k
    # The decisions after the switch are the cikan governor's on the states the graph flew
    # (a governor made and warmed up as the node makes one when switching).
    gov = make_governor("cikan", cfg, Predictor.from_config(cfg))
    warm_up(gov, nominal_start(gov.predictor), gov.predictor.orbit.state(0.0))
    stamps, x_d = states(msgs, "/deputy/odom")
    _, x_c = states(msgs, "/chief/odom")
    for k in range(tl.step(switched) + 1, loop.n_steps):
        rec = loop.decide(gov, k, x_d[k], x_c[k], tau[k - 1])
        if rec is not None:
            assert (rec.tau_s, rec.path) == (tau[k], source[tl.stamp_ns(k)]), k
    h1n, h3 = independent_check(x_d, x_c)
    assert h1n <= 1e-9 and h3 <= 1e-9
    assert metrics["violations"] == 0


def test_a_governor_that_raises_is_held_at_its_last_verified_shift(ros_env: int, tmp_path: Path) -> None:
    """governor_node whose governor raises on every update from t = 300 s on: up to then the
    shifts of the conventional TSG flown offline; from the first failed update on, every step's
    /tsg/time_shift holds the last verified shift (the offline run's at step 29) with path 'hold',
    each failure reported; the node survives and the mission runs to its end."""
    cfg = load_config(**{"mission.duration_s": 600.0})
    script = HERE / "raising_governor.py"
    metrics = run_ros_mission(cfg, bag=tmp_path / "bag", governor_exec=f"{sys.executable} {script} 300")
    assert metrics["ros"]["exit_codes"] == {"recorder": 0, "governor": 0, "controller": 0, "sim": 0}
    offline = run_mission(make_governor("conventional", cfg, Predictor.from_config(cfg)),
                          nominal_start(Predictor.from_config(cfg)))
    msgs = rosbags_messages(tmp_path / "bag")
    tl = Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
    published, source = shifts(msgs), sources(msgs)
    n = len(offline.t) - 1
    assert sorted(published) == [tl.stamp_ns(k) for k in range(n)]
    for k in range(30):
        assert published[tl.stamp_ns(k)] == offline.tau[k], k
    for k in range(30, n):
        assert (published[tl.stamp_ns(k)], source[tl.stamp_ns(k)]) == (offline.tau[29], PATH_HOLD), k
    failed = diagnostics(msgs, "governor_node", "failed")
    assert [tl.step(s) for s, _, _ in failed] == list(range(30, n, 6))   # each update from t = 300 s
    assert all("failing as planned" in st.message and "holding the last verified shift" in st.message
               for _, _, st in failed)
    assert offline.tau[29] < 0.0 and metrics["violations"] == 0


def test_a_governor_that_misses_its_deadline_is_taken_back(ros_env: int, tmp_path: Path) -> None:
    """One process per node (so that the governor stops alone): governor_node stopped (SIGSTOP)
    for 2.5 s from about step 5, then continued: the
    controller holds the last verified shift for the steps it missed (each hold's shift is the
    one in force before), rejects the shifts that come late for those steps as stale, and takes
    the governor's shifts again once they come in time: the mission ends on the governor's shifts.
    Every step is commanded once, with the FTRE law toward the shift it names; the run counts its
    fired deadlines and is not a success."""
    cfg = load_config(**{"mission.duration_s": 800.0})
    node = watcher(ros_env)
    stopped: list[float] = []

    def stop_for_a_while(graph: Graph) -> None:
        governor = graph.procs["governor"]
        governor.send_signal(signal.SIGSTOP)
        try:
            time.sleep(2.5)
            stopped.append(2.5)
        finally:
            governor.send_signal(signal.SIGCONT)
    try:   # paced (8 s wall): the lost mode's short waits do not race to the mission's end
        metrics = run_ros_mission(cfg, bag=tmp_path / "bag", on_started=at_step(node, 5, stop_for_a_while),
                                  node_params={"controller.tau_deadline_s": 1.0, "sim.max_rtf": 100.0},
                                  layout="separate")
    finally:
        node.close()
    assert stopped and metrics["ros"]["exit_codes"] == {"recorder": 0, "governor": 0, "controller": 0, "sim": 0}
    msgs = rosbags_messages(tmp_path / "bag")
    loop = ClosedLoop(Predictor.from_config(cfg))
    tl = Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
    published, stale, holds, commands = controller_record(msgs)
    stamps, x_d = states(msgs, "/deputy/odom")
    _, x_c = states(msgs, "/chief/odom")
    assert holds and stale and stale <= set(holds)            # late shifts only for held steps
    first = tl.step(min(commands))    # a first command lost in discovery under load: zero thrust
    assert first < 10 and len(msgs["/deputy/accel_cmd"]) == len(commands) == loop.n_steps - first
    tau_used: list[float] = []
    for k in range(first, loop.n_steps):
        s = tl.stamp_ns(k)
        if s in holds:
            assert k > first and holds[s] == tau_used[-1], k
            tau_used.append(holds[s])
        else:
            assert s in published and s not in stale, k
            tau_used.append(published[s])
        u = loop.command(k, tau_used[-1], x_d[k], x_c[k])    # the FTRE law toward that shift
        np.testing.assert_array_equal(commands[s], u * 1e3)
    last_hold = tl.step(max(holds))
    assert last_hold < loop.n_steps - 1                        # taken back before the end
    assert all(tl.stamp_ns(k) in published for k in range(last_hold + 1, loop.n_steps))
    assert metrics["lockstep_deadlines"] == len(holds) + metrics["ros"]["deadline_misses"]
    assert metrics["success"] is False
    h1n, h3 = independent_check(x_d, x_c)
    assert h1n <= 1e-9 and h3 <= 1e-9


def test_recorder_records_only_the_topics_it_is_given(ros_env: int, tmp_path: Path) -> None:
    """recorder.topics = [/deputy/odom, /tsg/time_shift]: the bag holds those two topics and
    nothing else (read by rosbags and by mcap), one message per state and per step, stamped
    t_0..t_K and t_0..t_{K-1}; its metadata lists only them."""
    cfg = load_config(**{"mission.duration_s": 100.0})
    bag = tmp_path / "bag"
    chosen = ["/deputy/odom", "/tsg/time_shift"]
    params = write_params(tmp_path / "params.yaml", cfg, {
        "graph.peers": PEERS, "recorder.bag": str(bag), "recorder.topics": chosen})
    graph = Graph(tmp_path, ros_environment(ros_env, tmp_path / "log"), params)
    try:
        graph.start(PEERS)
        assert graph.procs["sim"].wait(timeout=300) == 0, graph.tail("sim")
    finally:
        graph.stop_all()
    assert {n: p.returncode for n, p in graph.procs.items()} == {n: 0 for n in PEERS}
    msgs = rosbags_messages(bag)
    assert sorted(msgs) == sorted(chosen) and mcap_counts(bag) == {t: len(m) for t, m in msgs.items()}
    tl = Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
    assert [stamp_ns(m) for _, m in msgs["/deputy/odom"]] == [tl.stamp_ns(k) for k in range(11)]
    assert sorted(shifts(msgs)) == [tl.stamp_ns(k) for k in range(10)]
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert sorted(t["topic_metadata"]["name"] for t in meta["topics_with_message_count"]) == sorted(chosen)


def test_geo_mission_as_a_graph_equals_the_offline_mission(ros_env: int, tmp_path: Path) -> None:
    """`cikan mission --scenario geo` (5 minutes) through the real graph: the bag's true states
    are the offline GEO mission's (to the SI round trip), its shifts the offline ones, the bag
    carries the GEO configuration, and the run reports no violation and no fired deadline."""
    from cikan_ros.config import scenario_overrides

    bag = tmp_path / "bag"
    out = subprocess.run([str(Path(sys.executable).parent / "cikan"), "mission", "--scenario", "geo", "--json",
                          "--set", "mission.duration_s=300", "--bag", str(bag)],
                         capture_output=True, text=True, env={**os.environ, "TMPDIR": str(tmp_path)}, timeout=600)
    assert out.returncode in (0, 1), out.stderr         # 1: not docked after 5 minutes (a failed mission)
    m = json.loads(out.stdout)
    assert m["violations"] == 0 and m["lockstep_deadlines"] == 0 and m["ros"]["steps"] == 30, m
    cfg = load_config(**{**scenario_overrides("geo"), "mission.duration_s": 300.0})
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    flown = json.loads(meta["custom_data"]["cikan_ros.config"])
    assert flown["scenario.name"] == "geo" and flown["orbit.a_km"] == 42164.17
    pred = Predictor.from_config(cfg)
    offline = run_mission(make_governor("conventional", cfg, pred), nominal_start(pred))
    msgs = rosbags_messages(bag)
    stamps, x_d = states(msgs, "/truth/deputy/odom")
    _, x_c = states(msgs, "/truth/chief/odom")
    tl = Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
    assert list(stamps) == [tl.stamp_ns(k) for k in range(31)]
    np.testing.assert_allclose(x_d, offline.x_d, rtol=1e-12, atol=0)
    np.testing.assert_allclose(x_c, offline.x_c, rtol=1e-12, atol=0)
    np.testing.assert_allclose(x_d - x_c, offline.x_d - offline.x_c, rtol=0, atol=1e-9)   # 1 um, 1 um/s
    published = shifts(msgs)
    assert [published[tl.stamp_ns(k)] for k in range(30)] == list(offline.tau[:30])


def test_a_cikan_ros_in_the_working_directory_does_not_fly_in_the_nodes(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """`cikan mission` run where another cikan_ros lies (a checkout of another commit): its
    nodes (`python -m cikan_ros...` in the graph's environment, launch.ros_environment) import
    the package the launcher imported, not the one in the working directory, which without
    PYTHONSAFEPATH would come first on their sys.path. An external governor gets the user's
    own setting back (a script beside its modules imports them)."""
    import cikan_ros

    decoy = tmp_path / "cikan_ros"
    decoy.mkdir()
    (decoy / "__init__.py").write_text("raise ImportError('the cikan_ros of the working directory')\n")
    code = ["-c", "import cikan_ros; print(cikan_ros.__file__)"]
    env = ros_environment(0, tmp_path / "log")
    out = subprocess.run([sys.executable, *code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert Path(out.stdout.strip()) == Path(cikan_ros.__file__)
    bare = {k: v for k, v in env.items() if k != "PYTHONSAFEPATH"}
    out = subprocess.run([sys.executable, *code], cwd=tmp_path, env=bare, capture_output=True, text=True)
    assert "the cikan_ros of the working directory" in out.stderr   # what it guards against
    monkeypatch.delenv("PYTHONSAFEPATH", raising=False)
    assert "PYTHONSAFEPATH" not in exec_environment(ros_environment(0, tmp_path / "log"))
