"""A mission as recorded in a bag: rebuild the :class:`MissionResult` of a ROS run (read with
rosbags), so the ROS graph reports exactly the metrics of the offline loop.

Per step k (stamp t_k): x_d, x_c from the odometry; the thrust the simulator APPLIED (its
/diagnostics step record, exact floats; zero where it had no valid command); the shift in force
from /tsg/time_shift (held forward where the governor did not answer, as the controller does);
governor decisions (path, Verify calls, wall time) from the governor's /diagnostics records.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..config import Config
from ..constraints import margins
from ..errors import CikanError
from ..governor import PATH_INITIAL, UpdateRecord
from ..mission import MissionResult
from ..units import m_to_km, ns_to_seconds
from .convert import Timeline, diagnostic_values, floats, time_to_ns
from .graph import CHIEF_ODOM, DEPUTY_ODOM, DIAGNOSTICS, TIME_SHIFT


#: Integer values of the simulator's summary record.
_COUNTS = ("k", "steps", "deadline_misses", "rejected")


def read_bag(path: str | Path) -> dict[str, list[tuple[int, Any]]]:
    """Every message of a bag, decoded by rosbags, as ``{topic: [(log_time_ns, msg), ...]}``."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    out: dict[str, list[tuple[int, Any]]] = {}
    with AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    return out


def _state(msg: Any) -> np.ndarray:
    p, v = msg.pose.pose.position, msg.twist.twist.linear
    return m_to_km(np.array([p.x, p.y, p.z, v.x, v.y, v.z]))


def mission_from_bag(path: str | Path, cfg: Config, governor: str) -> tuple[MissionResult, dict[str, Any]]:
    """(MissionResult, the simulator's summary values) of a recorded lockstep mission."""
    msgs = read_bag(path)
    tl = Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
    deputy = {tl.step(time_to_ns(m.header.stamp)): _state(m) for _, m in msgs.get(DEPUTY_ODOM, [])}
    chief = {tl.step(time_to_ns(m.header.stamp)): _state(m) for _, m in msgs.get(CHIEF_ODOM, [])}
    if not deputy or sorted(deputy) != list(range(len(deputy))) or sorted(chief) != sorted(deputy):
        raise CikanError(f"bag {path}: the deputy/chief states do not cover steps 0..K without gaps")
    n = len(deputy)
    shifts: dict[int, float] = {}
    for _, m in msgs.get(TIME_SHIFT, []):
        stamp = time_to_ns(m.header.stamp)
        shifts[tl.step(stamp)] = ns_to_seconds(time_to_ns(m.time_ref) - stamp)
    u = np.zeros((n, 3))
    initial: UpdateRecord | None = None
    updates: list[tuple[int, UpdateRecord]] = []
    summary: dict[str, Any] = {}
    for _, arr in msgs.get(DIAGNOSTICS, []):
        for st in arr.status:
            v = diagnostic_values(st)
            if st.name == "sim_node" and v.get("event") == "step":
                u[int(v["k"])] = floats(v["u_kmps2"])
            elif st.name == "sim_node" and v.get("event") == "complete":
                summary = {k: x if k == "event" else int(x) if k in _COUNTS else float(x)
                           for k, x in v.items()}
            elif st.name == "governor_node" and v.get("event") == "update":
                rec = UpdateRecord(float(v["tau_s"]), v["path"], int(v["verify_calls"]), float(v["wall_s"]))
                if rec.path == PATH_INITIAL and initial is None:
                    initial = rec
                elif rec.path != PATH_INITIAL:
                    updates.append((int(v["k"]), rec))
    if initial is None:
        raise CikanError(f"bag {path}: no initial governor decision recorded")
    tau = np.empty(n)
    current = initial.tau_s
    for k in range(n):
        current = shifts.get(k, current)
        tau[k] = current
    x_d = np.array([deputy[k] for k in range(n)])
    x_c = np.array([chief[k] for k in range(n)])
    t = np.array([tl.seconds(tl.stamp_ns(k)) for k in range(n)])
    m = margins(x_d, x_c, u, cfg.constraints, cfg.control.u_max_kmps2)
    m.h2[-1] = math.nan  # no command is applied at the final instant
    updates.sort(key=lambda p: p[0])
    per_update = round(cfg.tsg.update_period_s / cfg.control.period_s)
    records = [replace(r, k=k // per_update, tau_prev=float(tau[k - 1])) for k, r in updates]
    result = MissionResult(cfg, governor, t, x_d, x_c, u, tau, m, initial,
                           np.array([t[k] for k, _ in updates]), records)
    return result, summary
