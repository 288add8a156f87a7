"""The bag reader: a mission as recorded in a bag (read with rosbags, an independent reader),
rebuilt into the :class:`MissionResult` of the offline loop, so the ROS graph reports exactly its
metrics; the checks of a recorded lockstep (lost, duplicated, off-grid messages); what the bag's
metadata carries (the configuration, the governors that flew). No rclpy: ``cikan report`` reads
bags without it. The bag writer is :mod:`cikan_ros.ros.bag_writer`.

The metrics are the core's (:meth:`MissionResult.metrics`, :func:`cikan_ros.mission.audit_shifts`):
:func:`recorded_metrics` hands them the rebuilt run. It lives here rather than in ``analysis/``
because the launcher (:mod:`cikan_ros.ros.launch`, below ``analysis/`` in the import order)
reports them too.

The typed topics are enough (any governor keeping the topic contract, docs/governor_contract.md). Per step
k (stamp t_k): x_d, x_c from the truth's odometry (/truth/*; a bag without them, recorded before
the truth had topics of its own, from the measured odometry), and the measured states the
governor saw from /deputy/odom and /chief/odom; the shift in force from /tsg/time_shift (the first
valid shift stamped t_k, held forward where none came, as the controller does; NaN before the
first); the applied thrust from /deputy/accel_cmd (the first valid command stamped t_k, zero
where none came, as the simulator does). The decisions are the shifts at the first step and at
every step an update was due, with their ``source`` as the path.

Optional extras, used when recorded: the simulator's /diagnostics step records (the thrust it
actually applied, exact floats, e.g. zero after a missed deadline, and the truth states
violating h1 or h3 between the samples, which the bag does not hold), the controller's hold
records (the shift it held when a shift came late), and governor_node's decision records
(Verify calls and wall time of each decision; without them these are unknown: NaN / None).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..config import Config, config_from_flat, load_config
from ..constraints import margins
from ..errors import CikanError
from ..governor import UpdateRecord
from ..learn.governor import nn_accept_rate
from ..mission import MissionResult, Schedule, audit_shifts
from ..tsg import Predictor
from ..units import m_to_km
from .convert import MessageError, Timeline, accel_from_msg, diagnostic_values, floats, shift_from_msg, time_to_ns
from .graph_spec import (ACCEL_CMD, CHIEF_ODOM, CLOCK, DEPUTY_ODOM, DIAGNOSTICS, SCENE_MARKERS, SCENE_TOPICS,
                         TELEMETRY, TIME_SHIFT, TRUTH_ACCEL, TRUTH_CHIEF, TRUTH_DEPUTY)


#: Integer values of the simulator's summary record.
_COUNTS = ("k", "steps", "deadline_misses", "rejected", "controller_holds")


def read_bag(path: str | Path, scene: bool = False) -> dict[str, list[tuple[int, Any]]]:
    """Every message of a bag, decoded by rosbags, as ``{topic: [(log_time_ns, msg), ...]}``; the
    telemetry and scene topics (:data:`~cikan_ros.ros.graph_spec.SCENE_TOPICS`, derived from the
    others and more than half the decoding time) only with ``scene``. CikanError (one line) if
    the bag cannot be read whole (:func:`read_bag_partial` reads what is readable of a damaged
    one)."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    out: dict[str, list[tuple[int, Any]]] = {}
    try:
        with AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
            conns = [c for c in reader.connections if scene or c.topic not in SCENE_TOPICS]
            for conn, t, raw in reader.messages(connections=conns):
                out.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    except AnyReaderError as exc:
        raise CikanError(f"bag {path} is unreadable: {exc}") from None
    return out


#: Topics of the states of every step (measured and true): a damaged bag is read up to the last
#: step all of them hold (:func:`read_bag_partial`).
STATE_TOPICS = (CHIEF_ODOM, DEPUTY_ODOM, TRUTH_CHIEF, TRUTH_DEPUTY)


def read_bag_partial(path: str | Path) -> tuple[dict[str, list[tuple[int, Any]]], str | None]:
    """(messages, what is missing) of a bag: :func:`read_bag`'s messages and None for a whole bag;
    for a damaged one (an MCAP file cut short: no summary, a torn last record) what mcap's stream
    reader gets from its start, up to the last step whose states every state topic holds, and a
    sentence saying what is missing. CikanError (one line) when nothing is readable."""
    try:
        return read_bag(path), None
    except CikanError as exc:
        damage = str(exc).split(": ", 1)[-1].rstrip(".")
    from mcap.stream_reader import StreamReader
    from mcap.records import Channel, Message, Schema
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    files = sorted(Path(path).glob("*.mcap"))
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    out: dict[str, list[tuple[int, Any]]] = {}
    if len(files) == 1:
        with open(files[0], "rb") as f:
            try:
                for rec in StreamReader(f, record_size_limit=1 << 30).records:
                    if isinstance(rec, Schema):
                        schemas[rec.id] = rec.name
                    elif isinstance(rec, Channel):
                        channels[rec.id] = (rec.topic, schemas[rec.schema_id])
                    elif isinstance(rec, Message):
                        topic, msgtype = channels[rec.channel_id]
                        out.setdefault(topic, []).append((rec.log_time, store.deserialize_cdr(rec.data, msgtype)))
            except Exception:  # noqa: BLE001 - whatever the torn end raises, what came before it stands
                pass
    states = [{t for t, _ in out.get(topic, [])} for topic in STATE_TOPICS if topic in out]
    common = sorted(set.intersection(*states)) if states else []
    if not common:
        raise CikanError(f"bag {path} is unreadable ({damage}) and holds no step's states before the damage")
    last = common[-1]
    kept = {topic: [(t, m) for t, m in msgs if t <= last] for topic, msgs in out.items()}
    read = sum(len(v) for v in kept.values())
    try:
        total = int(yaml.safe_load((Path(path) / "metadata.yaml").read_text())
                    ["rosbag2_bagfile_information"]["message_count"])
    except (OSError, TypeError, KeyError, ValueError, yaml.YAMLError):
        total = None
    of = f" of the {total} its metadata counts" if total else ""
    return kept, (f"the bag is damaged ({damage}): read {read} messages{of}, up to "
                  f"{(last - common[0]) / 1e9:g} s after its first state; the rest is missing")


#: The simulator's topics, published at every state t_0..t_K or step t_0..t_{K-1} whatever the
#: other nodes do: a bag that lacks one of their messages lost it.
SIM_TOPICS = (CLOCK, CHIEF_ODOM, DEPUTY_ODOM, TRUTH_CHIEF, TRUTH_DEPUTY, TRUTH_ACCEL)
#: Name of the simulator's per-step records in :func:`check_messages` (on /diagnostics).
SIM_STEPS = "/diagnostics (sim steps)"


def expected_stamps(n_steps: int) -> dict[str, int]:
    """Topic -> number of steps it carries a message for: the states of t_0..t_K, with their
    telemetry and scene markers, one shift and one command for each of t_0..t_{K-1}."""
    states = {t: n_steps + 1 for t in (CLOCK, CHIEF_ODOM, DEPUTY_ODOM, TRUTH_CHIEF, TRUTH_DEPUTY,
                                       TELEMETRY, SCENE_MARKERS)}
    return {**states, TIME_SHIFT: n_steps, ACCEL_CMD: n_steps, TRUTH_ACCEL: n_steps}


def _stamp_ns(topic: str, msg: Any) -> int:
    """The stamp of a recorded message: the clock's, a MarkerArray's first marker's (what the
    recorder logs it at), else its header's."""
    if topic == CLOCK:
        return time_to_ns(msg.clock)
    if topic == SCENE_MARKERS:
        return time_to_ns(msg.markers[0].header.stamp)
    return time_to_ns(msg.header.stamp)


def check_messages(msgs: dict[str, list[tuple[int, Any]]], cfg: Config, n_steps: int,
                   topics: tuple[str, ...] | None = None, scene: bool = False) -> dict[str, Any]:
    """Lost, duplicated and off-grid messages of a recorded lockstep mission of ``n_steps`` steps:
    each topic of ``topics`` (default all of :func:`expected_stamps`) holds one message for each
    of its stamps, none twice, none off the T_c grid, each logged at its own stamp; the
    simulator's /diagnostics holds one step record for each step. ``lost_on``: where. With
    ``scene`` the default topics include the telemetry and the scene markers (``msgs`` read by
    ``read_bag(path, scene=True)``)."""
    tl = Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
    expected = expected_stamps(n_steps)
    lost = dup = off = total = 0
    where: dict[str, list[int]] = {}
    for topic in topics or tuple(t for t in expected if scene or t not in SCENE_TOPICS):
        n = expected[topic]
        ks = []
        for log_time, m in msgs.get(topic, []):
            stamp = _stamp_ns(topic, m)
            try:
                k = tl.step(stamp)
            except MessageError:
                off += 1
                continue
            off += log_time != stamp   # the recorder logs every message at its own stamp
            ks.append(k)
        total += len(ks)
        missing = sorted(set(range(n)) - set(ks))
        lost += len(missing)
        if missing:
            where[topic] = missing
        dup += len(ks) - len(set(ks))
        off += sum(1 for k in ks if not 0 <= k < n)
    steps = [int(diagnostic_values(s)["k"]) for _, arr in msgs.get(DIAGNOSTICS, []) for s in arr.status
             if s.name == "sim_node" and diagnostic_values(s).get("event") == "step"]
    missing = sorted(set(range(n_steps)) - set(steps))
    lost += len(missing)
    if missing:
        where[SIM_STEPS] = missing
    dup += len(steps) - len(set(steps))
    total += sum(len(v) for t, v in msgs.items() if t not in expected)
    return {"steps": n_steps, "messages": total, "lost": lost, "duplicated": dup, "off_grid": off,
            "lost_on": ", ".join(f"{t} {len(ks)} (k {_ranges(ks)})" for t, ks in where.items())}


def _ranges(ks: list[int], most: int = 3) -> str:
    """Sorted step numbers as ranges: ``3, 7-9, 12``, the first ``most`` of them then ``...``."""
    runs: list[list[int]] = []
    for k in ks:
        if runs and k == runs[-1][1] + 1:
            runs[-1][1] = k
        else:
            runs.append([k, k])
    text = [f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:most]]
    return "; ".join(text) + ("; ..." if len(runs) > most else "")


def sim_summary(msgs: dict[str, list[tuple[int, Any]]]) -> dict[str, str] | None:
    """The values of the simulator's mission-complete record, or None if the bag lacks it."""
    for _, arr in msgs.get(DIAGNOSTICS, []):
        for st in arr.status:
            v = diagnostic_values(st)
            if st.name == "sim_node" and v.get("event") == "complete":
                return v
    return None


def _state(msg: Any) -> np.ndarray:
    p, v = msg.pose.pose.position, msg.twist.twist.linear
    return m_to_km(np.array([p.x, p.y, p.z, v.x, v.y, v.z]))


def _decision(tau_s: float, path: str, verify_calls: int = 0, wall_s: float = math.nan,
              cpu_s: float = math.nan) -> UpdateRecord:
    """One decision record (Verify calls, wall and CPU time unknown unless governor_node recorded
    them); its update index and tau_prev are set from the step it was applied at."""
    return UpdateRecord(tau_s, path, verify_calls, wall_s, cpu_s=cpu_s)


def _first_valid(msgs: list[tuple[int, Any]], tl: Timeline, decode: Any) -> dict[int, Any]:
    """{k: decoded value} of the first message stamped t_k that decodes (others are rejected)."""
    out: dict[int, Any] = {}
    for _, m in msgs:
        try:
            k = tl.step(time_to_ns(m.header.stamp))
            value = decode(m)
        except MessageError:
            continue
        out.setdefault(k, value)
    return out


def mission_from_bag(path: str | Path, cfg: Config, governor: str,
                     msgs: dict[str, list[tuple[int, Any]]] | None = None) -> tuple[MissionResult, dict[str, Any]]:
    """(MissionResult, the simulator's summary values + ``missing_shifts``) of a recorded lockstep
    mission. ``missing_shifts``: steps 0..K-1 with no valid time shift (the controller held).
    ``msgs``: the bag's messages if already read (:func:`read_bag`)."""
    msgs = read_bag(path) if msgs is None else msgs
    tl = Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
    def states(topic: str) -> dict[int, np.ndarray]:
        return {tl.step(time_to_ns(m.header.stamp)): _state(m) for _, m in msgs.get(topic, [])}

    seen_d, seen_c = states(DEPUTY_ODOM), states(CHIEF_ODOM)
    has_truth = TRUTH_DEPUTY in msgs
    deputy, chief = (states(TRUTH_DEPUTY), states(TRUTH_CHIEF)) if has_truth else (seen_d, seen_c)
    for d, c, what in ((deputy, chief, "true"), (seen_d, seen_c, "measured")):
        if not d or sorted(d) != list(range(len(d))) or sorted(c) != sorted(d):
            raise CikanError(f"bag {path}: the {what} deputy/chief states do not cover steps 0..K "
                             "without gaps")
    n = len(deputy)
    u_max = cfg.control.u_max_kmps2
    limit = cfg.thrust_limit_kmps2
    shifts = _first_valid(msgs.get(TIME_SHIFT, []), tl, lambda m: shift_from_msg(m, cfg.side)[1:])
    commands = _first_valid(msgs.get(ACCEL_CMD, []), tl, lambda m: accel_from_msg(m, u_max))
    if has_truth:  # the thrust as applied (the simulator's step records below take precedence)
        commands = _first_valid(msgs.get(TRUTH_ACCEL, []), tl, lambda m: accel_from_msg(m, 2.0 * limit))
    applied: dict[int, np.ndarray] = {}
    between: dict[int, int] = {}
    held: dict[int, float] = {}
    recorded: dict[int, UpdateRecord] = {}
    summary: dict[str, Any] = {}
    for _, arr in msgs.get(DIAGNOSTICS, []):
        for st in arr.status:
            v = diagnostic_values(st)
            if st.name == "sim_node" and v.get("event") == "step":
                applied[int(v["k"])] = floats(v["u_kmps2"])
                if "between_violations" in v:
                    between[int(v["k"])] = int(v["between_violations"])
            elif st.name == "sim_node" and v.get("event") == "complete":
                summary = {k: x if k == "event" else int(x) if k in _COUNTS else float(x)
                           for k, x in v.items()}
            elif st.name == "controller_node" and v.get("event") == "hold":
                held[tl.step(time_to_ns(arr.header.stamp))] = float(v["tau_s"])
            elif st.name == "governor_node" and v.get("event") == "update":
                recorded.setdefault(int(v["k"]), _decision(float(v["tau_s"]), v["path"],
                                                           int(v["verify_calls"]), float(v["wall_s"]),
                                                           float(v.get("cpu_s", "nan"))))
    schedule = Schedule(cfg)
    tau = np.full(n, math.nan)
    u = np.zeros((n, 3))
    current = math.nan
    initial: UpdateRecord | None = None
    updates: list[tuple[int, UpdateRecord]] = []
    for k in range(n):
        u[k] = applied.get(k, commands.get(k, u[k]))
        if k in held:                       # the controller held (the shift came late or never)
            current = held[k]
        elif k in shifts and k < n - 1:
            current = shifts[k][0]
            rec = recorded.get(k) or _decision(current, shifts[k][1])
            if initial is None:
                initial = replace(rec, k=k // schedule.every)
            elif schedule.update_due(k):
                updates.append((k, replace(rec, k=k // schedule.every, tau_prev=float(tau[k - 1]))))
        tau[k] = current
    if initial is None:
        raise CikanError(f"bag {path}: no time shift recorded on {TIME_SHIFT}")
    summary["missing_shifts"] = sum(1 for k in range(n - 1) if k not in shifts)
    if held:   # the controller's wall-clock deadline fired: recorded beside the sim's misses
        summary["controller_holds"] = len(held)
    x_d = np.array([deputy[k] for k in range(n)])
    x_c = np.array([chief[k] for k in range(n)])
    t = np.array([tl.seconds(tl.stamp_ns(k)) for k in range(n)])
    m = margins(x_d, x_c, u, cfg.constraints, limit, cfg.side)
    m.h2[-1] = math.nan  # no command is applied at the final instant
    seen = None if not has_truth or cfg.truth.is_nominal else (
        np.array([seen_d[k] for k in range(n)]), np.array([seen_c[k] for k in range(n)]))
    # between samples: the simulator's count per step (NaN where its step record is missing;
    # None for a bag recorded before the simulator judged them)
    judged = np.array([between.get(k, math.nan) for k in range(n - 1)] + [0.0]) if between else None
    result = MissionResult(cfg, governor, t, x_d, x_c, u, tau, m, initial,
                           np.array([t[k] for k, _ in updates]), [r for _, r in updates],
                           *(seen or (None, None)), limit, judged)
    return result, summary


def recorded_metrics(path: str | Path, cfg: Config, governor: str,
                     msgs: dict[str, list[tuple[int, Any]]] | None = None) -> tuple[MissionResult, dict[str, Any]]:
    """(MissionResult, metrics) of a recorded mission: :meth:`MissionResult.metrics`, plus the
    governor contract audit of its shifts (:func:`cikan_ros.mission.audit_shifts`):
    ``unverified_shifts``, ``off_schedule_shifts`` and ``missing_shifts`` (steps with no valid
    shift), the simulator's summary under ``ros`` when it was recorded, and, where a model flew
    (the governor's announcement names one), ``nn_accept_rate``
    (:func:`cikan_ros.learn.governor.nn_accept_rate` of its recorded decisions). Values the bag
    does not hold (decision wall times without governor_node's records) are None."""
    result, summary = mission_from_bag(path, cfg, governor, msgs)
    seen_d = result.x_d if result.x_d_seen is None else result.x_d_seen
    seen_c = None if result.x_c_seen is None else result.x_c_seen
    audit = audit_shifts(Predictor.from_config(cfg), seen_d, result.tau, seen_c)
    # What the bag does not tell (decision wall times without governor_node's records) is None.
    metrics = {k: None if isinstance(v, float) and not math.isfinite(v) else v
               for k, v in result.metrics().items()}
    metrics.update(unverified_shifts=audit.unverified, off_schedule_shifts=audit.off_schedule,
                   missing_shifts=summary.pop("missing_shifts"))
    if summary:
        metrics["ros"] = summary
    announced = bag_governor_announcements(path)
    if any(a.get("model") for a in announced):
        metrics["nn_accept_rate"] = nn_accept_rate(result.updates)
    foreign = [a["foreign_model"] for a in announced if a.get("foreign_model")]
    if foreign:
        metrics["foreign_model"] = foreign[-1]
    return result, metrics


def bag_model(path: str | Path) -> str | None:
    """The model directory the bag's governor announced (the last one), or None."""
    models = [a["model"] for a in bag_governor_announcements(path) if a.get("model")]
    return models[-1] if models else None


# -- metadata -----------------------------------------------------------------------------------
def bag_custom_data(path: str | Path) -> dict[str, str]:
    """The ``custom_data`` of a bag's metadata.yaml (what the recorder stored beside the
    messages); OSError or yaml.YAMLError when the file cannot be read."""
    meta = yaml.safe_load((Path(path) / "metadata.yaml").read_text()) or {}
    return (meta.get("rosbag2_bagfile_information") or {}).get("custom_data") or {}


def bag_config(path: str | Path, fallback: Config | None) -> Config:
    """The configuration a bag was recorded with (``cikan_ros.config``), else ``fallback`` (else
    the shipped one)."""
    custom = bag_custom_data(path)
    if "cikan_ros.config" in custom:
        return config_from_flat(json.loads(custom["cikan_ros.config"]))
    return fallback or load_config()


def bag_governor(path: str | Path) -> str:
    """The governors that flew as the bag records them (``cikan_ros.governor``), else the part of
    the bag's name after its first ``_`` (``<UTC time>_<governor>``)."""
    return bag_custom_data(path).get("cikan_ros.governor", Path(path).name.split("_", 1)[-1])


def bag_governor_announcements(path: str | Path) -> list[dict[str, Any]]:
    """The governor announcements a bag's metadata holds (``cikan_ros.governor_announcements``:
    which governor flew, its model, scenario and side; empty when there are none)."""
    try:
        custom = bag_custom_data(path)
    except (OSError, yaml.YAMLError):
        return []
    try:
        out = json.loads(custom.get("cikan_ros.governor_announcements", "[]"))
    except json.JSONDecodeError:
        return []
    return [a for a in out if isinstance(a, dict)] if isinstance(out, list) else []


def bag_telemetry(path: str | Path) -> dict[str, Any]:
    """The telemetry dictionary document of a bag (:func:`cikan_ros.telemetry.to_json`; read the
    points with :func:`cikan_ros.telemetry.from_json`): the one the recorder stored (metadata.yaml
    ``cikan_ros.telemetry``, else the MCAP metadata record ``cikan_telemetry``), else, for a bag
    recorded before bags carried one, the dictionary of the bag's configuration (``"stored":
    false`` says so). CikanError naming a bag that is not there."""
    from ..telemetry import dictionary, to_json
    from .bag_writer import TELEMETRY_CUSTOM_KEY, TELEMETRY_RECORD

    p = Path(path)
    if not (p / "metadata.yaml").is_file():
        raise CikanError(f"{p} is not a bag directory (no metadata.yaml)")
    text = bag_custom_data(p).get(TELEMETRY_CUSTOM_KEY)
    if text is None:
        from mcap.reader import make_reader

        for mcap_file in sorted(p.glob("*.mcap")):
            with mcap_file.open("rb") as f:
                for record in make_reader(f).iter_metadata():
                    if record.name == TELEMETRY_RECORD:
                        text = record.metadata["json"]
    if text is not None:
        return {**json.loads(text), "stored": True}
    cfg = bag_config(p, None)
    return {**to_json(dictionary(cfg), cfg), "stored": False}
