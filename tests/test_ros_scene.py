"""Bags that open as a scene: a short mission through the real graph records the telemetry and
the scene markers in the chief's LVLH frame and carries the telemetry dictionary; rosbags and
mcap read them; the shipped Foxglove layout names only topics the bag has; ``cikan scene``
rebuilds the same messages from the recorded states (and adds them to an old bag)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cikan_ros.config import load_config
from cikan_ros.orbit import lvlh_frame
from cikan_ros.ros.bag_reader import bag_telemetry
from cikan_ros.ros.convert import Timeline
from cikan_ros.ros.launch import run_ros_mission
from cikan_ros.telemetry import dictionary, from_json, to_json
from ros_helpers import isolated_ros, rosbags_messages, shifts, stamp_ns, states

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "foxglove" / "mission_layout.json"
SCENE = ("/telemetry", "/scene/markers", "/scene/path", "/scene/constraints")
CFG = load_config(**{"mission.duration_s": 600.0})
CIKAN = Path(sys.executable).parent / "cikan"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """A 10-minute lockstep mission's bag and its messages read by rosbags."""
    bag = tmp_path_factory.mktemp("scene") / "bag"
    with pytest.MonkeyPatch.context() as mp, isolated_ros(tmp_path_factory.mktemp("env"), mp):
        run_ros_mission(CFG, bag=bag)
    return bag, rosbags_messages(bag)


def test_rosbags_reads_the_scene_in_lvlh_stamped_on_the_step_grid(recorded: tuple[Path, dict]) -> None:
    bag, msgs = recorded
    tl = Timeline(CFG.orbit.epoch_unix_s, CFG.control.period_s)
    n = round(CFG.mission.duration_s / CFG.control.period_s) + 1
    grid = [tl.stamp_ns(k) for k in range(n)]
    for topic in ("/telemetry", "/scene/markers"):
        assert [t for t, _ in msgs[topic]] == grid, topic           # logged at their own stamps
    assert [t for t, _ in msgs["/scene/path"]] == grid[::6]          # every update period, and the end
    assert msgs["/scene/constraints"][0][0] == grid[0]
    for topic in SCENE[1:]:
        for t, arr in msgs[topic]:
            assert arr.markers and {m.header.frame_id for m in arr.markers} == {"lvlh"}
            assert {stamp_ns(m) for m in arr.markers} == {t}
    # the deputy marker sits where the recorded truth puts it in the chief's LVLH frame (m)
    _, x_d = states(msgs, "/truth/deputy/odom")
    _, x_c = states(msgs, "/truth/chief/odom")
    rot = lvlh_frame(x_c)
    expected = np.einsum("nij,nj->ni", rot, x_d[:, :3] - x_c[:, :3]) * 1e3
    got = np.array([[(m.points[0].x, m.points[0].y, m.points[0].z)
                     for m in arr.markers if m.ns == "bodies"][0] for _, arr in msgs["/scene/markers"]])
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-6)
    # the telemetry: tau as the governor published it (held at the end), the range from the truth
    keys = list(msgs["/telemetry"][0][1].name)
    values = np.array([m.position for _, m in msgs["/telemetry"]])
    tau = shifts(msgs)
    np.testing.assert_array_equal(values[:-1, keys.index("tau")], [tau[s] for s in grid[:-1]])
    assert values[-1, keys.index("tau")] == tau[grid[-2]]
    np.testing.assert_allclose(values[:, keys.index("range")], np.linalg.norm(x_d[:, :3] - x_c[:, :3], axis=1) * 1e3,
                               rtol=1e-9)
    assert keys == [p.key for p in dictionary(CFG)]


def test_the_bag_carries_the_dictionary_for_mcap_and_rosbags(recorded: tuple[Path, dict]) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.rosbag2 import Reader

    bag, _ = recorded
    expected = json.loads(json.dumps(to_json(dictionary(CFG), CFG)))
    (path,) = bag.glob("*.mcap")
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        (record,) = [m for m in reader.iter_metadata() if m.name == "cikan_telemetry"]
        (attachment,) = [a for a in reader.iter_attachments() if a.name == "cikan_telemetry.json"]
        frames = {m.header.frame_id for _s, ch, _m, arr in reader.iter_decoded_messages(topics=["/scene/constraints"])
                  for m in arr.markers}
    assert json.loads(record.metadata["json"]) == expected == json.loads(attachment.data)
    assert frames == {"lvlh"}
    with Reader(bag) as reader:
        assert json.loads(reader.storage.metadata.custom["cikan_ros.telemetry"]) == expected  # metadata.yaml
    doc = bag_telemetry(bag)
    assert doc["stored"] and from_json(doc) == dictionary(CFG)


def test_every_topic_the_layout_names_is_in_the_bag(recorded: tuple[Path, dict]) -> None:
    """The shipped Foxglove layout: its 3D panel in frame lvlh shows topics of the bag; each plot
    path is a telemetry index whose label names the dictionary's key at that index."""
    bag, msgs = recorded
    layout = json.loads(LAYOUT.read_text())
    keys = [p.key for p in dictionary(CFG)]
    named: set[str] = set()
    for panel, conf in layout["configById"].items():
        if panel.startswith("3D!"):
            assert conf["followTf"] == "lvlh"
            named |= set(conf["topics"])
        for path in conf.get("paths", []):
            topic, _, field = path["value"].partition(".")
            named.add(topic)
            index = int(field.removeprefix("position[").removesuffix("]"))
            assert path["label"].split(" ")[0] == keys[index], path
    assert {"/scene/markers", "/scene/path", "/scene/constraints", "/telemetry"} <= named
    assert named <= set(msgs)


def test_cikan_scene_rebuilds_the_recorded_scene_and_converts_an_old_bag(recorded: tuple[Path, dict],
                                                                         tmp_path: Path) -> None:
    bag, msgs = recorded
    out = subprocess.run([str(CIKAN), "scene", str(bag), "--out", str(tmp_path / "again"), "--json"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    again = rosbags_messages(tmp_path / "again")
    assert {t: len(v) for t, v in again.items()} == {t: len(v) for t, v in msgs.items()}
    live = np.array([m.position for _, m in msgs["/telemetry"]])
    rebuilt = np.array([m.position for _, m in again["/telemetry"]])
    np.testing.assert_allclose(rebuilt, live, rtol=1e-9, atol=1e-9)   # the states went through SI
    assert [t for t, _ in again["/scene/path"]] == [t for t, _ in msgs["/scene/path"]]
    # an old bag (the shipped one, recorded before the scene existed): scene and dictionary added
    old = ROOT / "bags" / "nominal_conventional"
    assert "/scene/markers" not in {p.name for p in old.iterdir()} and not bag_telemetry(old)["stored"]
    new = tmp_path / "old_with_scene"
    out = subprocess.run([str(CIKAN), "scene", str(old), "--out", str(new)], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    converted = rosbags_messages(new)
    assert set(SCENE) <= set(converted) and len(converted["/telemetry"]) == len(converted["/clock"])
    assert bag_telemetry(new)["stored"]
    # refused with one line: an existing output, a directory that is not a bag
    for args in ([str(old), "--out", str(new)], [str(tmp_path), "--out", str(tmp_path / "x")]):
        out = subprocess.run([str(CIKAN), "scene", *args], capture_output=True, text=True, timeout=60)
        assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr
    shutil.rmtree(new)


def test_the_soak_check_counts_a_lost_telemetry_or_marker_message(recorded: tuple[Path, dict]) -> None:
    """cikan soak's check (check_messages with the scene) finds every step's telemetry and markers
    in a recorded bag, and counts one removed from either as lost, at its step."""
    from cikan_ros.ros.bag_reader import check_messages, read_bag

    bag, _ = recorded
    steps = round(CFG.mission.duration_s / CFG.control.period_s)
    msgs = read_bag(bag, scene=True)
    whole = check_messages(msgs, CFG, steps, scene=True)
    assert (whole["lost"], whole["duplicated"], whole["off_grid"]) == (0, 0, 0)
    for topic in ("/telemetry", "/scene/markers"):
        cut = {t: (v[:7] + v[8:] if t == topic else v) for t, v in msgs.items()}
        check = check_messages(cut, CFG, steps, scene=True)
        assert check["lost"] == 1 and f"{topic} 1 (k 7)" in check["lost_on"]
