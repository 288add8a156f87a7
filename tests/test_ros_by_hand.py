"""docs/ros_graph.md, "Running the nodes by hand": the recipe runs exactly as written (one bash per
shell, in a directory laid out like the repository), flies the mission and leaves a bag that names
the governor that flew, as the governor announced it. Judged by the bag, read with rosbags."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cikan_ros.config import load_config
from cikan_ros.ros.bag_reader import mission_from_bag
from ros_helpers import rosbags_messages, ros_env

__all__ = ["ros_env"]
ROOT = Path(__file__).resolve().parent.parent


def by_hand_recipe() -> tuple[str, list[tuple[str, str]]]:
    """(lines for every shell, [(shell comment, command)]) of the by-hand block of docs/ros_graph.md."""
    text = (ROOT / "docs" / "ros_graph.md").read_text()
    section = text.split("## Running the nodes by hand", 1)[1]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1)
    prelude, shells = [], []
    comment = None
    for line in block.splitlines():
        if line.startswith("# shell "):
            comment = line
        elif comment is not None and line.strip():
            shells.append((comment, line))
            comment = None
        elif not shells and line.strip() and not line.startswith("#"):
            prelude.append(line)
    return "\n".join(prelude), shells


@pytest.mark.slow
def test_by_hand_recipe_flies_and_names_the_governor(ros_env: int, tmp_path: Path) -> None:
    prelude, shells = by_hand_recipe()
    assert [c.split(":")[0] for c, _ in shells] == ["# shell 1", "# shell 2", "# shell 3", "# shell 4"]
    assert [cmd.split()[0] for _, cmd in shells] == ["recorder_node", "governor_node", "controller_node",
                                                     "sim_node"]
    governor = re.search(r"governor\.name:=(\S+)", shells[1][1]).group(1)
    bag_rel = re.search(r"recorder\.bag:=(\S+)", shells[0][1]).group(1)
    # A directory that looks like the repository to the recipe: the venv and the shipped config.
    (tmp_path / ".venv").symlink_to(Path(sys.prefix))
    (tmp_path / "config").symlink_to(ROOT / "config")
    # The recipe's domain, 42, becomes the test's leased one: no concurrent graph shares it.
    assert "export ROS_DOMAIN_ID=42 " in prelude
    env_names = ("ROS_DOMAIN_ID", "CIKAN_ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE",
                 "FASTRTPS_DEFAULT_PROFILES_FILE")   # the recipe sets them itself
    prelude = prelude.replace("export ROS_DOMAIN_ID=42 ", f"export ROS_DOMAIN_ID={ros_env} ")
    env = {k: v for k, v in os.environ.items() if k not in env_names}
    procs: dict[str, subprocess.Popen] = {}
    logs: dict[str, Path] = {}
    try:
        for comment, cmd in shells:
            name = cmd.split()[0]
            logs[name] = tmp_path / f"{name}.log"
            with open(logs[name], "wb") as log:
                procs[name] = subprocess.Popen(["bash", "-c", f"{prelude}\n{cmd}"], cwd=tmp_path, env=env,
                                               stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        assert procs["sim_node"].wait(timeout=600) == 0, logs["sim_node"].read_text()
    finally:
        # "Press Ctrl-C in shells 2, 3 and 1": SIGINT to each shell's process group.
        for name in ("governor_node", "controller_node", "recorder_node"):
            if name in procs and procs[name].poll() is None:
                os.killpg(procs[name].pid, signal.SIGINT)
                try:
                    procs[name].wait(timeout=30)
                except subprocess.TimeoutExpired:
                    os.killpg(procs[name].pid, signal.SIGKILL)
                    procs[name].wait()
        for p in procs.values():
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
    for name in ("governor_node", "controller_node", "recorder_node"):
        assert procs[name].returncode == 0, logs[name].read_text()
    bag = tmp_path / bag_rel
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["custom_data"]["cikan_ros.governor"] == governor      # announced by the governor
    msgs = rosbags_messages(bag)
    cfg = load_config()
    steps = round(cfg.mission.duration_s / cfg.control.period_s)
    assert len(msgs["/deputy/odom"]) == len(msgs["/chief/odom"]) == steps + 1   # from the first state on
    assert len(msgs["/tsg/time_shift"]) == len(msgs["/deputy/accel_cmd"]) == steps
    result, summary = mission_from_bag(bag, cfg, governor)
    assert summary["deadline_misses"] == 0
    assert result.metrics()["success"]
