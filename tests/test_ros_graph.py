"""The ROS graph as real processes over real DDS (isolated domain), checked against the offline
loop and through the independent bag readers (rosbags, mcap)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from cikan_ros.config import load_config
from cikan_ros.registry import GOVERNOR_NAMES, make_governor
from cikan_ros.mission import nominal_start, run_mission
from cikan_ros.tsg import Predictor
from cikan_ros.ros.graph_spec import DEFAULT_LAYOUT, LAYOUTS, process_name
from cikan_ros.ros.launch import run_ros_mission
from ros_helpers import (independent_check, isolated_ros, mcap_counts, ros_env, rosbags_messages, shifts, sim_steps,
                         states, tau_history)

__all__ = ["ros_env"]


@pytest.fixture(scope="module")
def conventional(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    """One full 4-hour lockstep mission with the conventional governor (shared by the tests)."""
    bag = tmp_path_factory.mktemp("conventional") / "bag"
    with pytest.MonkeyPatch.context() as mp, isolated_ros(tmp_path_factory.mktemp("env"), mp):
        metrics = run_ros_mission(load_config(), governor="conventional", bag=bag)
    return metrics, bag


def test_lockstep_graph_equals_offline_loop(conventional: tuple[dict, Path]) -> None:
    metrics, bag = conventional
    cfg = load_config()
    gov = make_governor("conventional", cfg, Predictor.from_config(cfg))
    offline = run_mission(gov, nominal_start(gov.predictor))
    msgs = rosbags_messages(bag)
    stamps, x_d = states(msgs, "/deputy/odom")
    assert len(stamps) == len(offline.t)
    epoch = round(cfg.orbit.epoch_unix_s * 1e9)
    np.testing.assert_array_equal((stamps - epoch) / 1e9, offline.t)
    tau = tau_history(msgs, len(stamps), stamps)
    np.testing.assert_array_equal(tau, offline.tau)          # identical values, every step
    rel = np.abs(x_d[-1] - offline.x_d[-1]) / np.abs(offline.x_d[-1])
    assert rel.max() < 1e-9
    steps = sim_steps(msgs)                                   # the thrust the simulator applied
    u = np.array([[float(w) for w in steps[k]["u_kmps2"].split()] for k in range(len(stamps) - 1)])
    np.testing.assert_array_equal(u, offline.u[:-1])
    off = offline.metrics()
    for key in ("success", "violations", "violations_between", "tau0_s", "t_tau_zero_s", "t_docked_s", "updates",
                "active_updates", "verify_calls", "delta_v_kmps"):
        assert metrics[key] == off[key], key


def test_the_other_executor_flies_the_same_mission(ros_env: int, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """Every node on rclpy's SingleThreadedExecutor (CIKAN_ROS_EXECUTOR=single, the QoS event
    handlers dropped once each node is ready): one hour of the lockstep flies the offline loop's
    shifts and thrusts, step for step."""
    monkeypatch.setenv("CIKAN_ROS_EXECUTOR", "single")
    cfg = load_config(**{"mission.duration_s": 3600.0})
    metrics = run_ros_mission(cfg, governor="conventional", bag=tmp_path / "bag")
    gov = make_governor("conventional", cfg, Predictor.from_config(cfg))
    offline = run_mission(gov, nominal_start(gov.predictor))
    msgs = rosbags_messages(tmp_path / "bag")
    stamps, _ = states(msgs, "/deputy/odom")
    assert len(stamps) == len(offline.t)
    np.testing.assert_array_equal(tau_history(msgs, len(stamps), stamps), offline.tau)
    steps = sim_steps(msgs)
    u = np.array([[float(w) for w in steps[k]["u_kmps2"].split()] for k in range(len(stamps) - 1)])
    np.testing.assert_array_equal(u, offline.u[:-1])
    assert metrics["ros"]["deadline_misses"] == 0 and metrics["tau0_s"] == offline.metrics()["tau0_s"]


@pytest.mark.parametrize("layout", sorted(set(LAYOUTS) - {DEFAULT_LAYOUT}))
def test_every_process_layout_flies_the_same_mission(layout: str, ros_env: int, tmp_path: Path) -> None:
    """The nodes in other processes (one each; all in one) than the default's (the module's
    full mission, test_lockstep_graph_equals_offline_loop): one hour of the lockstep flies the
    offline loop's shifts and thrusts, step for step, and the recorder's bag has every message."""
    cfg = load_config(**{"mission.duration_s": 3600.0})
    metrics = run_ros_mission(cfg, governor="conventional", bag=tmp_path / "bag", layout=layout)
    assert metrics["ros"]["layout"] == layout
    assert metrics["ros"]["processes"] == [process_name(g) for g in LAYOUTS[layout]]
    gov = make_governor("conventional", cfg, Predictor.from_config(cfg))
    offline = run_mission(gov, nominal_start(gov.predictor))
    msgs = rosbags_messages(tmp_path / "bag")
    stamps, _ = states(msgs, "/deputy/odom")
    assert len(stamps) == len(offline.t) and len(msgs["/deputy/accel_cmd"]) == len(offline.t) - 1
    np.testing.assert_array_equal(tau_history(msgs, len(stamps), stamps), offline.tau)
    steps = sim_steps(msgs)
    u = np.array([[float(w) for w in steps[k]["u_kmps2"].split()] for k in range(len(stamps) - 1)])
    np.testing.assert_array_equal(u, offline.u[:-1])
    assert metrics["ros"]["deadline_misses"] == 0 and metrics["tau0_s"] == offline.metrics()["tau0_s"]


def test_conventional_mission_docks_without_violation(conventional: tuple[dict, Path]) -> None:
    metrics, bag = conventional
    msgs = rosbags_messages(bag)
    _, x_d = states(msgs, "/deputy/odom")
    _, x_c = states(msgs, "/chief/odom")
    rel = x_d[-1] - x_c[-1]
    assert np.linalg.norm(rel[:3]) < 1e-3 and np.linalg.norm(rel[3:]) < 1e-6   # docked (km, km/s)
    h1n, h3 = independent_check(x_d, x_c)
    assert h1n <= 1e-9 and h3 <= 1e-9
    assert max(shifts(msgs).items())[1] == 0.0
    assert metrics["success"] and metrics["violations"] == 0
    assert metrics["ros"]["deadline_misses"] == 0 and metrics["ros"]["rejected"] == 0


def test_bag_opens_with_both_readers_and_counts_match(conventional: tuple[dict, Path]) -> None:
    from mcap.reader import make_reader

    cfg = load_config()
    _, bag = conventional
    n_steps = round(cfg.mission.duration_s / cfg.control.period_s)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    meta_topics = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    by_rosbags = {t: len(v) for t, v in rosbags_messages(bag).items()}
    by_mcap = mcap_counts(bag)
    assert by_rosbags == by_mcap == {t: m["message_count"] for t, m in meta_topics.items()}
    assert sum(by_mcap.values()) == meta["message_count"]
    # What the nodes published: K+1 states and clock ticks, K shifts and commands.
    for topic in ("/clock", "/chief/odom", "/deputy/odom"):
        assert by_mcap[topic] == n_steps + 1
    assert by_mcap["/tsg/time_shift"] == by_mcap["/deputy/accel_cmd"] == n_steps
    with open(next(bag.glob("*.mcap")), "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
    assert header.profile == "ros2"
    share = Path(__import__("sys").prefix) / "share"
    for ch in summary.channels.values():
        schema = summary.schemas[ch.schema_id]
        assert ch.message_encoding == "cdr" and schema.encoding == "ros2msg"
        pkg, _, name = schema.name.split("/")
        assert schema.data.decode().startswith((share / pkg / "msg" / f"{name}.msg").read_text().rstrip("\n"))
        topic_meta = meta_topics[ch.topic]["topic_metadata"]
        assert yaml.safe_load(ch.metadata["offered_qos_profiles"]) == topic_meta["offered_qos_profiles"]
        assert topic_meta["offered_qos_profiles"], ch.topic
        hashes = json.loads((share / pkg / "msg" / f"{name}.json").read_text())["type_hashes"]
        assert ch.metadata["topic_type_hash"] == topic_meta["type_description_hash"] == hashes[0]["hash_string"]
    # The recorder registered every topic before the lockstep began (Readiness' prepare hook): in
    # the record stream every Channel comes before the first Message.
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    with open(next(bag.glob("*.mcap")), "rb") as f:
        before = set()
        for record in StreamReader(f).records:
            if isinstance(record, Message):
                break
            if isinstance(record, Channel):
                before.add(record.topic)
    assert before == set(meta_topics)


def _learned_mission(name: str, tmp_path: Path, scenario: str = "paper", approach: str = "behind") -> None:
    from cikan_ros.config import scenario_overrides
    from cikan_ros.learn.modelfile import scenario_model_dir

    cfg = load_config(**scenario_overrides(scenario), **{"mission.approach": approach})
    if not scenario_model_dir(cfg.scenario.models_dir, name, approach).exists():
        pytest.skip(f"no shipped model {name} for scenario {scenario}, approach {approach}")
    bag = tmp_path / "bag"
    metrics = run_ros_mission(cfg, governor=name, bag=bag)
    msgs = rosbags_messages(bag)
    _, x_d = states(msgs, "/deputy/odom")
    _, x_c = states(msgs, "/chief/odom")
    rel = x_d[-1] - x_c[-1]
    assert np.linalg.norm(rel[:3]) < 1e-3 and np.linalg.norm(rel[3:]) < 1e-6
    c = cfg.constraints
    h1n, h3 = independent_check(x_d, x_c, c.los_half_angle_deg, (c.gamma1_km, c.gamma2_per_s, c.gamma3_kmps),
                                port=-cfg.side)
    assert h1n <= 1e-9 and h3 <= 1e-9
    paths = {m.source for _, m in msgs["/tsg/time_shift"]}
    assert paths & {"nn", "nn+bisect"}, paths      # the network was consulted
    failed = [st.message for _, arr in msgs["/diagnostics"] for st in arr.status if st.level >= 2]
    assert not failed
    assert metrics["governor"] == name and metrics["success"]
    # the same governor offline: the same shifts
    gov = make_governor(name, cfg, Predictor.from_config(cfg))
    offline = run_mission(gov, nominal_start(gov.predictor))
    stamps, _ = states(msgs, "/deputy/odom")
    np.testing.assert_array_equal(tau_history(msgs, len(stamps), stamps), offline.tau)


@pytest.mark.parametrize("name, scenario, approach", [(n, "paper", "behind") for n in GOVERNOR_NAMES[1:]]
                         + [("cikan", "leo", "ahead")])
def test_learned_governor_mission(name: str, scenario: str, approach: str, ros_env: int, tmp_path: Path) -> None:
    """Every learned governor (the conventional one: the module's shared mission above) flies the
    graph, docks safely and gives the offline shifts; and one in LEO from ahead (`cikan mission
    --scenario leo --set mission.approach=ahead --governor cikan`), the port facing forward."""
    _learned_mission(name, tmp_path, scenario, approach)


def test_realistic_truth_and_robust_verify_graph_equals_offline(tmp_path, ros_env) -> None:
    """`cikan mission --truth realistic --robust --seed 2` as the ROS graph: the same run as the
    offline loop (tau history, true states, applied thrust), 0 violations and docked on the truth,
    and the bag holds the truth and the measured states (with their covariance), read by rosbags."""
    from cikan_ros.config import truth_overrides
    from cikan_ros.mission import sample_start
    from cikan_ros.truth import Truth

    cfg = load_config(**truth_overrides("realistic"), **{"tsg.robust": True})
    bag = tmp_path / "bag"
    metrics = run_ros_mission(cfg, governor="conventional", seed=2, bag=bag)
    gov = make_governor("conventional", cfg, Predictor.from_config(cfg))
    offline = run_mission(gov, sample_start(gov.predictor, 2), 2)
    msgs = rosbags_messages(bag)
    stamps, seen = states(msgs, "/deputy/odom")
    _, x_d = states(msgs, "/truth/deputy/odom")
    _, x_c = states(msgs, "/truth/chief/odom")
    np.testing.assert_array_equal(tau_history(msgs, len(stamps), stamps), offline.tau)
    np.testing.assert_allclose(x_d, offline.x_d, rtol=1e-15, atol=0)  # SI round trip only
    np.testing.assert_allclose(x_c, offline.x_c, rtol=1e-15, atol=0)
    steps = sim_steps(msgs)
    u = np.array([[float(w) for w in steps[k]["u_kmps2"].split()] for k in range(len(stamps) - 1)])
    np.testing.assert_array_equal(u, offline.u[:-1])
    # measured = truth + navigation error within its bound; the covariance says a third of it
    truth = Truth(cfg, 2, len(stamps) - 1)
    err = np.linalg.norm(seen[:, :3] - x_d[:, :3], axis=1)
    rng = np.linalg.norm(x_d[:, :3] - x_c[:, :3], axis=1)
    bound = np.array([truth.nav_bounds(r)[0] for r in rng])
    assert np.all(err <= bound + 1e-9) and err.max() > 0  # km; the SI round trip moves ~1e-12 km
    cov = np.array(msgs["/deputy/odom"][len(stamps) // 2][1].pose.covariance).reshape(6, 6)
    assert cov[0, 0] > 0 and cov[0, 0] == cov[1, 1] == cov[2, 2] and cov[3, 3] == 0
    off = offline.metrics()
    for key in ("success", "violations", "violations_between", "tau0_s", "t_tau_zero_s", "delta_v_kmps",
                "final_distance_m"):
        assert metrics[key] == off[key], key
    assert metrics["success"] and metrics["violations"] == 0
    h1n, h3 = independent_check(x_d, x_c)
    assert h1n <= 1e-9 and h3 <= 1e-9


def test_sim_diagnostics_h1_from_ahead_is_the_forward_ports(tmp_path, ros_env) -> None:
    """From ahead the docking port faces +v_c: the normalised h1 the simulator publishes on
    /diagnostics at every step (and in its summary) is SPEC §4's with the port mirrored,
    (-v_c.p + cos a |v_c| |p|) / (|v_c| |p|), computed here with numpy from the recorded true
    states; the behind port's value (the wrong one) is ~2 away. A 10-minute mission."""
    cfg = load_config(**{"mission.approach": "ahead", "mission.duration_s": 600.0})
    bag = tmp_path / "bag"
    run_ros_mission(cfg, governor="conventional", bag=bag)
    msgs = rosbags_messages(bag)
    _, x_d = states(msgs, "/truth/deputy/odom")
    _, x_c = states(msgs, "/truth/chief/odom")
    p, vc = x_d[:, :3] - x_c[:, :3], x_c[:, 3:]
    scale = np.linalg.norm(vc, axis=1) * np.linalg.norm(p, axis=1)
    cos_a = np.cos(np.radians(cfg.constraints.los_half_angle_deg))
    forward = -np.sum(vc * p, axis=1) / scale + cos_a
    behind = np.sum(vc * p, axis=1) / scale + cos_a
    steps = sim_steps(msgs)
    assert len(steps) == len(x_d) - 1 == round(600.0 / cfg.control.period_s)
    published = np.array([float(steps[k]["h1_normalised"]) for k in range(len(x_d) - 1)])
    (summary,) = [{kv.key: kv.value for kv in st.values} for _, arr in msgs["/diagnostics"] for st in arr.status
                  if st.name == "sim_node" and any(kv.key == "event" and kv.value == "complete" for kv in st.values)]
    published = np.append(published, float(summary["h1_normalised"]))
    np.testing.assert_allclose(published, forward, rtol=0, atol=1e-12)
    assert np.all(published < 0) and np.all(np.abs(published - behind) > 1.0)
