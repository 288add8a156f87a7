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

import numpy as np
from nav_msgs.msg import Odometry
from numpy.typing import ArrayLike, NDArray
from rclpy.serialization import deserialize_message, serialize_message

from ..units import km_to_m
from .convert import NS_PER_S, MessageError, odom_msg, time_to_ns

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


def odom_from_cdr(data: bytes) -> tuple[int, str, NDArray]:
    """(header.stamp as absolute ns, header.frame_id, [position (m); linear velocity (m/s)]) of a
    serialised nav_msgs/Odometry, as rclpy's deserialiser reads them (the same floats).

    Read in place for little-endian CDR of Odometry's layout (a received message costs ~3 us
    instead of rclpy's ~36 us for the whole nested message); anything else (another encoding, a
    length that does not add up) goes through rclpy's ``deserialize_message``, and MessageError
    when that fails too."""
    try:
        if data[:2] != _CDR_LE:
            raise ValueError("not little-endian CDR")
        sec, nsec = _TIME.unpack_from(data, 4)
        frame, _end = _cdr_string(data, 12)
        _end, pos = _doubles_at(data, 2)
        if not 0 <= len(data) - (pos + 8 * _ODOM_DOUBLES) < 8:
            raise ValueError("length does not match the layout")
        x_si = np.array(_VEC3.unpack_from(data, pos) + _VEC3.unpack_from(data, pos + 8 * _ODOM_TWIST))
        return sec * NS_PER_S + nsec, frame.decode(), x_si
    except (ValueError, struct.error, UnicodeDecodeError):
        pass
    try:
        msg = deserialize_message(bytes(data), Odometry)
    except Exception as exc:  # rclpy's RMWError: not an Odometry at all
        raise MessageError(f"undecodable odometry ({len(data)} bytes): {exc}") from None
    p, v = msg.pose.pose.position, msg.twist.twist.linear
    return time_to_ns(msg.header.stamp), msg.header.frame_id, np.array([p.x, p.y, p.z, v.x, v.y, v.z])


class OdometryCdr:
    """The serialised :func:`odom_msg` of one publisher (little-endian CDR, the bytes rclpy's
    ``serialize_message`` gives for the message), refilled in place step after step and published
    raw: converting the nested Python message to C at publish costs rclpy more than the rest of
    the publish. ``covariance``: whether the topic carries one (always, or never)."""

    def __init__(self, child_frame: str, covariance: bool) -> None:
        self.buf = bytearray(serialize_message(odom_msg(np.zeros(6), 0, child_frame,
                                                        np.zeros((6, 6)) if covariance else None)))
        end, self.pos = _doubles_at(self.buf, 2)
        # The alignment padding before the doubles: zeros (rclpy leaves whatever was in memory).
        self.buf[end:self.pos] = bytes(self.pos - end)
        self.covariance = covariance

    def __call__(self, x_km: ArrayLike, stamp_ns: int, cov_km: ArrayLike | None = None) -> bytes:
        """The bytes of ``odom_msg(x_km, stamp_ns, child_frame, cov_km)``."""
        if (cov_km is not None) != self.covariance:
            raise ValueError(f"this topic's odometry {'carries' if self.covariance else 'has no'} covariance")
        buf, pos = self.buf, self.pos
        _TIME.pack_into(buf, 4, *divmod(int(stamp_ns), NS_PER_S))
        x_m = km_to_m(x_km)
        _VEC3.pack_into(buf, pos, *x_m[:3])
        _VEC3.pack_into(buf, pos + 8 * _ODOM_TWIST, *x_m[3:])
        if cov_km is not None:
            cov = np.asarray(cov_km, dtype=float) * 1e6  # km^2 -> m^2
            for i in range(3):   # row i of the position block; of the linear-velocity block
                _VEC3.pack_into(buf, pos + 8 * (_ODOM_POSE_COV + 6 * i), *cov[i, :3])
                _VEC3.pack_into(buf, pos + 8 * (_ODOM_TWIST_COV + 6 * i), *cov[3 + i, 3:])
        return bytes(buf)


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
