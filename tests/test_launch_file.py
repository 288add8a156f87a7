"""launch/mission.launch.yaml (for ROS installs) against the graph definition
(cikan_ros/ros/graph_spec.py) and what the built-in launcher really starts (cikan_ros/ros/launch.py:
its node modules and the params file it writes). The ROS launch system cannot launch it here:
launch, launch_ros, launch_yaml and ros2launch are not published as ros-jazzy-* wheels on PyPI
(`pip download --no-deps ros-jazzy-launch ros-jazzy-launch-ros`: no matching distribution,
2026-11-25), so the file is read with the two substitutions it uses."""

from __future__ import annotations

import re
import subprocess
import tomllib
from datetime import datetime
from pathlib import Path
from typing import Any

import pytest
import yaml

from cikan_ros.config import load_config
from cikan_ros.errors import CikanError
from cikan_ros.ros import graph_spec, launch
from cikan_ros.ros.params import node_defaults

ROOT = Path(__file__).resolve().parent.parent
LAUNCH_FILE = ROOT / "launch" / "mission.launch.yaml"


def substitute(text: str, args: dict[str, str], share: str) -> str:
    """The two launch substitutions the file uses: $(var NAME) and $(find-pkg-share cikan_ros)."""
    def one(m: re.Match) -> str:
        kind, _, what = m.group(1).partition(" ")
        if kind == "var":
            return args[what]
        assert (kind, what) == ("find-pkg-share", "cikan_ros"), m.group(0)
        return share
    return re.sub(r"\$\(([^)]*)\)", one, text)


def evaluate(given: dict[str, str]) -> tuple[dict[str, dict[str, Any]], list[dict[str, Any]]]:
    """({name: arg entity}, [node: exec, files, params, on_exit]) as `ros2 launch` reads the file with
    ``given`` arguments: defaults filled in order, parameter values typed by YAML as launch_ros does."""
    doc = yaml.safe_load(LAUNCH_FILE.read_text())
    args: dict[str, str] = {}
    declared: dict[str, dict[str, Any]] = {}
    nodes = []
    for entity in doc["launch"]:
        if "arg" in entity:
            a = entity["arg"]
            declared[a["name"]] = a
            args[a["name"]] = given.get(a["name"], substitute(str(a["default"]), args, "SHARE"))
        else:
            n = entity["node"]
            files, params = [], {}
            for p in n["param"]:
                if "from" in p:
                    files.append(substitute(p["from"], args, "SHARE"))
                else:
                    v = p["value"]
                    params[p["name"]] = yaml.safe_load(substitute(v, args, "SHARE")) if isinstance(v, str) else v
            nodes.append({"pkg": n["pkg"], "exec": n["exec"], "files": files, "params": params,
                          "on_exit": n.get("on_exit")})
    return declared, nodes


def peers_as_set(params: dict[str, Any]) -> dict[str, Any]:
    return {**params, "graph.peers": sorted(params["graph.peers"])}


def test_launch_file_has_the_graphs_nodes_parameters_and_arguments() -> None:
    given = {"governor": "cikan", "seed": "3", "bag": "bags/cikan3", "scenario": "leo", "approach": "ahead"}
    declared, nodes = evaluate(given)
    assert set(declared) == set(graph_spec.ARGUMENTS) == {"governor", "seed", "bag", "scenario", "approach"}
    assert all(a.get("description") for a in declared.values())
    assert [n["exec"] for n in nodes] == [n.executable for n in graph_spec.NODES]
    expected = graph_spec.node_parameters(governor="cikan", seed=3, bag="bags/cikan3", approach="ahead")
    for n in nodes:
        assert n["pkg"] == "cikan_ros"
        # the mission configuration, then the scenario's file over it
        assert n["files"] == ["SHARE/config/cikan.yaml", "SHARE/config/scenarios/leo.yaml"]
        assert peers_as_set(n["params"]) == peers_as_set(expected), n["exec"]
        assert n["on_exit"] == ("shutdown" if n["exec"] == "sim_node" else None)  # the sim ends it
    # every one is a declared parameter: a node parameter, or one of the mission configuration
    assert set(expected) <= set(node_defaults()) | set(load_config().flat())


def test_launch_file_defaults_are_the_launchers() -> None:
    _, nodes = evaluate({})
    params = nodes[0]["params"]
    assert params["governor.name"] == graph_spec.ARGUMENTS["governor"] == "conventional"
    assert params["sim.seed"] == graph_spec.ARGUMENTS["seed"] == -1
    assert params["recorder.bag"] == graph_spec.ARGUMENTS["bag"].format(utc="{utc}", governor="conventional")
    # the launcher's default bag: runs/bags/<UTC time in graph_spec.UTC_FORMAT>_<governor>, where
    # git ignores it (bags/ holds the committed reference bags)
    default = launch.default_bag_path("conventional")
    prefix, utc, rest = default.parent.as_posix(), *default.name.split("_", 1)
    datetime.strptime(utc, graph_spec.UTC_FORMAT)
    assert f"{prefix}/{{utc}}_{rest}" == params["recorder.bag"]
    if (ROOT / ".git").exists():   # a checkout: git ignores what a mission records by default
        assert subprocess.run(["git", "-C", str(ROOT), "check-ignore", "-q", default.as_posix()]).returncode == 0


def test_graph_spec_is_what_the_launcher_starts(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The launcher's node modules, the executables' console scripts, and the parameters it writes."""
    graph = launch.Graph(tmp_path, {}, tmp_path / "params.yaml")
    for n in graph_spec.NODES:   # each node runs its module: python -m MODULE --ros-args --params-file FILE
        assert graph.argv(n.name)[1:3] == ["-m", n.module]
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    for n in graph_spec.NODES:
        assert scripts[n.executable].split(":")[0] in (n.module, f"{n.module}.node")
    written: dict[str, Any] = {}

    class Written(Exception):
        pass

    def capture(path: Path, cfg: Any, node_params: dict[str, Any]) -> Path:
        written.update(cfg=cfg, params=node_params)
        raise Written   # stop before any process starts

    monkeypatch.setattr(launch, "write_params", capture)
    monkeypatch.setattr(launch.tempfile, "tempdir", str(tmp_path))
    cfg = load_config()
    with pytest.raises(Written):
        launch.run_ros_mission(cfg, governor="cikan", seed=3, bag=tmp_path / "bag")
    assert written["cfg"] == cfg
    assert peers_as_set(written["params"]) == peers_as_set(
        graph_spec.node_parameters(governor="cikan", seed=3, bag=(tmp_path / "bag").resolve()))


def test_every_layout_runs_every_node_once_and_a_container_runs_several(tmp_path: Path) -> None:
    """Each process layout puts each node of the graph in exactly one process, the recorder's
    first (it must hear everything; the simulator waits for every peer to be ready); a process
    of several nodes is the container's command line, its nodes named; a node run by another
    executable (--governor-exec) gets a process of its own; the container builds each node from
    the class graph_spec names."""
    names = [n.name for n in graph_spec.NODES]
    for layout, groups in graph_spec.LAYOUTS.items():
        flat = [n for g in groups for n in g]
        assert sorted(flat) == sorted(names), layout
        assert "recorder" in groups[0], layout
    assert graph_spec.DEFAULT_LAYOUT in graph_spec.LAYOUTS
    assert graph_spec.processes("paired", ["governor"]) == [("recorder", "sim"), ("governor",), ("controller",)]
    assert graph_spec.processes("single", ["governor"]) == [("governor",), ("recorder", "controller", "sim")]
    assert graph_spec.processes("separate") == [(n,) for n in names]
    with pytest.raises(ValueError, match="unknown process layout 'pairs'"):
        graph_spec.processes("pairs")
    assert graph_spec.process_name(("sim",)) == "sim_node"
    assert graph_spec.process_name(("recorder", "sim")) == "recorder+sim"
    graph = launch.Graph(tmp_path, {}, tmp_path / "params.yaml")
    assert graph.argv(("recorder", "sim"))[1:] == ["-m", "cikan_ros.ros.container", "recorder", "sim", "--ros-args",
                                                   "--params-file", str(tmp_path / "params.yaml")]
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["cikan_container"] == "cikan_ros.ros.container:main"
    for n in graph_spec.NODES:
        cls = graph_spec.load_object(n.node_class)
        assert cls.__module__ in (n.module, f"{n.module}.node") and isinstance(cls, type)


def test_a_bad_layout_is_one_line_before_any_process_starts(tmp_path: Path) -> None:
    with pytest.raises(CikanError, match="unknown process layout 'both'; known: paired, separate, single"):
        launch.run_ros_mission(load_config(), bag=tmp_path / "bag", layout="both")
    assert not (tmp_path / "bag").exists()
