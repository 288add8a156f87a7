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


def by_hand_recipe(index: int = 0) -> tuple[str, list[tuple[str, str]]]:
    """(lines for every shell, [(shell comment, command)]) of by-hand block ``index`` of
    docs/ros_graph.md (0: one process per node, 1: two containers)."""
    text = (ROOT / "docs" / "ros_graph.md").read_text()
    section = text.split("## Running the nodes by hand", 1)[1].split("\n## ", 1)[0]
    block = re.findall(r"```sh\n(.*?)```", section, re.S)[index]
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


#: The shells of each by-hand block: their programs (and the nodes a container runs).
RECIPES = {0: ["recorder_node", "governor_node", "controller_node", "sim_node"],
           1: ["cikan_container recorder sim", "cikan_container governor controller"]}


@pytest.mark.slow
@pytest.mark.parametrize("index", sorted(RECIPES))
def test_by_hand_recipe_flies_and_names_the_governor(index: int, ros_env: int, tmp_path: Path) -> None:
    prelude, shells = by_hand_recipe(index)
    assert [c.split(":")[0] for c, _ in shells] == [f"# shell {i + 1}" for i in range(len(RECIPES[index]))]
    assert [" ".join(cmd.split()[:len(p.split())]) for (_, cmd), p in zip(shells, RECIPES[index])] == RECIPES[index]
    governor = re.search(r"governor\.name:=(\S+)", next(c for _, c in shells if "governor.name" in c)).group(1)
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
    procs: dict[int, subprocess.Popen] = {}   # by shell
    logs: dict[int, Path] = {}
    sim = next(i for i, (_, cmd) in enumerate(shells) if re.search(r"\bsim(_node)?\b", cmd.split("--ros-args")[0]))
    try:
        for i, (comment, cmd) in enumerate(shells):
            logs[i] = tmp_path / f"shell{i + 1}.log"
            with open(logs[i], "wb") as log:
                procs[i] = subprocess.Popen(["bash", "-c", f"{prelude}\n{cmd}"], cwd=tmp_path, env=env,
                                            stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        assert procs[sim].wait(timeout=600) == 0, logs[sim].read_text()
    finally:
        # "Press Ctrl-C in shells 2, 3 and 1" (in the other shell): SIGINT to each shell's process group.
        for i in [*range(1, len(shells)), 0]:
            if i in procs and procs[i].poll() is None:
                os.killpg(procs[i].pid, signal.SIGINT)
                try:
                    procs[i].wait(timeout=30)
                except subprocess.TimeoutExpired:
                    os.killpg(procs[i].pid, signal.SIGKILL)
                    procs[i].wait()
        for p in procs.values():
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
    for i in procs:
        assert procs[i].returncode == 0, logs[i].read_text()
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
