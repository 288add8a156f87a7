"""Message <-> domain conversions: the only place where ROS messages meet library values (with
:mod:`cikan_ros.ros.cdr`, which reads and writes some of them serialised, in place).

Library side: km, km/s, km/s^2 in ECI, times as whole nanoseconds since the mission epoch or
seconds (``ns / 1e9``). Message side (REP 103): m, m/s, m/s^2, frame ``eci``, stamps as absolute
UTC ``builtin_interfaces/Time``. Receivers call :func:`cikan_ros.units.m_to_km` on what senders
produced with :func:`cikan_ros.units.km_to_m`, exactly as the offline loop does through
``through_si``, so both see bit-identical numbers.

Decoders raise :class:`MessageError` (a :class:`StateError`) naming what is wrong with a message;
nodes turn it into a diagnostic and reject the message.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import AccelStamped, Point
from nav_msgs.msg import Odometry
from numpy.typing import ArrayLike, NDArray
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from ..config import Side
from ..errors import StateError
from ..scene import Shape
from ..units import km_to_m, m_to_km, ns_to_seconds, seconds_to_ns

#: Inertial frame of every pose, twist and acceleration in the graph.
FRAME_ECI = "eci"
#: The chief's LVLH frame of the scene markers (:mod:`cikan_ros.scene`).
FRAME_LVLH = "lvlh"
NS_PER_S = 1_000_000_000


class MessageError(StateError):
    """A received message is non-finite, out of range or malformed."""


# -- time ---------------------------------------------------------------------------------------
def ns_to_time(ns: int) -> Time:
    """Absolute nanoseconds since 1970 (UTC) -> builtin_interfaces/Time (exact)."""
    sec, nsec = divmod(int(ns), NS_PER_S)
    return Time(sec=sec, nanosec=nsec)


def time_to_ns(stamp: Any) -> int:
    """builtin_interfaces/Time -> absolute nanoseconds (exact integer)."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def clock_msg(ns: int) -> Clock:
    """rosgraph_msgs/Clock at absolute time ``ns``."""
    return Clock(clock=ns_to_time(ns))


class Timeline:
    """Mission time: absolute stamps <-> library time t (s since the epoch) and step index k.

    ``epoch_ns`` is the mission epoch (UTC, ns), ``period_ns`` the control period T_c.
    """

    def __init__(self, epoch_unix_s: float, period_s: float) -> None:
        self.epoch_ns = seconds_to_ns(epoch_unix_s)
        self.period_ns = seconds_to_ns(period_s)

    def stamp_ns(self, k: int) -> int:
        """Absolute stamp of control step k."""
        return self.epoch_ns + k * self.period_ns

    def seconds(self, stamp_ns: int) -> float:
        """Library time t (s since epoch) of an absolute stamp: the same float the offline loop uses."""
        return ns_to_seconds(stamp_ns - self.epoch_ns)

    def step(self, stamp_ns: int) -> int:
        """Control step index of a stamp; raises MessageError if the stamp is off the T_c grid."""
        k, rem = divmod(stamp_ns - self.epoch_ns, self.period_ns)
        if rem or k < 0:
            raise MessageError(f"stamp {stamp_ns} ns is not a control step of this mission "
                               f"(epoch {self.epoch_ns} ns, period {self.period_ns} ns)")
        return int(k)


# -- states -------------------------------------------------------------------------------------
def _finite(values: NDArray, what: str) -> NDArray:
    if not np.isfinite(values).all():
        raise MessageError(f"{what} has non-finite components: {values.tolist()}")
    return values


def set_stamp(stamp: Time, ns: int) -> None:
    """Set a builtin_interfaces/Time in place to absolute nanoseconds (exact)."""
    stamp.sec, stamp.nanosec = divmod(int(ns), NS_PER_S)


def odom_msg(x_km: ArrayLike, stamp_ns: int, child_frame: str, cov_km: ArrayLike | None = None) -> Odometry:
    """nav_msgs/Odometry of an ECI state [r (km); v (km/s)]: position in m, velocity in m/s.

    The orientation is the identity, so the child frame's axes are ECI's and the twist (expressed
    in the child frame, as nav_msgs asks) is the ECI velocity. ``cov_km`` (6, 6; km^2, km^2/s^2):
    the state's covariance, written in m^2 and m^2/s^2 into the position block of the pose
    covariance and the linear block of the twist covariance (orientation and angular rate are
    not estimated: their blocks stay 0). A publisher that sends one every step serialises it
    with :class:`cikan_ros.ros.cdr.OdometryCdr` instead.
    """
    x_m = km_to_m(x_km)
    msg = Odometry()
    msg.header.frame_id = FRAME_ECI
    msg.child_frame_id = child_frame
    msg.pose.pose.orientation.w = 1.0
    set_stamp(msg.header.stamp, stamp_ns)
    p = msg.pose.pose.position
    p.x, p.y, p.z = (float(v) for v in x_m[:3])
    v = msg.twist.twist.linear
    v.x, v.y, v.z = (float(w) for w in x_m[3:])
    if cov_km is not None:
        cov = np.asarray(cov_km, dtype=float) * 1e6  # km^2 -> m^2
        pose = np.zeros((6, 6))
        twist = np.zeros((6, 6))
        pose[:3, :3] = cov[:3, :3]
        twist[:3, :3] = cov[3:, 3:]
        msg.pose.covariance = [float(c) for c in pose.ravel()]
        msg.twist.covariance = [float(c) for c in twist.ravel()]
    return msg


def covariance_from_odom(msg: Odometry) -> NDArray:
    """The state covariance (6, 6; km^2, km^2/s^2) an Odometry message carries (position block of
    the pose covariance, linear block of the twist covariance; cross terms are not carried)."""
    out = np.zeros((6, 6))
    out[:3, :3] = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)[:3, :3]
    out[3:, 3:] = np.asarray(msg.twist.covariance, dtype=float).reshape(6, 6)[:3, :3]
    return out * 1e-6


def state_from_odom(frame_id: str, x_si: ArrayLike) -> NDArray:
    """ECI state [r (km); v (km/s)] of an Odometry's ``header.frame_id`` and its position and
    linear velocity [m; m/s] (:func:`cikan_ros.ros.cdr.odom_from_cdr`); MessageError if not ECI,
    non-finite or degenerate."""
    if frame_id != FRAME_ECI:
        raise MessageError(f"odometry frame must be {FRAME_ECI!r}, got {frame_id!r}")
    x = m_to_km(_finite(np.array(x_si, dtype=float), "odometry"))
    if math.sqrt(x[:3] @ x[:3]) < 1.0:
        raise MessageError(f"odometry position is within 1 km of Earth's centre: {x[:3].tolist()} km")
    return x


# -- commands -----------------------------------------------------------------------------------
def accel_msg(u_kmps2: ArrayLike, stamp_ns: int) -> AccelStamped:
    """geometry_msgs/AccelStamped (linear, m/s^2, ECI) of an acceleration in km/s^2 (a publisher
    that sends one every step serialises it with :class:`cikan_ros.ros.cdr.AccelCdr` instead)."""
    u = km_to_m(u_kmps2)
    msg = AccelStamped()
    msg.header.frame_id = FRAME_ECI
    set_stamp(msg.header.stamp, stamp_ns)
    a = msg.accel.linear
    a.x, a.y, a.z = (float(w) for w in u)
    return msg


def accel_from_msg(msg: AccelStamped, u_max_kmps2: float) -> NDArray:
    """Commanded acceleration (km/s^2) of an AccelStamped (see :func:`accel_from_si`)."""
    a = msg.accel.linear
    return accel_from_si(msg.header.frame_id, [a.x, a.y, a.z], u_max_kmps2)


def accel_from_si(frame_id: str, a_si: ArrayLike, u_max_kmps2: float) -> NDArray:
    """Commanded acceleration (km/s^2) of an AccelStamped's ``header.frame_id`` and linear
    acceleration (m/s^2; :func:`cikan_ros.ros.cdr.accel_from_cdr`); MessageError if non-finite,
    in another frame, or above the thrust limit (beyond rounding)."""
    if frame_id != FRAME_ECI:
        raise MessageError(f"acceleration frame must be {FRAME_ECI!r}, got {frame_id!r}")
    u = m_to_km(_finite(np.array(a_si, dtype=float), "acceleration command"))
    if float(np.linalg.norm(u)) > u_max_kmps2 * (1.0 + 1e-9):
        raise MessageError(f"acceleration command |u| = {np.linalg.norm(u) * 1e3:.6g} m/s^2 exceeds "
                           f"the thrust limit {u_max_kmps2 * 1e3:g} m/s^2")
    return u


# -- time shift ---------------------------------------------------------------------------------
def shift_ns(tau_s: float) -> int:
    """tau (s) as whole nanoseconds; MessageError when it is not on that grid (every verified
    shift is), so that the receiver's ``ns_to_seconds(time_ref - stamp)`` is the same float."""
    tau_ns = seconds_to_ns(tau_s)
    if ns_to_seconds(tau_ns) != tau_s:
        raise MessageError(f"time shift {tau_s!r} s is not a whole number of nanoseconds")
    return tau_ns


def time_shift_msg(stamp_ns: int, tau_s: float, source: str) -> TimeReference:
    """sensor_msgs/TimeReference: header.stamp = t_k, time_ref = t_k + tau, source = decision path.

    tau must lie on the whole-nanosecond grid (every verified shift does), so the receiver's
    ``ns_to_seconds(time_ref - stamp)`` is the same float.
    """
    tau_ns = shift_ns(tau_s)
    msg = TimeReference()
    msg.header.stamp = ns_to_time(stamp_ns)
    msg.time_ref = ns_to_time(stamp_ns + tau_ns)
    msg.source = source
    return msg


def shift_from_msg(msg: TimeReference, side: Side) -> tuple[int, float, str]:
    """(stamp ns, tau s, source) of a TimeReference (see :func:`shift_from_times`)."""
    return shift_from_times(time_to_ns(msg.header.stamp), time_to_ns(msg.time_ref), msg.source, side)


def shift_from_times(stamp_ns: int, time_ref_ns: int, source: str, side: Side) -> tuple[int, float, str]:
    """(stamp ns, tau s, source) of a TimeReference's header.stamp, time_ref (absolute ns) and
    source (:func:`cikan_ros.ros.cdr.shift_from_cdr`); MessageError unless tau lies on the
    mission's ``side`` of 0 (BEHIND: tau <= 0, the deputy behind the chief; AHEAD: tau >= 0)."""
    tau_ns = time_ref_ns - stamp_ns
    if side * tau_ns < 0:
        raise MessageError(f"time shift must be {'<=' if side < 0 else '>='} 0 "
                           f"(mission.approach {side.approach}), got {tau_ns} ns")
    return stamp_ns, ns_to_seconds(tau_ns), source


# -- diagnostics --------------------------------------------------------------------------------
LEVELS = {"ok": DiagnosticStatus.OK, "warn": DiagnosticStatus.WARN,
          "error": DiagnosticStatus.ERROR, "stale": DiagnosticStatus.STALE}


def status_text(value: Any) -> str:
    """Diagnostic value text: floats as repr (round-trips exactly), sequences space-separated."""
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, (list, tuple, np.ndarray)):
        return " ".join(status_text(v) for v in value)
    return str(value)


def diagnostic(name: str, level: str, message: str, stamp_ns: int,
               values: Mapping[str, Any] | None = None) -> DiagnosticArray:
    """A DiagnosticArray with one status; values become KeyValue strings (floats exactly,
    :func:`status_text`). What a node publishes every step goes out serialised instead
    (:func:`cikan_ros.ros.cdr.diagnostic_cdr`, the same bytes)."""
    arr = DiagnosticArray()
    arr.header.stamp = ns_to_time(stamp_ns)
    arr.status = [_status(name, level, message, values)]
    return arr


def _status(name: str, level: str, message: str, values: Mapping[str, Any] | None) -> DiagnosticStatus:
    status = DiagnosticStatus(level=LEVELS[level], name=name, message=message, hardware_id="cikan_ros")
    status.values = [KeyValue(key=k, value=status_text(v)) for k, v in (values or {}).items()]
    return status


def governor_info(node: str, values: Mapping[str, Any]) -> DiagnosticStatus:
    """The governor's announcement (/tsg/governor): message = the governor's name, ``values`` with
    at least ``governor`` (the same name) and, for a model, ``model`` and ``weights_sha256``."""
    return _status(node, "ok", str(values["governor"]), values)


def governor_from_info(status: Any) -> dict[str, str]:
    """What an announcement says: ``{"governor": name, ...}`` (a bare status: its message)."""
    values = diagnostic_values(status)
    values.setdefault("governor", status.message)
    return values


def diagnostic_values(status: Any) -> dict[str, str]:
    """KeyValue pairs of a DiagnosticStatus (any message object with ``values``) as a dict."""
    return {kv.key: kv.value for kv in status.values}


def floats(text: str) -> NDArray:
    """Parse a space-separated float list written by :func:`diagnostic`."""
    return np.array([float(w) for w in text.split()])


# -- telemetry and scene -----------------------------------------------------------------------
def telemetry_msg(keys: list[str], values: ArrayLike, stamp_ns: int) -> JointState:
    """The telemetry of one step as sensor_msgs/JointState: ``name`` the dictionary's keys,
    ``position`` the values in the dictionary's units (:mod:`cikan_ros.telemetry`; NaN where a
    constraint is not evaluated). The simulator sends it serialised
    (:class:`cikan_ros.ros.cdr.TelemetryCdr`, the same bytes)."""
    msg = JointState(name=list(keys))
    msg.header.stamp = ns_to_time(stamp_ns)
    msg.position = np.asarray(values, dtype=float).tolist()
    return msg


_MARKER_TYPES = {"sphere": Marker.SPHERE, "sphere_list": Marker.SPHERE_LIST, "line_strip": Marker.LINE_STRIP,
                 "triangle_list": Marker.TRIANGLE_LIST, "arrow": Marker.ARROW}


def marker_msg(shape: Shape, stamp_ns: int) -> Marker:
    """visualization_msgs/Marker (m, frame ``lvlh``) of a scene shape (km); persistent (lifetime
    0): a later marker of the same ``ns``/``id`` replaces it. The scale is the shape's size (m)
    times the kind's factors (:data:`cikan_ros.ros.cdr.SCALE_FACTORS`: the simulator sends its
    scene serialised from this message, :class:`cikan_ros.ros.cdr.MarkersCdr`); a sphere's centre
    is its pose, any other kind's points are its points."""
    m = Marker()
    m.header.frame_id = FRAME_LVLH
    m.header.stamp = ns_to_time(stamp_ns)
    m.ns, m.id, m.type, m.action = shape.ns, int(shape.ident), _MARKER_TYPES[shape.kind], Marker.ADD
    m.pose.orientation.w = 1.0
    m.color = ColorRGBA(r=shape.color[0], g=shape.color[1], b=shape.color[2], a=shape.color[3])
    pts = km_to_m(shape.points)
    size = float(shape.size) * 1e3
    if shape.kind == "sphere":
        m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(v) for v in pts[0])
        m.scale.x = m.scale.y = m.scale.z = size
        return m
    if shape.kind == "arrow":
        m.scale.x, m.scale.y, m.scale.z = size, 2.0 * size, 3.0 * size
    elif shape.kind == "line_strip":
        m.scale.x = size
    elif shape.kind == "sphere_list":
        m.scale.x = m.scale.y = m.scale.z = size
    else:
        m.scale.x = m.scale.y = m.scale.z = 1.0
    m.colors = [ColorRGBA(r=c[0], g=c[1], b=c[2], a=c[3]) for c in shape.colors]
    m.points = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in pts.tolist()]
    return m


def markers_msg(shapes: list[Shape], stamp_ns: int) -> MarkerArray:
    """visualization_msgs/MarkerArray of scene shapes (see :func:`marker_msg`)."""
    return MarkerArray(markers=[marker_msg(s, stamp_ns) for s in shapes])
