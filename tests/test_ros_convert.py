"""Message <-> domain conversions, bag schemas and QoS, parameters: plain unit tests (no DDS traffic)."""

from __future__ import annotations

import io
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings, strategies as st
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import AccelStamped
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, TimeReference
from visualization_msgs.msg import MarkerArray

from cikan_ros.config import Side, load_config
from cikan_ros.errors import ConfigError
from cikan_ros.ros import cdr, convert as cv
from cikan_ros.ros.bag_writer import BagWriter, qos_dict, schema_text, type_hash
from cikan_ros.ros.graph import QOS_PROFILES, QOS_STREAM, qos_for
from cikan_ros.ros.graph_spec import QOS_KINDS, TOPICS
from cikan_ros.ros.params import declare_config, parameter_descriptions
from cikan_ros.scene import SceneBuilder, Shape, port_axis_lvlh
from cikan_ros.units import ns_to_seconds, seconds_to_ns, through_si
from ros_helpers import ros_env

__all__ = ["ros_env"]

X = np.array([6928.137, -1234.5678901234, 4321.000000123, 1.2345678901, 10.00542, -0.000123456789])


def test_stamps_are_exact_and_on_the_control_grid() -> None:
    cfg = load_config()
    tl = cv.Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
    assert tl.epoch_ns == 1735689600 * 10**9
    for k in (0, 1, 7, 1440):
        stamp = tl.stamp_ns(k)
        assert cv.time_to_ns(cv.ns_to_time(stamp)) == stamp
        assert tl.step(stamp) == k
        assert tl.seconds(stamp) == ns_to_seconds(k * seconds_to_ns(cfg.control.period_s))
    with pytest.raises(cv.MessageError, match="not a control step"):
        tl.step(tl.stamp_ns(3) + 1)
    with pytest.raises(cv.MessageError):
        tl.step(tl.epoch_ns - tl.period_ns)


def test_odometry_round_trip_is_what_the_offline_loop_sees() -> None:
    data = serialize_message(cv.odom_msg(X, 123, "deputy"))
    msg = deserialize_message(data, Odometry)
    assert msg.header.frame_id == "eci" and msg.child_frame_id == "deputy"
    assert msg.pose.pose.position.x == X[0] * 1000.0                  # SI on the wire
    stamp, frame, x_si = cdr.odom_from_cdr(data)
    assert (stamp, frame) == (123, "eci")
    np.testing.assert_array_equal(cv.state_from_odom(frame, x_si), through_si(X))
    with pytest.raises(cv.MessageError, match="non-finite"):
        cv.state_from_odom("eci", [X[0], X[1], X[2], 0.0, float("inf"), 0.0])
    with pytest.raises(cv.MessageError, match="Earth's centre"):
        cv.state_from_odom(*cdr.odom_from_cdr(serialize_message(cv.odom_msg(np.array([0.1, 0, 0, 0, 0, 0]), 0,
                                                                           "deputy")))[1:])
    msg.header.frame_id = "map"
    with pytest.raises(cv.MessageError, match="frame"):
        cv.state_from_odom(*cdr.odom_from_cdr(serialize_message(msg))[1:])


def test_command_and_shift_read_in_place_are_what_rclpy_deserialises() -> None:
    """accel_from_cdr and shift_from_cdr read an AccelStamped's and a TimeReference's fields from
    the CDR bytes as rclpy's deserialiser does, for frames and sources of every length (they move
    the alignment); other bytes go through rclpy, and bytes nothing decodes are a MessageError."""
    rng = np.random.default_rng(11)
    for frame in ("eci", "", "m", "lvlh_frame"):
        for stamp in (0, 5, 1_735_689_600_123_456_789):
            msg = cv.accel_msg(rng.normal(size=3) * 1e-4, stamp)
            msg.header.frame_id = frame
            data = serialize_message(msg)
            ref = deserialize_message(data, AccelStamped)
            a = ref.accel.linear
            got = cdr.accel_from_cdr(data)
            assert got[:2] == (cv.time_to_ns(ref.header.stamp), frame) and np.array_equal(got[2], [a.x, a.y, a.z])
            for source in ("", "hold", "bisect", "nn-accepted"):
                shift = cv.time_shift_msg(stamp, -ns_to_seconds(int(rng.integers(0, 10**12))), source)
                shift.header.frame_id = frame
                data = serialize_message(shift)
                ref = deserialize_message(data, TimeReference)
                expected = (cv.time_to_ns(ref.header.stamp), cv.time_to_ns(ref.time_ref), ref.source)
                assert cdr.shift_from_cdr(data) == expected
                assert cdr.shift_from_cdr(data + b"\x00" * 3) == expected      # trailing padding
    data = serialize_message(cv.time_shift_msg(7, -2.5, "hold"))
    assert cdr.shift_from_cdr(data + b"\x00" * 8) == (7, 7 - 2_500_000_000, "hold")   # via rclpy
    for bad in (b"", b"\x00\x01\x00\x00", data[:20], b"\x00\x01\x00\x00" + b"\xff" * 40):
        with pytest.raises(cv.MessageError, match="undecodable time shift"):
            cdr.shift_from_cdr(bad)
        with pytest.raises(cv.MessageError, match="undecodable acceleration"):
            cdr.accel_from_cdr(bad)


def _rclpy_odom_fields(data: bytes) -> tuple[int, str, list[float]]:
    """The reference: what rclpy's own deserialiser reads from serialised Odometry."""
    msg = deserialize_message(data, Odometry)
    p, v = msg.pose.pose.position, msg.twist.twist.linear
    return cv.time_to_ns(msg.header.stamp), msg.header.frame_id, [p.x, p.y, p.z, v.x, v.y, v.z]


def test_odometry_read_in_place_is_what_rclpy_deserialises() -> None:
    """odom_from_cdr reads stamp, frame and state from the CDR bytes as rclpy's deserialiser does,
    bit for bit, whatever the frame names' lengths (they move the doubles' alignment) and the
    covariance; bytes in another encoding or layout go through rclpy, and bytes nothing can
    decode are a MessageError."""
    rng = np.random.default_rng(7)
    for frame, child in (("eci", "deputy"), ("eci", "chief"), ("map", ""), ("", "c"), ("earth_fixed", "ab")):
        for stamp in (0, 5, 1_735_689_600_123_456_789, 2**31 * 10**9 - 1):
            x = rng.normal(size=6) * [7000, 7000, 7000, 7, 7, 7]
            msg = cv.odom_msg(x, stamp, child, np.diag(rng.uniform(0, 1e-6, 6)))
            msg.header.frame_id = frame
            data = serialize_message(msg)
            stamp_read, frame_read, x_si = cdr.odom_from_cdr(data)
            ref = _rclpy_odom_fields(data)
            assert (stamp_read, frame_read) == ref[:2]
            assert np.array_equal(x_si, ref[2]) and x_si.dtype == np.float64
            padded = data + b"\x00" * 4   # padding a transport may add at the end: still in place
            assert cdr.odom_from_cdr(padded)[1] == frame
    data = serialize_message(cv.odom_msg(X, 42, "deputy"))
    # Another layout than Odometry's (here: longer) is left to rclpy, which reads what it can.
    stamp, frame, x_si = cdr.odom_from_cdr(data + b"\x00" * 16)
    assert (stamp, frame) == (42, "eci") and np.array_equal(x_si, _rclpy_odom_fields(data)[2])
    for bad in (b"", b"\x00\x01\x00\x00", data[:60], data[:-8], b"\x00\x01\x00\x00" + b"\xff" * 712,
                b"\x00\x00\x00\x00" + data[4:]):
        with pytest.raises(cv.MessageError, match="undecodable odometry"):
            cdr.odom_from_cdr(bad)


def test_acceleration_round_trip_and_limits() -> None:
    u = np.array([3.1e-4, -2.2e-4, 1.23456789e-4])
    msg = cv.accel_msg(u, 5)
    np.testing.assert_array_equal(cv.accel_from_msg(msg, 5e-4), through_si(u))
    assert cv.time_to_ns(msg.header.stamp) == 5
    with pytest.raises(cv.MessageError, match="exceeds the thrust limit"):
        cv.accel_from_msg(cv.accel_msg([6e-4, 0, 0], 0), 5e-4)
    bad = cv.accel_msg(u, 0)
    bad.accel.linear.z = float("nan")
    with pytest.raises(cv.MessageError, match="non-finite"):
        cv.accel_from_msg(bad, 5e-4)


def test_time_shift_crosses_exactly() -> None:
    stamp = 1735689600 * 10**9 + 60 * 10**9
    for tau in (-7.564323426, -1e-9, 0.0, -599.999999999):
        got_stamp, got_tau, source = cv.shift_from_msg(cv.time_shift_msg(stamp, tau, "bisect"), Side.BEHIND)
        assert (got_stamp, got_tau, source) == (stamp, tau, "bisect")
        assert cv.shift_from_msg(cv.time_shift_msg(stamp, -tau, "nn"), Side.AHEAD) == (stamp, -tau, "nn")
    with pytest.raises(cv.MessageError, match="whole number of nanoseconds"):
        cv.time_shift_msg(stamp, -7.5643234261, "nn")
    msg = cv.time_shift_msg(stamp, 0.0, "x")
    msg.time_ref = cv.ns_to_time(stamp + 1)
    with pytest.raises(cv.MessageError, match="<= 0 \\(mission.approach behind\\)"):
        cv.shift_from_msg(msg, Side.BEHIND)
    assert cv.shift_from_msg(msg, Side.AHEAD)[1] == 1e-9
    msg.time_ref = cv.ns_to_time(stamp - 1)
    with pytest.raises(cv.MessageError, match=">= 0 \\(mission.approach ahead\\)"):
        cv.shift_from_msg(msg, Side.AHEAD)


def test_diagnostic_values_round_trip_floats_exactly() -> None:
    arr = cv.diagnostic("sim_node", "warn", "step", 42, {"k": 3, "u": np.array([1e-4 / 3, -0.0, 2.5]),
                                                          "h": float("nan"), "x": 0.1 + 0.2})
    (st,) = arr.status
    assert st.level == b"\x01" and cv.time_to_ns(arr.header.stamp) == 42
    v = cv.diagnostic_values(st)
    np.testing.assert_array_equal(cv.floats(v["u"]), [1e-4 / 3, -0.0, 2.5])
    assert float(v["x"]) == 0.1 + 0.2 and np.isnan(float(v["h"])) and v["k"] == "3"


def test_cdr_stamp_of_serialised_messages() -> None:
    stamp = 1735689600 * 10**9 + 987654321
    for msg in (cv.odom_msg(X, stamp, "chief"), cv.clock_msg(stamp), cv.accel_msg([0, 0, 0], stamp),
                cv.time_shift_msg(stamp, -1.0, "hold"), cv.diagnostic("n", "ok", "m", stamp)):
        assert cdr.cdr_stamp_ns(serialize_message(msg)) == stamp
    with pytest.raises(cv.MessageError):
        cdr.cdr_stamp_ns(b"\x00\x01\x00")
    # a MarkerArray is stamped by its first marker; an empty one has no stamp
    shapes = SceneBuilder(load_config(), 6).moving(np.array([1.0, 2.0, 3.0]), None)
    arr = serialize_message(cv.markers_msg(shapes, stamp))
    assert cdr.cdr_stamp_ns(arr, "visualization_msgs/msg/MarkerArray") == stamp
    with pytest.raises(cv.MessageError):
        cdr.cdr_stamp_ns(serialize_message(cv.markers_msg([], stamp)), "visualization_msgs/msg/MarkerArray")


def test_scene_and_telemetry_messages() -> None:
    """Shapes in km become markers in m in frame lvlh; the telemetry's names and values as given."""
    from visualization_msgs.msg import Marker

    cfg = load_config()
    builder = SceneBuilder(cfg, 6)
    (bodies,) = cv.markers_msg(builder.moving(np.array([1.0, -2.0, 0.5]), np.array([0.0, 3.0, 0.0])), 7).markers
    assert bodies.header.frame_id == "lvlh" and bodies.type == Marker.SPHERE_LIST
    assert cv.time_to_ns(bodies.header.stamp) == 7 and len(bodies.colors) == 2
    assert [(p.x, p.y, p.z) for p in bodies.points] == [(1000.0, -2000.0, 500.0), (0.0, 3000.0, 0.0)]
    cone, port, sphere = cv.markers_msg(builder.constraints(port_axis_lvlh(X, Side.BEHIND)[0]), 7).markers
    assert cone.type == Marker.TRIANGLE_LIST and len(cone.points) % 3 == 0
    assert sphere.scale.x == pytest.approx(2 * cfg.constraints.gamma1_km * 1e3)
    assert port.type == Marker.ARROW and len(port.points) == 2
    # the simulator's serialised scene is the bytes of fresh messages, step after step: a growing
    # path, the bodies before and after the first shift, the constraints as the axis turns
    stream = cdr.MarkersCdr()
    for k in range(13):
        shapes = builder.moving(np.array([k, 1.0, 2.0]), np.array([0.0, -k, 0.0]) if k else None)
        trail = builder.trail(k, np.array([1.0 + k, 2.0 * k, 0.5]), last=k == 12)
        shapes += [trail] if trail is not None else []
        turned = builder.constraints(port_axis_lvlh(X, Side.BEHIND)[0] + [0.0, 0.02 * k, 0.0], force=True)
        for group in (shapes, turned):
            assert stream(group, 100 + k) == cdr.exact_cdr(cv.markers_msg(group, 100 + k),
                                                           "visualization_msgs/msg/MarkerArray")
    # a step of the simulator's stream: the target where the scene's geometry puts it
    from cikan_ros.ros.scene_stream import SceneStream
    from cikan_ros.scene import virtual_target_lvlh
    from cikan_ros.tsg import Predictor

    pred = Predictor.from_config(cfg)
    x_c = pred.orbit.state(500.0)
    x_d = pred.orbit.state(400.0)
    (_, telemetry), (_, arr), *_ = SceneStream(cfg, pred).step(50, 123, 500.0, x_c, x_d, np.zeros(3), -60.0)
    telemetry, arr = deserialize_message(telemetry, JointState), deserialize_message(arr, MarkerArray)
    target = arr.markers[0].points[1]
    np.testing.assert_allclose([target.x, target.y, target.z],
                               virtual_target_lvlh(pred.orbit, x_c, 500.0, -60.0)[:3] * 1e3, rtol=1e-12)
    assert dict(zip(telemetry.name, telemetry.position))["tau"] == -60.0
    msg = cv.telemetry_msg(["a", "b"], [1.5, float("nan")], 9)
    assert list(msg.name) == ["a", "b"] and msg.position[0] == 1.5 and np.isnan(msg.position[1])


def test_schemas_parse_with_rosbags_and_hashes_match_installed_json() -> None:
    from rosbags.typesys import get_types_from_msg

    text = schema_text("nav_msgs/msg/Odometry")
    parts = text.split("=" * 80 + "\n")
    names = [p.splitlines()[0].removeprefix("MSG: ") for p in parts[1:]]
    assert set(names) >= {"std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/PoseWithCovariance",
                          "geometry_msgs/Pose", "geometry_msgs/Point", "geometry_msgs/Quaternion",
                          "geometry_msgs/TwistWithCovariance", "geometry_msgs/Twist", "geometry_msgs/Vector3"}
    assert len(names) == len(set(names))
    types = get_types_from_msg(parts[0], "nav_msgs/msg/Odometry")
    assert "nav_msgs/msg/Odometry" in types
    share = Path(sys.prefix) / "share"
    data = json.loads((share / "sensor_msgs/msg/TimeReference.json").read_text())
    assert type_hash("sensor_msgs/msg/TimeReference") == data["type_hashes"][0]["hash_string"]


def test_qos_profile_in_rosbag2_v9_form() -> None:
    d = qos_dict(QOS_STREAM)
    assert (d["history"], d["depth"], d["reliability"], d["durability"]) == ("keep_last", 4000, "reliable",
                                                                            "volatile")
    assert d["deadline"] == d["lifespan"] == {"sec": 0, "nsec": 0}   # rclpy's "default" durations
    assert d["liveliness"] == "system_default" and d["avoid_ros_namespace_conventions"] is False


def test_every_qos_kind_of_the_topic_table_has_its_profile() -> None:
    """The table names kinds, graph builds them: the streams deep and volatile, the announcements
    latched (a reader that joins later gets the last one)."""
    from rclpy.qos import DurabilityPolicy

    assert set(QOS_PROFILES) == set(QOS_KINDS) == {t.qos for t in TOPICS.values()}
    for name, topic in TOPICS.items():
        durability = qos_for(name).durability
        assert durability == (DurabilityPolicy.TRANSIENT_LOCAL if topic.qos == "latched" else DurabilityPolicy.VOLATILE)
    assert qos_for("/tsg/governor").depth == 1 and qos_for("/tsg/time_shift").depth == 4000


def test_bag_writer_flushed_bag_survives_a_crash(tmp_path: Path) -> None:
    """Files as a SIGKILL after a flush leaves them (copied before close) read with both readers;
    messages written out of stamp order are served in order."""
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    bag = tmp_path / "bag"
    writer = BagWriter(bag)
    writer.add_topic("/clock", "rosgraph_msgs/msg/Clock", [qos_dict(QOS_STREAM)])
    order = [5, 3, 4, 1, 2, 9, 8, 7, 6]
    for n, i in enumerate(order):
        writer.write("/clock", serialize_message(cv.clock_msg(i * 10**9)), i * 10**9)
        if n == 4:
            writer.flush()
    shutil.copytree(bag, tmp_path / "crashed")
    writer.close()
    for path, expected in ((tmp_path / "crashed", [1, 2, 3, 4, 5]), (bag, list(range(1, 10)))):
        with AnyReader([path]) as reader:
            got = [t // 10**9 for _, t, _ in reader.messages()]
            assert got == expected and reader.message_count == len(expected)
        with open(next(path.glob("*.mcap")), "rb") as f:
            assert sorted(m.log_time // 10**9 for _, _, m in make_reader(f).iter_messages()) == expected
    with pytest.raises(FileExistsError):
        BagWriter(bag)


def test_bag_writer_flushing_in_the_background_writes_the_same_file(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A flush in its own thread (the recorder's): messages written while it runs are held, then
    written in arrival order; another flush meanwhile does nothing; the closed file is byte for
    byte the one flushing in place gives, and reads back with rosbags."""
    import threading

    from rosbags.highlevel import AnyReader

    def fill(writer: BagWriter, gate: threading.Event | None) -> None:
        writer.add_topic("/clock", "rosgraph_msgs/msg/Clock", [qos_dict(QOS_STREAM)])
        for i in (5, 3, 4, 1, 2):
            writer.write("/clock", serialize_message(cv.clock_msg(i * 10**9)), i * 10**9)
        writer.flush()
        for i in (9, 8, 7, 6):
            writer.write("/clock", serialize_message(cv.clock_msg(i * 10**9)), i * 10**9)
            if gate is not None:
                writer.flush()      # while the first flush runs: nothing
        if gate is not None:
            assert len(writer._held) == 4 and writer.flushed["/clock"] == 0   # held, the flush not done
            gate.set()
        writer.close()

    fill(BagWriter(tmp_path / "in_place"), None)
    gate = threading.Event()
    background = BagWriter(tmp_path / "background", background=True)
    flush = background._flush
    monkeypatch.setattr(background, "_flush", lambda: (gate.wait(30.0), flush()))
    fill(background, gate)
    files = [next((tmp_path / name).glob("*.mcap")).read_bytes() for name in ("in_place", "background")]
    assert files[0] == files[1]
    with AnyReader([tmp_path / "background"]) as reader:
        assert [t // 10**9 for _, t, _ in reader.messages()] == list(range(1, 10))


def test_bag_writer_packs_message_indexes_into_the_librarys_bytes(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """The chunks' message indexes packed in one call (bag_writer._PackedMessageIndex, what every
    flush and the close write) give the file mcap's own MessageIndex.write gives, byte for byte,
    over two topics, three chunks and messages out of stamp order; and packing did happen (an
    mcap that moved its chunk builder would silently fall back: this says so)."""
    from cikan_ros.ros import bag_writer

    def fill(name: str) -> bytes:
        writer = BagWriter(tmp_path / name)
        writer.add_topic("/clock", "rosgraph_msgs/msg/Clock", [qos_dict(QOS_STREAM)])
        writer.add_topic("/tsg/time_shift", "sensor_msgs/msg/TimeReference", [qos_dict(QOS_STREAM)])
        for chunk in range(3):
            for i in (5, 3, 4, 1, 2, 9, 8, 7, 6):
                t = (chunk * 10 + i) * 10**9
                writer.write("/clock", serialize_message(cv.clock_msg(t)), t)
                if i % 3 == 0:
                    writer.write("/tsg/time_shift", cdr.time_shift_cdr(t, -0.5 * i, "bisect"), t + 1)
            if chunk < 2:
                writer.flush()
        writer.close()
        return next((tmp_path / name).glob("*.mcap")).read_bytes()

    packed = []
    write = bag_writer._PackedMessageIndex.write
    monkeypatch.setattr(bag_writer._PackedMessageIndex, "write", lambda self, s: (packed.append(1), write(self, s)))
    ours = fill("packed")
    assert len(packed) == 6   # two topics' indexes in each of three chunks
    monkeypatch.setattr(bag_writer, "_pack_message_indexes", lambda writer: None)
    assert fill("library") == ours


def test_bag_writer_provisional_end_is_what_finish_of_a_deep_copy_writes(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """After each flush the file ends in a provisional trailer (DataEnd, summary, Footer, magic):
    ``finish`` of a shallow copy of mcap's writer (bag_writer._provisional_trailer) writes the
    bytes ``finish`` of a deep copy writes, flush after flush (the summary offsets and chunk
    indexes growing), the writer left as it was (the closed files equal too); and mcap reads
    each provisional file with the messages flushed so far."""
    from mcap.reader import make_reader

    from cikan_ros.ros import bag_writer

    def fill(name: str) -> list[bytes]:
        writer = BagWriter(tmp_path / name)
        writer.add_topic("/clock", "rosgraph_msgs/msg/Clock", [qos_dict(QOS_STREAM)])
        writer.add_topic("/tsg/time_shift", "sensor_msgs/msg/TimeReference", [qos_dict(QOS_STREAM)])
        files = []
        for chunk in range(3):
            for i in (3, 1, 2):
                t = (chunk * 10 + i) * 10**9
                writer.write("/clock", serialize_message(cv.clock_msg(t)), t)
                writer.write("/tsg/time_shift", cdr.time_shift_cdr(t, -0.5 * i, "bisect"), t + 1)
            writer.flush()
            files.append(writer.file.read_bytes())
        writer.close()
        return files + [writer.file.read_bytes()]

    ours = fill("shallow")
    for k, data in enumerate(ours[:-1]):
        summary = make_reader(io.BytesIO(data)).get_summary()
        assert summary.statistics.message_count == 6 * (k + 1) and len(summary.chunk_indexes) == k + 1
    monkeypatch.setattr(bag_writer, "_FINISH_WRITES", ("_Writer__no_such_state",))   # the deep copy
    assert fill("deep") == ours


def test_bag_writer_closes_a_chunk_every_chunk_bytes(tmp_path: Path) -> None:
    """``BagWriter(path, chunk_bytes)`` flushes by itself once that many message bytes are
    unflushed (the recorder's ``recorder.chunk_bytes``): 100 clock messages of 12 bytes in
    256-byte chunks are 4 chunks of 22 messages (264 bytes) and one of 12 at close; 0 flushes
    only when asked."""
    from mcap.reader import make_reader

    for chunk_bytes, chunks in ((256, [22] * 4 + [12]), (0, [100])):
        writer = BagWriter(tmp_path / f"bag{chunk_bytes}", chunk_bytes)
        writer.add_topic("/clock", "rosgraph_msgs/msg/Clock", [qos_dict(QOS_STREAM)])
        data = serialize_message(cv.clock_msg(10**9))
        assert len(data) == 12
        for k in range(100):
            writer.write("/clock", data, (k + 1) * 10**9)
        writer.close()
        with open(writer.file, "rb") as f:
            summary = make_reader(f).get_summary()
        sizes = [(c.message_end_time - c.message_start_time) // 10**9 + 1 for c in summary.chunk_indexes]
        assert sizes == chunks and sum(sizes) == 100


def test_bag_writer_a_failed_background_flush_is_raised_where_the_bag_is_used(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    writer = BagWriter(tmp_path / "bag", background=True)
    writer.add_topic("/clock", "rosgraph_msgs/msg/Clock", [qos_dict(QOS_STREAM)])
    writer.write("/clock", serialize_message(cv.clock_msg(10**9)), 10**9)

    def full() -> None:
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(writer, "_flush", full)
    writer.flush()
    with pytest.raises(OSError, match="No space left"):
        writer.settle()
    writer.close()   # closes all the same
    assert writer.closed


def test_bag_writer_as_a_context_manager_closes_the_bag_on_an_exception(tmp_path: Path) -> None:
    """``with BagWriter(...)``: an exception inside the block leaves a closed, complete bag of what
    was written (no flush asked for), read back with rosbags and mcap; the exception propagates."""
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    bag = tmp_path / "bag"

    class Stop(Exception):
        pass

    with pytest.raises(Stop):
        with BagWriter(bag) as writer:
            writer.add_topic("/clock", "rosgraph_msgs/msg/Clock", [qos_dict(QOS_STREAM)])
            for i in (1, 2, 3):
                writer.write("/clock", serialize_message(cv.clock_msg(i * 10**9)), i * 10**9)
            raise Stop
    assert writer.closed
    with AnyReader([bag]) as reader:
        assert [t for _, t, _ in reader.messages()] == [10**9, 2 * 10**9, 3 * 10**9]
    with open(next(bag.glob("*.mcap")), "rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None and summary.statistics.message_count == 3   # the full summary
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["message_count"] == 3 and meta["duration"]["nanoseconds"] == 2 * 10**9
    with BagWriter(tmp_path / "empty") as empty:   # and a block that ends normally
        pass
    assert empty.closed and (tmp_path / "empty" / "metadata.yaml").exists()


_TEXT = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x85\u2028\u2029"), max_size=60)


@settings(max_examples=40, deadline=None)
@given(custom=st.dictionaries(_TEXT, _TEXT, max_size=4),
       counts=st.lists(st.integers(0, 10**6), min_size=0, max_size=3),
       times=st.tuples(st.integers(0, 2**62), st.integers(0, 2**40)))
def test_bag_writer_metadata_text_is_the_documents_yaml(tmp_path_factory: pytest.TempPathFactory,
                                                         custom: dict[str, str], counts: list[int],
                                                         times: tuple[int, int]) -> None:
    """metadata.yaml is composed from cached topic entries (BagWriter.metadata_text): PyYAML
    reads it as the document itself (metadata_info), with the topics' QoS profiles, counts and
    any custom data (quotes, colons, newlines, non-ASCII), the same as a whole-document dump."""
    topics = [("/clock", "rosgraph_msgs/msg/Clock", QOS_STREAM), ("/tsg/governor",
               "diagnostic_msgs/msg/DiagnosticStatus", QOS_PROFILES["latched"]),
              ("/deputy/odom", "nav_msgs/msg/Odometry", QOS_STREAM)][:len(counts)]
    writer = BagWriter(tmp_path_factory.mktemp("meta") / "bag", custom_data=custom)
    for (topic, type_name, qos), n in zip(topics, counts):
        writer.add_topic(topic, type_name, [qos_dict(qos)])
        writer.flushed[topic] = n
    writer.metadata_text()   # the caches filled, then the counts and the custom data change
    writer.flushed = {t: n + 1 for t, n in writer.flushed.items()}
    writer.custom_data["cikan_ros.governor"] = "conventional -> exec: 'x'"
    writer.flushed_times = [times[0], times[0] + times[1]]
    doc = {"rosbag2_bagfile_information": writer.metadata_info()}
    text = writer.metadata_text()
    assert yaml.safe_load(text) == doc == yaml.safe_load(yaml.safe_dump(doc, sort_keys=False))
    assert doc["rosbag2_bagfile_information"]["custom_data"]["cikan_ros.governor"] == "conventional -> exec: 'x'"
    assert [e["message_count"] for e in doc["rosbag2_bagfile_information"]["topics_with_message_count"]] \
        == [n + 1 for n in counts]
    writer.close()


def test_parameters_declared_with_descriptions_and_validated(ros_env: int) -> None:
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    desc = parameter_descriptions()
    assert desc["orbit.a_km"] == "chief semi-major axis [paper]"
    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_env)
    try:
        node = rclpy.create_node("p", context=ctx, parameter_overrides=[
            Parameter("tsg.tolerance_s", value=1e-4), Parameter("mission.duration_s", value=3600)])
        cfg = declare_config(node)
        assert cfg.tsg.tolerance_s == 1e-4 and cfg.mission.duration_s == 3600.0
        assert cfg.control.q_diag == (10.0, 10.0, 10.0, 1.0, 1.0, 1.0)
        (d,) = node.describe_parameters(["orbit.a_km"])
        assert d.description == "chief semi-major axis [paper]" and d.read_only
        node.destroy_node()
        bad = rclpy.create_node("q", context=ctx, parameter_overrides=[Parameter("orbit.e", value=1.5)])
        with pytest.raises(ConfigError, match="orbit.e"):
            declare_config(bad)
        bad.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_a_wait_deadline_fires_once_per_missed_wait_and_then_keeps_the_lost_pace(ros_env: int) -> None:
    """WaitDeadline (the simulator's and the controller's deadlines, checked by free-running
    timers): a wait that is never answered misses once, no sooner than its deadline; the next
    wait, the peer presumed gone, misses no sooner than the lost deadline; a wait that is stopped
    never misses; :meth:`heard` gives the full deadline back. Judged by the order of events and
    lower bounds of time only."""
    import time

    import rclpy
    from rclpy.context import Context
    from rclpy.task import Future

    from cikan_ros.ros.graph import WaitDeadline, make_executor

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_env)
    try:
        node = rclpy.create_node("deadline", context=ctx)
        executor = make_executor(ctx)
        executor.add_node(node)
        misses: list[tuple[float, bool]] = []
        done = Future()

        def on_miss() -> None:
            misses.append((time.perf_counter(), wait.lost))
            if len(misses) == 1:
                wait.start()      # the next step's wait, with the peer presumed gone
            else:
                done.set_result(True)

        wait = WaitDeadline(node, 0.2, 0.04, on_miss)
        t0 = time.perf_counter()
        wait.start(t0)
        executor.spin_until_future_complete(done, timeout_sec=60.0)
        assert done.done() and len(misses) == 2 and not wait.waiting
        (t1, lost1), (t2, lost2) = misses
        assert t1 - t0 >= 0.2 and t2 - t1 >= 0.04 and lost1 and lost2
        wait.heard()
        assert not wait.lost and wait.deadline_s == 0.2
        # a wait answered in time (stopped) never misses, however long the executor runs
        wait.start()
        wait.stop()
        later = Future()
        node.create_timer(0.6, lambda: later.set_result(True))
        executor.spin_until_future_complete(later, timeout_sec=60.0)
        assert len(misses) == 2
        executor.shutdown()
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_dropped_event_handlers_leave_the_wait_set_and_messages_still_flow(ros_env: int) -> None:
    """drop_event_handlers (a ready node under the SingleThreadedExecutor): every QoS event
    handler of the node's endpoints (the matched callbacks and rclpy's default incompatible-QoS
    and -type ones) leaves the node's waitables and the endpoints' lists; messages still go from
    the publisher to the subscription through the executor, and the node is destroyed cleanly."""
    import rclpy
    from rclpy.context import Context
    from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.task import Future
    from std_msgs.msg import String

    from cikan_ros.ros.graph import drop_event_handlers

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_env)
    try:
        node = rclpy.create_node("events", context=ctx)
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        received = Future()
        pub = node.create_publisher(String, "chatter", 10,
                                    event_callbacks=PublisherEventCallbacks(matched=lambda _s: None))
        got: list[str] = []
        node.create_subscription(String, "chatter", lambda m: (got.append(m.data), received.set_result(True)), 10,
                                 event_callbacks=SubscriptionEventCallbacks(matched=lambda _s: None))
        handlers = [h for e in [*node.publishers, *node.subscriptions] for h in e.event_handlers]
        assert len(handlers) >= 6 and all(h in list(node.waitables) for h in handlers)
        assert drop_event_handlers(node) == len(handlers)
        assert not any(h in list(node.waitables) for h in handlers)
        assert all(not e.event_handlers for e in [*node.publishers, *node.subscriptions])
        node.create_timer(0.05, lambda: pub.publish(String(data="hello")))
        executor.spin_until_future_complete(received, timeout_sec=30.0)
        assert got and got[0] == "hello"
        executor.shutdown()
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_odometry_carries_the_state_covariance_in_si() -> None:
    """The navigation covariance (km^2, km^2/s^2) goes out as m^2 and m^2/s^2 in the position
    block of pose.covariance and the linear block of twist.covariance, and comes back."""
    cov = np.diag([1e-10, 2e-10, 3e-10, 1e-12, 2e-12, 3e-12])
    cov[0, 1] = cov[1, 0] = 5e-11
    msg = deserialize_message(serialize_message(cv.odom_msg(X, 0, "deputy", cov)), type(cv.odom_msg(X, 0, "d")))
    pose = np.array(msg.pose.covariance).reshape(6, 6)
    assert pose[0, 0] == pytest.approx(1e-4) and pose[0, 1] == pytest.approx(5e-5) and pose[3, 3] == 0.0
    np.testing.assert_allclose(cv.covariance_from_odom(msg), cov, rtol=1e-12)
    assert not np.any(np.array(cv.odom_msg(X, 0, "deputy").pose.covariance))  # none given: zeros


def test_a_reused_message_serialises_as_a_fresh_one():
    """OdometryCdr and AccelCdr refill a publisher's serialised message in place: after any
    earlier use each gives the same CDR bytes as rclpy's serialize_message of a message built
    afresh."""
    rng = np.random.default_rng(3)
    odom = {"chief": cdr.OdometryCdr("chief", False), "deputy": cdr.OdometryCdr("deputy", False)}
    odom_cov = {"chief": cdr.OdometryCdr("chief", True), "deputy": cdr.OdometryCdr("deputy", True)}
    accel = cdr.AccelCdr()
    for stamp in (1_700_000_000_123_456_789, 1_700_000_010_000_000_000, 5):
        x = rng.normal(size=6) * [7000, 7000, 7000, 7, 7, 7]
        cov = rng.normal(size=(6, 6)) * 1e-7    # any sign: -0.0 of a zeroed covariance too
        u = rng.normal(size=3) * 1e-4
        for child, pad in (("chief", slice(30, 36)), ("deputy", slice(31, 36))):
            # The same bytes but the alignment padding after child_frame_id, which rclpy leaves
            # uninitialised (OdometryCdr: zeros).
            def fresh(*cov_km: np.ndarray) -> bytearray:
                data = bytearray(serialize_message(cv.odom_msg(x, stamp, child, *cov_km)))
                data[pad] = bytes(pad.stop - pad.start)
                return data
            assert odom[child](x, stamp) == fresh()
            for c in (cov, 0.0 * cov):
                assert odom_cov[child](x, stamp, c) == fresh(c)
        with pytest.raises(ValueError, match="covariance"):
            odom["chief"](x, stamp, cov)
        assert accel(u, stamp) == serialize_message(cv.accel_msg(u, stamp))   # "eci": no padding


def test_messages_written_whole_are_the_bytes_of_the_messages() -> None:
    """What the nodes publish every step, written straight to CDR (clock, time shift, diagnostic,
    telemetry, moving bodies, path), is byte for byte rosbags' serialisation of the message convert
    builds (the bytes a publisher sends, which rosbags reads), and rclpy reads it back as that
    message; the templates refilled step after step stay so."""
    rng = np.random.default_rng(5)
    keys = ["t_s", "tau", "h1", "h3", "r_km"]
    telemetry, bodies = cdr.TelemetryCdr(keys), cdr.MarkersCdr()
    builder = SceneBuilder(load_config(), 6)
    for k, stamp in enumerate((1_700_000_000_123_456_789, 5, 1_700_000_010_000_000_000, 0)):
        assert cdr.clock_cdr(stamp) == cdr.exact_cdr(cv.clock_msg(stamp), "rosgraph_msgs/msg/Clock")
        assert deserialize_message(cdr.clock_cdr(stamp), Clock) == cv.clock_msg(stamp)
        for tau, source in ((-12.5, "hold"), (0.0, "verify-zero"), (3.000000001, "nn+bisect"), (-1e-9, "")):
            data = cdr.time_shift_cdr(stamp, tau, source)
            assert data == cdr.exact_cdr(cv.time_shift_msg(stamp, tau, source), "sensor_msgs/msg/TimeReference")
            assert deserialize_message(data, TimeReference) == cv.time_shift_msg(stamp, tau, source)
            assert cdr.shift_from_cdr(data) == (stamp, stamp + round(tau * 1e9), source)
        values = {"k": k, "event": "step", "u_kmps2": rng.normal(size=3) * 1e-4, "h3_kmps": float("nan"),
                  "between_violations": k % 2, "latency_ms": float(rng.uniform()), "note": "héllo"}
        for name, level, text, vals in (("sim_node", "ok", "step", values), ("controller_node", "warn", "x", {}),
                                        ("governor_node", "error", "failed: ünïcode", {"k": "v"})):
            data = cdr.diagnostic_cdr(name, level, text, stamp, vals)
            fresh = cv.diagnostic(name, level, text, stamp, vals)
            assert data == cdr.exact_cdr(fresh, "diagnostic_msgs/msg/DiagnosticArray")
            # (compared as text: the messages' own == is field by field, and NaN != NaN)
            assert str(deserialize_message(data, DiagnosticArray)) == str(fresh)
        row = rng.normal(size=len(keys))
        row[k % len(keys)] = np.nan
        data = telemetry(row, stamp)
        assert data == cdr.exact_cdr(cv.telemetry_msg(keys, row, stamp), "sensor_msgs/msg/JointState")
        back = deserialize_message(data, JointState)
        assert list(back.name) == keys and cv.time_to_ns(back.header.stamp) == stamp
        np.testing.assert_array_equal(back.position, row)
        for target in (rng.normal(size=3), None):    # two layouts: with and without a virtual target
            shapes = builder.moving(rng.normal(size=3) * 100.0, target)
            data = bodies(shapes, stamp)
            fresh = cv.markers_msg(shapes, stamp)
            assert data == cdr.exact_cdr(fresh, "visualization_msgs/msg/MarkerArray")
            # (ColorRGBA is float32 on the wire: compared after rclpy's own round trip)
            assert deserialize_message(data, MarkerArray) == deserialize_message(serialize_message(fresh), MarkerArray)
    # a path of any length, a sphere, several markers in one array: the points spliced between
    # the fixed parts of one layout's template
    sphere = Shape("dot", 1, "sphere", np.array([[1.0, 2.0, 3.0]]), 0.5, (1.0, 0.0, 0.0, 1.0))
    for n in (1, 2, 7, 240):
        path = Shape("path", 0, "line_strip", rng.normal(size=(n, 3)) * 50.0, 0.3, (0.1, 0.2, 0.3, 1.0))
        for shapes in ([path], [path, sphere, *builder.moving(np.ones(3), -np.ones(3)), path]):
            assert bodies(shapes, 9 + n) == cdr.exact_cdr(cv.markers_msg(shapes, 9 + n),
                                                          "visualization_msgs/msg/MarkerArray")
    with pytest.raises(ValueError, match="cube"):
        bodies([Shape("box", 0, "cube", np.zeros((1, 3)), 0.3, (0.1, 0.2, 0.3, 1.0))], 9)
    with pytest.raises(ValueError, match="at least one point"):
        bodies([Shape("path", 0, "line_strip", np.empty((0, 3)), 0.3, (0.1, 0.2, 0.3, 1.0))], 9)
    with pytest.raises(cv.MessageError, match="nanoseconds"):
        cdr.time_shift_cdr(5, 0.1 + 1e-12, "bisect")

