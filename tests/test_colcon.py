"""colcon from the package index builds the package as a ROS user would (docs/ros_graph.md, "colcon
and ROS 2 launch": the repository linked into a workspace's src/), plain and with --symlink-install; the
install has what ROS expects, and the installed nodes fly a short mission in which the installed
governor loads its model from share/cikan_ros. Judged by the files and by the bag."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cikan_ros.config import load_config
from ros_helpers import isolated_ros, rosbags_messages

ROOT = Path(__file__).resolve().parent.parent
COLCON = Path(sys.executable).parent / "colcon"
NODES = ("sim_node", "governor_node", "controller_node", "recorder_node")
FAMILIES = sorted(p.parent.relative_to(ROOT / "models").as_posix() for p in (ROOT / "models").rglob("card.json"))


def build(ws: Path, *options: str) -> Path:
    """`colcon build [options]` in a new workspace whose src/cikan_ros links to this repository."""
    (ws / "src").mkdir(parents=True)
    (ws / "src" / "cikan_ros").symlink_to(ROOT)
    env = {k: v for k, v in os.environ.items() if k not in ("AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH")}
    out = subprocess.run([str(COLCON), "build", *options], cwd=ws, env=env, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    return ws / "install"


def sourced_env(install: Path) -> dict[str, str]:
    """The environment after `. install/setup.sh` (what ros2 run / launch would run nodes with)."""
    out = subprocess.run(["sh", "-c", f". '{install}/setup.sh' && env -0"], capture_output=True,
                         timeout=60, env=dict(os.environ))
    assert out.returncode == 0, out.stderr
    return dict(item.split("=", 1) for item in out.stdout.decode().split("\0") if "=" in item)


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def installs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return {"plain": build(tmp_path_factory.mktemp("ws_plain")),
            "symlink": build(tmp_path_factory.mktemp("ws_symlink"), "--symlink-install")}


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["plain", "symlink"])
def test_install_layout(installs: dict[str, Path], mode: str) -> None:
    prefix = installs[mode] / "cikan_ros"
    for node in NODES:
        exe = prefix / "lib" / "cikan_ros" / node
        assert exe.is_file() and os.access(exe, os.X_OK), node
    share = prefix / "share" / "cikan_ros"
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "cikan_ros").is_file()
    expected = ["package.xml", "config/cikan.yaml", "config/nodes.yaml", "launch/mission.launch.yaml",
                "config/scenarios/paper.yaml", "config/scenarios/leo.yaml", "config/scenarios/geo.yaml",
                "config/foxglove/mission_layout.json", "models/README.md"] + [f"models/{f}/{name}" for f in FAMILIES
                                       for name in ("model.safetensors", "card.json")]
    # the paper's five families, and the scenarios' models in their subdirectories
    assert {"cikan", "grbf", "rswaf", "relu", "gelu", "leo/cikan-ahead"} <= set(FAMILIES)
    for rel in expected:
        assert sha256(share / rel) == sha256(ROOT / rel), rel       # the same bytes as the source


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["plain", "symlink"])
def test_installed_nodes_answer_help(installs: dict[str, Path], mode: str, tmp_path: Path) -> None:
    env = sourced_env(installs[mode])
    for node in NODES:
        out = subprocess.run([str(installs[mode] / "cikan_ros" / "lib" / "cikan_ros" / node), "--help"],
                             capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
        assert out.returncode == 0, out.stderr
        assert out.stdout.startswith(f"usage: {node} ") and "orbit.a_km = " in out.stdout


@pytest.mark.slow
def test_installed_graph_flies_with_the_installed_model(installs: dict[str, Path], tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """The four installed executables (plain install, sourced as a user would, run outside the
    source tree) fly a 10-minute mission with governor.name:=cikan."""
    install = installs["plain"]
    share = install / "cikan_ros" / "share" / "cikan_ros"
    cfg = load_config(**{"mission.duration_s": 600.0})
    params = tmp_path / "params.yaml"
    flat = {**cfg.flat(), "governor.name": "cikan", "recorder.bag": str(tmp_path / "bag"),
            "graph.peers": ["sim", "governor", "controller", "recorder"]}
    nested: dict = {}
    for name, value in flat.items():
        group, key = name.split(".", 1)
        nested.setdefault(group, {})[key] = value
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": nested}}))
    with isolated_ros(tmp_path, monkeypatch):
        env = sourced_env(install)
        procs, logs = {}, {}
        try:
            for node in ("recorder_node", "governor_node", "controller_node", "sim_node"):
                logs[node] = tmp_path / f"{node}.log"
                with open(logs[node], "wb") as log:
                    procs[node] = subprocess.Popen(
                        [str(install / "cikan_ros" / "lib" / "cikan_ros" / node), "--ros-args",
                         "--params-file", str(params)], env=env, cwd=tmp_path, stdout=log,
                        stderr=subprocess.STDOUT, start_new_session=True)
            assert procs["sim_node"].wait(timeout=600) == 0, logs["sim_node"].read_text()
        finally:
            for node in ("governor_node", "controller_node", "recorder_node", "sim_node"):
                p = procs.get(node)
                if p is not None and p.poll() is None:
                    os.killpg(p.pid, signal.SIGINT)
                    try:
                        p.wait(timeout=30)
                    except subprocess.TimeoutExpired:
                        os.killpg(p.pid, signal.SIGKILL)
                        p.wait()
    assert [procs[n].returncode for n in NODES] == [0, 0, 0, 0], {n: logs[n].read_text()[-2000:] for n in NODES}
    meta = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["custom_data"]["cikan_ros.governor"] == "cikan"
    (announced,) = json.loads(meta["custom_data"]["cikan_ros.governor_announcements"])
    assert Path(announced["model"]) == (share / "models" / "cikan").resolve()   # from the install
    card = json.loads((share / "models" / "cikan" / "card.json").read_text())
    assert announced["weights_sha256"] == card["weights_sha256"] == sha256(ROOT / "models/cikan/model.safetensors")
    msgs = rosbags_messages(tmp_path / "bag")
    assert len(msgs["/deputy/odom"]) == 61 and len(msgs["/tsg/time_shift"]) == 60
    sources = {m.source for _, m in msgs["/tsg/time_shift"]}
    assert sources - {"hold"}, sources                           # the governor decided
