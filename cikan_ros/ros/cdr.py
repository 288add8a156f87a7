"""Serialised messages (CDR, as rmw_fastrtps sends them), read and written in place, without
building the Python message: what a node does with a message every step (rclpy's deserialiser
builds the whole nested message, ~35 us for an Odometry; its publish converts one to C, ~30 us),
and the stamp the recorder logs a message at.

Little-endian CDR (XCDR1): a 4-byte encapsulation header (byte 1 = 0x01), then the fields; a
string is a uint32 length (with its NUL), the bytes and a NUL; a double is 8-aligned from the end
of the encapsulation header. Anything else is left to rclpy (rclpy is imported here, never in
:mod:`cikan_ros.ros.convert`, which the rclpy-free modules import).
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np
from geometry_msgs.msg import AccelStamped
from nav_msgs.msg import Odometry
from numpy.typing import ArrayLike, NDArray
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import TimeReference

from ..units import km_to_m
from .convert import NS_PER_S, MessageError, accel_msg, odom_msg, time_to_ns

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
    values = np.array([v for i in vectors for v in _VEC3.unpack_from(data, pos + 8 * i)])
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
    each publish costs rclpy more than the rest of the publish."""

    def __init__(self, msg: Any, strings: int) -> None:
        self.buf = bytearray(serialize_message(msg))
        end, self.pos = _doubles_at(self.buf, strings)
        # The alignment padding before the doubles: zeros (rclpy leaves whatever was in memory).
        self.buf[end:self.pos] = bytes(self.pos - end)

    def _stamp(self, stamp_ns: int) -> None:
        _TIME.pack_into(self.buf, 4, *divmod(int(stamp_ns), NS_PER_S))

    def _vec3(self, index: int, values: Any) -> None:
        """Three doubles from the ``index``-th double on."""
        _VEC3.pack_into(self.buf, self.pos + 8 * index, *values)


class OdometryCdr(_Refilled):
    """The serialised :func:`~cikan_ros.ros.convert.odom_msg` of one publisher, refilled in place
    (see :class:`_Refilled`). ``covariance``: whether the topic carries one (always, or never)."""

    def __init__(self, child_frame: str, covariance: bool) -> None:
        super().__init__(odom_msg(np.zeros(6), 0, child_frame, np.zeros((6, 6)) if covariance else None), 2)
        self.covariance = covariance

    def __call__(self, x_km: ArrayLike, stamp_ns: int, cov_km: ArrayLike | None = None) -> bytes:
        """The bytes of ``odom_msg(x_km, stamp_ns, child_frame, cov_km)``."""
        if (cov_km is not None) != self.covariance:
            raise ValueError(f"this topic's odometry {'carries' if self.covariance else 'has no'} covariance")
        self._stamp(stamp_ns)
        x_m = km_to_m(x_km)
        self._vec3(0, x_m[:3])
        self._vec3(_ODOM_TWIST, x_m[3:])
        if cov_km is not None:
            cov = np.asarray(cov_km, dtype=float) * 1e6  # km^2 -> m^2
            for i in range(3):   # row i of the position block; of the linear-velocity block
                self._vec3(_ODOM_POSE_COV + 6 * i, cov[i, :3])
                self._vec3(_ODOM_TWIST_COV + 6 * i, cov[3 + i, 3:])
        return bytes(self.buf)


class AccelCdr(_Refilled):
    """The serialised :func:`~cikan_ros.ros.convert.accel_msg` of one publisher, refilled in
    place (see :class:`_Refilled`)."""

    def __init__(self) -> None:
        super().__init__(accel_msg(np.zeros(3), 0), 1)

    def __call__(self, u_kmps2: ArrayLike, stamp_ns: int) -> bytes:
        """The bytes of ``accel_msg(u_kmps2, stamp_ns)``."""
        self._stamp(stamp_ns)
        self._vec3(0, km_to_m(u_kmps2))
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
