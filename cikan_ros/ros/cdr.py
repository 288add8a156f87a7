"""Serialised messages (CDR, as rmw_fastrtps sends them), read and written in place, without
building the Python message: what a node does with a message every step (rclpy's deserialiser
builds the whole nested message, ~35 us for an Odometry; its publish converts one to C, ~30 us),
and the stamp the recorder logs a message at.

Written every step, published raw: the states and the thrust (:class:`OdometryCdr`,
:class:`AccelCdr`, refilled in place), the clock (:func:`clock_cdr`), the time shift
(:func:`time_shift_cdr`), the per-step diagnostic (:func:`diagnostic_cdr`), the telemetry
(:class:`TelemetryCdr`) and the scene's moving bodies and path (:class:`MarkersCdr`). Each gives the bytes a
publisher sends for the message :mod:`cikan_ros.ros.convert` builds (tested field by field against
rclpy's deserialiser and byte for byte against rosbags' serialiser).

Little-endian CDR (XCDR1): a 4-byte encapsulation header (byte 1 = 0x01), then the fields; a
string is a uint32 length (with its NUL), the bytes and a NUL; a double is 8-aligned from the end
of the encapsulation header. Anything else is left to rclpy (rclpy is imported here, never in
:mod:`cikan_ros.ros.convert`, which the rclpy-free modules import).
"""

from __future__ import annotations

import functools
import struct
from typing import Any, Mapping, Sequence

import numpy as np
from geometry_msgs.msg import AccelStamped
from nav_msgs.msg import Odometry
from numpy.typing import ArrayLike, NDArray
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import TimeReference

from ..scene import Shape
from ..units import km_to_m
from .convert import (LEVELS, NS_PER_S, MessageError, accel_msg, markers_msg, odom_msg, shift_ns,
                      status_text, telemetry_msg, time_to_ns)

#: CDR (XCDR1) little-endian encapsulation: what rmw_fastrtps sends.
_CDR_LE = b"\x00\x01"
_TIME = struct.Struct("<iI")         # builtin_interfaces/Time: sec, nanosec
_LENGTH = struct.Struct("<I")
_VEC3 = struct.Struct("<3d")
#: Doubles of an Odometry after its child_frame_id: position 3, orientation 4, covariance 36
#: (from _ODOM_POSE_COV), twist linear 3 (from _ODOM_TWIST), angular 3, covariance 36 (from
#: _ODOM_TWIST_COV).
_ODOM_DOUBLES, _ODOM_POSE_COV, _ODOM_TWIST, _ODOM_TWIST_COV = 85, 7, 43, 49


def _cdr_string(data: bytes | bytearray, pos: int) -> tuple[bytes, int]:
    """A CDR string (uint32 length with the NUL, the bytes, NUL) at ``pos`` (4-aligned):
    (its bytes without the NUL, the position after it); ValueError if it does not fit."""
    (n,) = _LENGTH.unpack_from(data, pos)
    end = pos + 4 + n
    if n < 1 or end > len(data) or data[end - 1] != 0:
        raise ValueError("malformed string")
    return data[pos + 4:end - 1], end


def _doubles_at(data: bytes | bytearray, strings: int) -> tuple[int, int]:
    """(the end of the strings, where the doubles begin) in little-endian CDR of a message that
    starts with a Time and ``strings`` strings (a Header's frame_id, an Odometry's
    child_frame_id), then doubles (8-aligned from the end of the 4-byte encapsulation header);
    ValueError if a string does not fit."""
    pos = 12
    for _ in range(strings):
        pos = _cdr_string(data, (pos + 3) & ~3)[1]
    return pos, 4 + ((pos - 4 + 7) & ~7)


#: What says that bytes are not the layout read in place (then rclpy reads them).
_NOT_IN_PLACE = (ValueError, struct.error, UnicodeDecodeError)


def _stamped_doubles(data: bytes, strings: int, doubles: int, vectors: tuple[int, ...]) -> tuple[int, str, NDArray]:
    """In place: (header.stamp as absolute ns, header.frame_id, the 3 doubles from each index of
    ``vectors``, concatenated) of little-endian CDR of a message made of a Header, ``strings`` - 1
    more strings and ``doubles`` doubles (trailing padding allowed); ValueError if the bytes are
    anything else."""
    if data[:2] != _CDR_LE:
        raise ValueError("not little-endian CDR")
    sec, nsec = _TIME.unpack_from(data, 4)
    frame = _cdr_string(data, 12)[0]
    pos = _doubles_at(data, strings)[1]
    if not 0 <= len(data) - (pos + 8 * doubles) < 8:
        raise ValueError("length does not match the layout")
    values = np.array(sum((_VEC3.unpack_from(data, pos + 8 * i) for i in vectors), ()))
    return sec * NS_PER_S + nsec, frame.decode(), values


def _deserialised(data: bytes, msg_type: type, what: str) -> Any:
    """rclpy's deserialisation of ``data``; MessageError if it is not a ``msg_type`` at all."""
    try:
        return deserialize_message(bytes(data), msg_type)
    except Exception as exc:  # rclpy's RMWError
        raise MessageError(f"undecodable {what} ({len(data)} bytes): {exc}") from None


def odom_from_cdr(data: bytes) -> tuple[int, str, NDArray]:
    """(header.stamp as absolute ns, header.frame_id, [position (m); linear velocity (m/s)]) of a
    serialised nav_msgs/Odometry, as rclpy's deserialiser reads them (the same floats).

    Read in place for little-endian CDR of Odometry's layout (~3 us, against ~35 us for rclpy's
    whole nested message); anything else (another encoding, a length that does not add up) goes
    through rclpy's ``deserialize_message``, and MessageError when that fails too."""
    try:
        return _stamped_doubles(data, 2, _ODOM_DOUBLES, (0, _ODOM_TWIST))
    except _NOT_IN_PLACE:
        msg = _deserialised(data, Odometry, "odometry")
    p, v = msg.pose.pose.position, msg.twist.twist.linear
    return time_to_ns(msg.header.stamp), msg.header.frame_id, np.array([p.x, p.y, p.z, v.x, v.y, v.z])


def accel_from_cdr(data: bytes) -> tuple[int, str, NDArray]:
    """(header.stamp as absolute ns, header.frame_id, linear acceleration (m/s^2)) of a
    serialised geometry_msgs/AccelStamped, as :func:`odom_from_cdr` reads an Odometry."""
    try:
        return _stamped_doubles(data, 1, 6, (0,))
    except _NOT_IN_PLACE:
        msg = _deserialised(data, AccelStamped, "acceleration")
    a = msg.accel.linear
    return time_to_ns(msg.header.stamp), msg.header.frame_id, np.array([a.x, a.y, a.z])


def shift_from_cdr(data: bytes) -> tuple[int, int, str]:
    """(header.stamp, time_ref (absolute ns), source) of a serialised sensor_msgs/TimeReference,
    as :func:`odom_from_cdr` reads an Odometry (CDR: the Header, then time_ref 4-aligned, then
    the source string 4-aligned)."""
    try:
        if data[:2] != _CDR_LE:
            raise ValueError("not little-endian CDR")
        sec, nsec = _TIME.unpack_from(data, 4)
        pos = (_cdr_string(data, 12)[1] + 3) & ~3
        ref_sec, ref_nsec = _TIME.unpack_from(data, pos)
        source, end = _cdr_string(data, pos + 8)
        if not 0 <= len(data) - end < 4:
            raise ValueError("length does not match the layout")
        return sec * NS_PER_S + nsec, ref_sec * NS_PER_S + ref_nsec, source.decode()
    except _NOT_IN_PLACE:
        msg = _deserialised(data, TimeReference, "time shift")
    return time_to_ns(msg.header.stamp), time_to_ns(msg.time_ref), msg.source


class _Refilled:
    """A publisher's serialised message (little-endian CDR, the bytes rclpy's ``serialize_message``
    gives for ``msg``, which starts with a Time and ``strings`` strings and goes on with doubles),
    refilled in place step after step and published raw: converting the Python message to C at
    each publish costs rclpy more than the rest of the publish. ``doubles`` views the doubles."""

    def __init__(self, msg: Any, strings: int) -> None:
        self.buf = bytearray(serialize_message(msg))
        end, pos = _doubles_at(self.buf, strings)
        # The alignment padding before the doubles: zeros (rclpy leaves whatever was in memory).
        self.buf[end:pos] = bytes(pos - end)
        self.doubles = np.frombuffer(self.buf, dtype="<f8", count=(len(self.buf) - pos) // 8, offset=pos)

    def _stamp(self, stamp_ns: int) -> None:
        _TIME.pack_into(self.buf, 4, *divmod(int(stamp_ns), NS_PER_S))


class OdometryCdr(_Refilled):
    """The serialised :func:`~cikan_ros.ros.convert.odom_msg` of one publisher, refilled in place
    (see :class:`_Refilled`). ``covariance``: whether the topic carries one (always, or never)."""

    def __init__(self, child_frame: str, covariance: bool) -> None:
        super().__init__(odom_msg(np.zeros(6), 0, child_frame, np.zeros((6, 6)) if covariance else None), 2)
        self.covariance = covariance
        d = self.doubles
        self.position, self.velocity = d[:3], d[_ODOM_TWIST:_ODOM_TWIST + 3]
        # the position block of pose.covariance, the linear-velocity block of twist.covariance (6 x 6, row-major)
        self.pose_cov = d[_ODOM_POSE_COV:_ODOM_POSE_COV + 36].reshape(6, 6)[:3, :3]
        self.twist_cov = d[_ODOM_TWIST_COV:_ODOM_TWIST_COV + 36].reshape(6, 6)[:3, :3]

    def __call__(self, x_km: ArrayLike, stamp_ns: int, cov_km: ArrayLike | None = None) -> bytes:
        """The bytes of ``odom_msg(x_km, stamp_ns, child_frame, cov_km)``."""
        if (cov_km is not None) != self.covariance:
            raise ValueError(f"this topic's odometry {'carries' if self.covariance else 'has no'} covariance")
        self._stamp(stamp_ns)
        x_m = km_to_m(x_km)
        self.position[:] = x_m[:3]
        self.velocity[:] = x_m[3:]
        if cov_km is not None:
            cov = np.asarray(cov_km, dtype=float) * 1e6  # km^2 -> m^2
            self.pose_cov[:] = cov[:3, :3]
            self.twist_cov[:] = cov[3:, 3:]
        return bytes(self.buf)


class AccelCdr(_Refilled):
    """The serialised :func:`~cikan_ros.ros.convert.accel_msg` of one publisher, refilled in
    place (see :class:`_Refilled`)."""

    def __init__(self) -> None:
        super().__init__(accel_msg(np.zeros(3), 0), 1)
        self.linear = self.doubles[:3]

    def __call__(self, u_kmps2: ArrayLike, stamp_ns: int) -> bytes:
        """The bytes of ``accel_msg(u_kmps2, stamp_ns)``."""
        self._stamp(stamp_ns)
        self.linear[:] = km_to_m(u_kmps2)
        return bytes(self.buf)


#: Types whose serialised form starts with a sequence of stamped messages (not a Time): their
#: stamp is the first element's (CDR: the uint32 length, then that element's header).
_SEQUENCE_FIRST = {"visualization_msgs/msg/MarkerArray"}


def cdr_stamp_ns(data: bytes, type_name: str = "") -> int:
    """Stamp of a serialised message whose first field is a Time (a Header or rosgraph Clock), or,
    for a type of :data:`_SEQUENCE_FIRST` (``type_name``), of its first element.

    CDR: 4-byte encapsulation header (byte 1 = 0x01 little-endian), then int32 sec, uint32 nanosec
    (after the uint32 sequence length for a sequence; MessageError when it is empty).
    """
    offset = 4
    fmt_len = "<I" if len(data) > 1 and data[1] & 1 else ">I"
    if type_name in _SEQUENCE_FIRST:
        if len(data) < 8 or struct.unpack_from(fmt_len, data, 4)[0] == 0:
            raise MessageError(f"serialised {type_name} has no element to take a stamp from")
        offset = 8
    if len(data) < offset + 8:
        raise MessageError(f"serialised message of {len(data)} bytes is too short for a stamp")
    fmt = "<iI" if data[1] & 1 else ">iI"
    sec, nsec = struct.unpack_from(fmt, data, offset)
    return sec * NS_PER_S + nsec


# -- messages written whole, every step --------------------------------------------------------
_HEADER = b"\x00\x01\x00\x00"   # little-endian CDR encapsulation, no options
_EMPTY_STRING = _LENGTH.pack(1) + b"\x00"


def _put_string(out: bytearray, text: str) -> None:
    """Append a CDR string (4-aligned: the encapsulation header is 4 bytes, so absolute offsets
    align as the stream's do)."""
    out += bytes(-len(out) % 4)
    raw = text.encode()
    out += _LENGTH.pack(len(raw) + 1)
    out += raw
    out += b"\x00"


def clock_cdr(stamp_ns: int) -> bytes:
    """The bytes of ``convert.clock_msg(stamp_ns)`` (rosgraph_msgs/Clock)."""
    return _HEADER + _TIME.pack(*divmod(int(stamp_ns), NS_PER_S))


def _stamped(stamp_ns: int) -> bytearray:
    """The start of a message whose first field is a Header with an empty frame_id, padded to
    the 4-alignment of what follows it."""
    out = bytearray(clock_cdr(stamp_ns) + _EMPTY_STRING)
    out += bytes(-len(out) % 4)
    return out


def time_shift_cdr(stamp_ns: int, tau_s: float, source: str) -> bytes:
    """The bytes of ``convert.time_shift_msg(stamp_ns, tau_s, source)`` (sensor_msgs/TimeReference:
    Header with an empty frame_id, time_ref = t_k + tau, source); MessageError, as there, for a
    tau off the whole-nanosecond grid."""
    ref = int(stamp_ns) + shift_ns(tau_s)
    out = _stamped(stamp_ns)
    out += _TIME.pack(*divmod(ref, NS_PER_S))
    _put_string(out, source)
    return bytes(out)


def diagnostic_cdr(name: str, level: str, message: str, stamp_ns: int,
                   values: Mapping[str, Any] | None = None) -> bytes:
    """The bytes of ``convert.diagnostic(name, level, message, stamp_ns, values)``
    (diagnostic_msgs/DiagnosticArray with one status; the values' text as there)."""
    out = _stamped(stamp_ns)
    out += _LENGTH.pack(1)                      # one status
    out += LEVELS[level]                        # a byte (octet)
    for text in (name, message, "cikan_ros"):
        _put_string(out, text)
    values = values or {}
    out += bytes(-len(out) % 4)
    out += _LENGTH.pack(len(values))
    for key, value in values.items():
        _put_string(out, key)
        _put_string(out, status_text(value))
    return bytes(out)


@functools.lru_cache(maxsize=1)
def typestore() -> Any:
    """rosbags' type store of ROS 2 Jazzy (its CDR serialiser writes the exact bytes a publisher
    sends; rclpy's ``serialize_message`` appends stray bytes to some types, JointState and
    MarkerArray among them, which rosbags refuses: "CDR message size mismatch")."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def rosbags_message(msg: Any, store: Any) -> Any:
    """The rosbags message equal to an rclpy message, field by field."""
    cls = store.types[msg.__class__.__module__.split(".")[0] + "/msg/" + msg.__class__.__name__]
    fields = {}
    for name, kind in msg.get_fields_and_field_types().items():
        value = getattr(msg, name)
        if hasattr(value, "get_fields_and_field_types"):
            fields[name] = rosbags_message(value, store)
        elif kind.startswith("sequence<") and kind[9:-1] in ("double", "float", "int32", "uint32", "uint8"):
            fields[name] = np.asarray(value, dtype={"double": np.float64, "float": np.float32, "int32": np.int32,
                                                    "uint32": np.uint32, "uint8": np.uint8}[kind[9:-1]])
        elif isinstance(value, list) and value and hasattr(value[0], "get_fields_and_field_types"):
            fields[name] = [rosbags_message(v, store) for v in value]
        elif isinstance(value, list):
            fields[name] = list(value)
        elif kind == "octet" and isinstance(value, bytes):  # rclpy's byte: one bytes object
            fields[name] = value[0]
        else:
            fields[name] = value
    return cls(**fields)


def exact_cdr(msg: Any, type_name: str) -> bytes:
    """The CDR bytes a publisher sends for the rclpy message ``msg`` of ROS type ``type_name``
    (rosbags' serialiser; alignment padding zeros). ~20 us for a small message: for templates and
    occasional messages."""
    store = typestore()
    return bytes(store.serialize_cdr(rosbags_message(msg, store), type_name))


#: What a template's stamps and refilled doubles hold when it is made (found again in its bytes):
#: a stamp no mission has, and doubles far outside any mission's values, each template's distinct.
_STAMP_SENTINEL_NS = 0x5EADBEEF * NS_PER_S + 0x3ADBEEF1


def _sentinels(n: int, exponent: int) -> NDArray:
    """n distinct doubles 2^exponent (1 + i / 1024), exact in binary."""
    return np.ldexp(1.0 + np.arange(n) / 1024.0, exponent)


class _Template:
    """The exact bytes (:func:`exact_cdr`) of a message whose layout repeats from step to step
    (the same strings, the same sequence lengths), made once with sentinel values where the
    fields to refill are, then refilled in place: the stamps, and runs of doubles viewed as numpy
    arrays into the bytes."""

    def __init__(self, msg: Any, type_name: str) -> None:
        self.buf = bytearray(exact_cdr(msg, type_name))
        key = _TIME.pack(*divmod(_STAMP_SENTINEL_NS, NS_PER_S))
        self.stamps = [i for i in range(len(self.buf) - 7) if self.buf[i:i + 8] == key]

    def doubles(self, sentinels: NDArray) -> NDArray:
        """A writable view of the run of doubles made from ``sentinels`` (found exactly once)."""
        key = np.asarray(sentinels, dtype="<f8").tobytes()
        at = self.buf.find(key)
        if at < 0 or self.buf.find(key, at + 1) >= 0:
            raise ValueError("a template's sentinel doubles are not where one run of them should be")
        return np.frombuffer(self.buf, dtype="<f8", count=len(sentinels), offset=at)

    def stamp(self, stamp_ns: int) -> None:
        sec_nsec = divmod(int(stamp_ns), NS_PER_S)
        for at in self.stamps:
            _TIME.pack_into(self.buf, at, *sec_nsec)


class TelemetryCdr:
    """The bytes of ``convert.telemetry_msg(keys, values, stamp_ns)`` (sensor_msgs/JointState)
    for the keys given once, refilled in place."""

    def __init__(self, keys: Sequence[str]) -> None:
        marks = _sentinels(len(keys), 900)
        self.template = _Template(telemetry_msg(list(keys), marks, _STAMP_SENTINEL_NS), "sensor_msgs/msg/JointState")
        self.position = self.template.doubles(marks)

    def __call__(self, values: ArrayLike, stamp_ns: int) -> bytes:
        self.template.stamp(stamp_ns)
        self.position[:] = values
        return bytes(self.template.buf)


#: The shapes :class:`MarkersCdr` writes (every kind of :mod:`cikan_ros.scene`), with the factors
#: of their size in the marker's scale (``convert.marker_msg``): a sphere (its centre is the
#: marker's pose), a sphere list, a line strip (its width), a triangle list (scale 1) and an arrow.
SCALE_FACTORS = {"sphere": (1.0, 1.0, 1.0), "sphere_list": (1.0, 1.0, 1.0), "line_strip": (1.0,),
                 "triangle_list": (), "arrow": (1.0, 2.0, 3.0)}
REFILLED_KINDS = tuple(SCALE_FACTORS)


class _MarkerLayout:
    """The serialised MarkerArray of one layout of shapes, cut at each marker's points: fixed
    segments (refilled in place: stamps, scales, a sphere's centre) between which the points are
    spliced. A Point is 24 bytes, so whatever follows a marker's points keeps its alignment
    whatever their number (at least one)."""

    def __init__(self, shapes: Sequence[Shape]) -> None:
        marked, marks = [], []
        for i, s in enumerate(shapes):
            n = 1 if s.kind == "sphere" else max(1, len(s.points))
            size, pts = _sentinels(1, 700 + 4 * i), _sentinels(3 * n, 702 + 4 * i)
            marked.append(Shape(s.ns, s.ident, s.kind, pts.reshape(n, 3), float(size[0]), s.color, s.colors))
            marks.append((float(size[0]) * 1e3, km_to_m(pts).astype("<f8").tobytes()))
        whole = _Template(markers_msg(marked, _STAMP_SENTINEL_NS), "visualization_msgs/msg/MarkerArray")
        buf = bytes(whole.buf)
        self.factors = [np.array(SCALE_FACTORS[s.kind]) for s in shapes]
        cuts: list[tuple[int, int]] = []   # (where the points begin, their length) per spliced marker
        centres: dict[int, int] = {}       # a sphere's pose.position (absolute offset)
        scales: list[int] = []             # where each marker's scale is (absolute offset)
        for i, (s, (size, pts)) in enumerate(zip(shapes, marks)):
            scales.append(buf.find((size * self.factors[i]).astype("<f8").tobytes()) if len(self.factors[i]) else 0)
            at = buf.find(pts)
            if at < 0 or scales[-1] < 0:
                raise ValueError("a marker template's sentinel values are not where they should be")
            if s.kind == "sphere":
                centres[i] = at
            else:
                cuts.append((at, len(pts)))
        # Fixed segments: before the first spliced points, between them, after the last.
        bounds, pos = [], 0
        for at, length in cuts:
            bounds.append((pos, at))
            pos = at + length
        bounds.append((pos, len(buf)))
        self.segments = [bytearray(buf[a:b]) for a, b in bounds]

        def locate(offset: int) -> tuple[int, int]:
            for i, (a, b) in enumerate(bounds):
                if a <= offset < b:
                    return i, offset - a
            raise ValueError("a refilled field lies in spliced points")

        self.stamps = [locate(at) for at in whole.stamps]
        self.scale_views = [self._view(*locate(at), len(f)) if len(f) else None
                            for at, f in zip(scales, self.factors)]
        # A sphere's centre (its pose.position, 3 doubles) is refilled; spliced points are not.
        self.centres = {i: self._view(*locate(at), 3) for i, at in centres.items()}
        # The uint32 count of each spliced marker's points: the word just before them, or the one
        # before that when 4 bytes of alignment padding lie between.
        self.counts = []
        for at, length in cuts:
            word = at - 4 if _LENGTH.unpack_from(buf, at - 4)[0] == length // 24 else at - 8
            if _LENGTH.unpack_from(buf, word)[0] != length // 24:
                raise ValueError("a marker template's point count is not where it should be")
            self.counts.append(locate(word))

    def _view(self, seg: int, offset: int, n: int) -> NDArray:
        return np.frombuffer(self.segments[seg], dtype="<f8", count=n, offset=offset)

    def __call__(self, shapes: Sequence[Shape], stamp_ns: int) -> bytes:
        sec_nsec = divmod(int(stamp_ns), NS_PER_S)
        for seg, off in self.stamps:
            _TIME.pack_into(self.segments[seg], off, *sec_nsec)
        parts: list[bytes | bytearray] = [self.segments[0]]
        spliced = 0
        for i, shape in enumerate(shapes):
            if self.scale_views[i] is not None:
                self.scale_views[i][:] = float(shape.size) * 1e3 * self.factors[i]
            pts = km_to_m(np.asarray(shape.points, dtype=float))
            if shape.kind == "sphere":
                self.centres[i][:] = pts[0]
                continue
            if len(pts) == 0:
                raise ValueError(f"MarkersCdr writes {shape.kind} shapes of at least one point")
            seg, word = self.counts[spliced]
            _LENGTH.pack_into(self.segments[seg], word, len(pts))
            spliced += 1
            parts.append(pts.astype("<f8", copy=False).tobytes())
            parts.append(self.segments[spliced])
        return b"".join(parts)


class MarkersCdr:
    """The bytes of ``convert.markers_msg(shapes, stamp_ns)`` (visualization_msgs/MarkerArray)
    for shapes of :data:`REFILLED_KINDS` (one layout per list of names, kinds and colours, made
    on first use by :class:`_MarkerLayout`; any number of points): the simulator's scene, its
    moving bodies every step, its path every governor update period and its constraints."""

    #: The layouts made so far, shared by every instance of the process: a layout is a template
    #: (bytes with offsets), the same for every stream, and making one takes ~1-2 ms (rosbags'
    #: serialisation), so the simulator's warm-up makes them before the lockstep's first step does.
    layouts: dict[tuple, _MarkerLayout] = {}

    @staticmethod
    def layout(shapes: Sequence[Shape]) -> tuple:
        return tuple((s.ns, int(s.ident), s.kind, s.color, tuple(s.colors)) for s in shapes)

    def __call__(self, shapes: Sequence[Shape], stamp_ns: int) -> bytes:
        bad = [s.kind for s in shapes if s.kind not in REFILLED_KINDS]
        if bad:
            raise ValueError(f"MarkersCdr writes {', '.join(REFILLED_KINDS)} shapes, not {bad[0]}")
        key = self.layout(shapes)
        made = self.layouts.get(key)
        if made is None:
            made = self.layouts[key] = _MarkerLayout(shapes)
        return made(shapes, stamp_ns)
