"""The node executables as a user starts them: --help without starting rclpy, bad input rejected
with one line and exit code 2, a lone node saying what it waits for and giving up (exit 1).
Real processes, the console scripts of the venv."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cikan_ros.config import load_config
from ros_helpers import ros_env

__all__ = ["ros_env"]
BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parent.parent
#: Node executable -> the groups of config/nodes.yaml it declares (docs/ros_graph.md / config/nodes.yaml header).
NODES = {"sim_node": ("sim", "graph"), "governor_node": ("governor", "graph"),
         "controller_node": ("controller", "graph"), "recorder_node": ("recorder", "graph")}


def yaml_comments(path: Path) -> dict[str, str]:
    """{"group.key": comment} read here from config/nodes.yaml (two levels under ros__parameters)."""
    out, group = {}, None
    for line in path.read_text().splitlines():
        m = re.match(r"^    (\w+):\s*$", line)
        if m:
            group = m.group(1)
        m = re.match(r"^      (\w+):.*?#\s*(.*)$", line)
        if m and group:
            out[f"{group}.{m.group(1)}"] = m.group(2).strip()
    return out


def run(args: list[str], timeout: float = 120, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / args[0]), *args[1:]], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, **env}, cwd=ROOT)


def stderr_lines(out: subprocess.CompletedProcess) -> list[str]:
    """stderr without rclpy's own log lines ([INFO] ... from the node's logger)."""
    return [ln for ln in out.stderr.splitlines() if ln.strip() and not ln.startswith("[")]


@pytest.mark.parametrize("node", sorted(NODES))
def test_help_lists_every_parameter_and_does_not_start_rclpy(node: str, ros_env: int,
                                                             tmp_path: Path) -> None:
    # Every rclpy.init writes a log file into ROS_LOG_DIR: --help must leave it untouched.
    logs = tmp_path / "help_logs"
    out = run([node, "--help"], ROS_LOG_DIR=str(logs))
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"usage: {node} ")
    text = " ".join(out.stdout.split())
    doc = yaml.safe_load((ROOT / "config" / "nodes.yaml").read_text())["/**"]["ros__parameters"]
    descriptions = yaml_comments(ROOT / "config" / "nodes.yaml")
    for group in NODES[node]:
        for key in doc[group]:
            name = f"{group}.{key}"
            assert f"{name} = " in text, name
            assert " ".join(descriptions[name].split()) in text, name
    for name in load_config().flat():               # the mission configuration the node declares
        assert f"{name} = " in text, name
    other = {g for n, groups in NODES.items() if n != node for g in groups} - set(NODES[node])
    for group in other:                              # not the parameters of the other nodes
        assert f"\n  {group}." not in out.stdout
    assert not logs.exists()
    # the same probe does see a node that starts (the recorder without a bag stops at once)
    run(["recorder_node"] if node == "recorder_node" else
        [node, "--ros-args", "-p", "graph.startup_timeout_s:=0.1"], ROS_LOG_DIR=str(logs))
    assert any(logs.iterdir())


@pytest.mark.parametrize("args, problem", [
    (["governor_node", "--ros-args", "-p", "governor.nmae:=cikan"], "unknown parameter 'governor.nmae' (did you mean governor.name?)"),
    (["recorder_node", "--ros-args", "-p", "recorder.bag:=BAG", "-p", "sim.seed:=3"], "unknown parameter 'sim.seed'"),
    (["sim_node", "--ros-args", "-p", "sim.seed:=three"], "sim.seed"),
    (["sim_node", "--ros-args", "-p", "orbit.e:=1.5"], "orbit.e"),
    (["controller_node", "--ros-args", "--params-file", "no/such/params.yaml"], "no/such/params.yaml"),
    (["governor_node", "--ros-args", "-p", "governor.name:=no_such_model"], "no_such_model"),
    (["sim_node", "--verbose"], "unrecognised arguments --verbose"),
    (["sim_node", "--ros-args", "-p", "sim.command_deadline_s:=0.0"],
     "sim.command_deadline_s must be a positive number of seconds, got 0.0"),
    (["controller_node", "--ros-args", "-p", "controller.lost_deadline_s:=-1.0"],
     "controller.lost_deadline_s must be a positive number of seconds, got -1.0"),
])
def test_bad_input_is_one_line_and_exit_code_2(args: list[str], problem: str, ros_env: int,
                                               tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    out = run([a.replace("BAG", str(bag)) for a in args])
    assert out.returncode == 2, out.stderr
    lines = stderr_lines(out)
    assert len(lines) == 1 and lines[0].startswith(f"{args[0]}: error: ") and problem in lines[0], out.stderr
    assert not bag.exists()                          # a rejected recorder leaves no bag behind


def test_unknown_parameter_in_a_params_file_is_rejected_other_nodes_groups_are_not(
        ros_env: int, tmp_path: Path) -> None:
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {
        "governor": {"nmae": "cikan"}, "sim": {"seed": 3}}}}))
    out = run(["governor_node", "--ros-args", "--params-file", str(params)])
    assert out.returncode == 2
    assert stderr_lines(out) == [
        "governor_node: error: unknown parameter 'governor.nmae' (did you mean governor.name?) "
        "(the parameters of governor_node: governor_node --help)"]
    # sim.seed belongs to sim_node: the governor ignores it (one params file serves the graph),
    # and the sim takes it while rejecting the governor's typo, which is not its group.
    out = run(["sim_node", "--ros-args", "--params-file", str(params), "-p", "graph.startup_timeout_s:=0.5"])
    assert out.returncode == 1, out.stderr                    # unknown-group typo ignored, peers missing


def test_lone_node_says_what_it_waits_for_and_gives_up(ros_env: int) -> None:
    out = run(["sim_node", "--ros-args", "-p", "graph.startup_timeout_s:=2.0"])
    assert out.returncode == 1
    log = out.stderr
    assert "waiting up to 2 s (graph.startup_timeout_s) for /deputy/odom: 0 of 1 readers matched " \
           "(expected controller)" in log
    (line,) = [ln for ln in log.splitlines() if "giving up after" in ln]   # one line names who is not ready
    assert "not ready: " in line and "/chief/odom: 0 of 1 readers matched (expected controller)" in line
    assert "governor: no announcement on /graph/ready" in line and "controller: no announcement" in line
    assert "mission complete" not in log and "no command for" not in log   # no fake mission


def test_a_node_that_hangs_while_it_ends_says_where_and_exits(ros_env: int) -> None:
    """SIGINT to a node whose close() never returns: after the stop watchdog (shortened to 1 s in
    that process) it exits with code 1 and its stderr holds the stack of the hang, close() in
    it, instead of waiting for the launcher's SIGKILL."""
    import signal

    proc = subprocess.Popen([sys.executable, str(ROOT / "tests" / "hanging_node.py")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert proc.stdout.readline().strip() == "spinning"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)   # its close() alone would take 600 s
    finally:
        proc.kill()
    assert proc.returncode == 1, err
    assert "Timeout" in err and "in close" in err and "hanging_node.py" in err


@pytest.mark.parametrize("args, problem", [
    (["cikan_container"], "name each node once, at least one: recorder, governor, controller, sim"),
    (["cikan_container", "sim", "sim"], "name each node once"),
    (["cikan_container", "sim", "planner"], "unknown node 'planner'; known: recorder, governor, controller, sim"),
    (["cikan_container", "recorder", "sim", "--ros-args", "--params-file", "no/such/params.yaml"],
     "no/such/params.yaml"),
    # a parameter none of its nodes declares; one that only one of them declares is taken
    (["cikan_container", "governor", "controller", "--ros-args", "-p", "sim.seed:=3", "-p",
      "controller.tau_deadline_s:=2.0"],
     "unknown parameter 'sim.seed' (the parameters of cikan_container: governor_node --help, controller_node --help)"),
    (["cikan_container", "governor", "controller", "--ros-args", "-p", "controller.tau_deadline_s:=0.0"],
     "controller.tau_deadline_s must be a positive number of seconds, got 0.0"),
])
def test_a_container_refuses_bad_input_with_one_line(args: list[str], problem: str, ros_env: int) -> None:
    """cikan_container (several nodes in one process) as a user starts it: a bad node list, params
    file or parameter is one line and exit code 2, before any node runs."""
    out = run(args)
    assert out.returncode == 2, out.stderr
    lines = stderr_lines(out)
    assert len(lines) == 1 and lines[0].startswith("cikan_container: error: ") and problem in lines[0], out.stderr


def test_a_container_help_names_its_nodes_and_layouts(ros_env: int, tmp_path: Path) -> None:
    logs = tmp_path / "help_logs"
    out = run(["cikan_container", "--help"], ROS_LOG_DIR=str(logs))
    assert out.returncode == 0 and out.stdout.startswith("usage: cikan_container "), out.stderr
    text = " ".join(out.stdout.split())
    assert "Nodes: recorder, governor, controller, sim." in text
    assert "paired: recorder sim | governor controller" in text and "sim_node --help" not in text
    assert not logs.exists()                         # rclpy not started
