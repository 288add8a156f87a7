"""The telemetry and scene messages of a mission, step by step: what the simulator publishes on
/telemetry and /scene/* and what ``cikan scene`` adds to a bag recorded without them
(:func:`add_scene`), from one implementation (:class:`SceneStream`).

Per step k (stamp t_k): the truth's chief x_c and deputy x_d, the applied thrust u and the shift
tau in force. The virtual target is x_c(t_k + tau) on the chief orbit through x_c at t_k (the
prediction model's, anchored as the controller anchors it: :class:`cikan_ros.tsg.ChiefAnchor`).
"""

from __future__ import annotations

import heapq
import math
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from numpy.typing import NDArray

from ..config import Config
from ..errors import CikanError
from ..constraints import constraint_params
from ..scene import SceneBuilder, port_axis_kernel, relative_lvlh_kernel
from ..telemetry import P_LVLH, keys, values_kernel
from ..units import KM
from ..tsg import ChiefAnchor, Predictor
from . import cdr, convert as cv
from .convert import Timeline
from .graph_spec import SCENE_CONSTRAINTS, SCENE_MARKERS, SCENE_PATH, SCENE_TOPICS, TELEMETRY


class SceneStream:
    """Telemetry and scene messages of consecutive steps of one mission (see the module docstring)."""

    def __init__(self, cfg: Config, predictor: Predictor) -> None:
        self.cfg = cfg
        self.keys = keys(cfg)
        self.anchor = ChiefAnchor(predictor)
        every = round(cfg.tsg.update_period_s / cfg.control.period_s)
        self.scene = SceneBuilder(cfg, path_every=every)
        self.markers = cdr.MarkersCdr()
        self.telemetry = cdr.TelemetryCdr(self.keys)
        # The compiled kernels are called on one-row buffers: a step costs no array wrapping.
        self.cparams = constraint_params(cfg.constraints, cfg.thrust_limit_kmps2, cfg.side)
        self.side = float(cfg.side)
        self.x_c, self.x_d, self.x_v = np.empty((1, 6)), np.empty((1, 6)), np.empty((1, 6))
        self.u, self.tau = np.empty((1, 3)), np.empty(1)
        self.row, self.rel, self.axis = np.empty((1, len(self.keys))), np.empty((1, 6)), np.empty((1, 3))

    def step(self, k: int, stamp_ns: int, t: float, x_c: NDArray, x_d: NDArray, u: NDArray, tau: float,
             last: bool = False) -> list[tuple[str, Any]]:
        """(topic, message) pairs of step k at time t (s since the epoch; tau NaN: no shift yet,
        no virtual target); ``last``: the mission's last step (the path ends at it). Each comes
        serialised (bytes, :mod:`cikan_ros.ros.cdr`: what a publisher sends)."""
        self.x_c[0], self.x_d[0], self.u[0], self.tau[0] = x_c, x_d, u, tau
        values_kernel(self.x_c, self.x_d, self.u, self.tau, self.cparams, self.row)
        out: list[tuple[str, Any]] = [(TELEMETRY, self.telemetry(self.row[0], stamp_ns))]
        p_d = self.row[0, P_LVLH] / KM
        p_v = None
        if not math.isnan(tau):
            self.x_v[0] = self.anchor(x_c, t).orbit.state(t + tau)
            relative_lvlh_kernel(self.x_v, self.x_c, self.rel)
            p_v = self.rel[0, :3].copy()
        out.append((SCENE_MARKERS, self.markers(self.scene.moving(p_d, p_v), stamp_ns)))
        trail = self.scene.trail(k, p_d, last)
        if trail is not None:
            out.append((SCENE_PATH, self.markers([trail], stamp_ns)))
        port_axis_kernel(self.x_c, self.side, self.axis)
        shapes = self.scene.constraints(self.axis[0])
        if shapes is not None:
            out.append((SCENE_CONSTRAINTS, self.markers(shapes, stamp_ns)))
        return out


def add_scene(src: str | Path, dst: str | Path) -> dict[str, int]:
    """Write a copy of the bag ``src`` to the new bag directory ``dst`` with the telemetry
    dictionary and the telemetry and scene topics (:data:`SCENE_TOPICS`) recomputed by
    :class:`SceneStream` from the recorded truth (or, in a bag without truth topics, the
    measured states), applied thrust and time shifts, exactly as the simulator publishes them
    (to the SI round trip of the recorded states). Every other message is copied as recorded; a
    bag's own scene topics are replaced. Returns the messages written per topic. CikanError for a
    bag that cannot be read or lacks the states or the shifts."""
    import yaml
    from mcap.reader import make_reader

    from ..telemetry import dictionary, to_json
    from .bag_reader import bag_config, bag_custom_data, bag_governor, mission_from_bag
    from .bag_writer import TELEMETRY_CUSTOM_KEY, BagWriter, qos_dict
    from .graph import qos_for
    from .graph_spec import TOPIC_TYPES

    src, dst = Path(src), Path(dst)
    try:
        custom = bag_custom_data(src)
        cfg = bag_config(src, None)
        run, _summary = mission_from_bag(src, cfg, bag_governor(src))
        (mcap_file,) = sorted(src.glob("*.mcap"))
    except (OSError, ValueError, yaml.YAMLError) as exc:
        raise CikanError(f"cannot read bag {src}: {exc}") from None
    tl = Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
    stream = SceneStream(cfg, Predictor.from_config(cfg))
    n = len(run.t)

    def scene() -> Iterator[tuple[int, str, bytes]]:
        for k in range(n):
            stamp = tl.stamp_ns(k)
            for topic, msg in stream.step(k, stamp, float(run.t[k]), run.x_c[k], run.x_d[k], run.u[k],
                                          float(run.tau[k]), last=k == n - 1):
                yield stamp, topic, msg

    custom.pop(TELEMETRY_CUSTOM_KEY, None)
    with BagWriter(dst, custom_data=custom) as bag, mcap_file.open("rb") as f:
        bag.add_telemetry(to_json(dictionary(cfg), cfg))
        reader = make_reader(f)
        recorded = ((msg.log_time, channel.topic, msg.data, channel, schema)
                    for schema, channel, msg in reader.iter_messages(log_time_order=True)
                    if channel.topic not in SCENE_TOPICS)
        added = ((stamp, topic, data, None, None) for stamp, topic, data in scene())
        for log_time, topic, data, channel, schema in heapq.merge(recorded, added, key=lambda r: r[0]):
            if topic not in bag.channels:
                if channel is None:
                    bag.add_topic(topic, TOPIC_TYPES[topic], [qos_dict(qos_for(topic))])
                else:
                    qos = channel.metadata.get("offered_qos_profiles", "")
                    bag.add_topic(topic, schema.name, yaml.safe_load(qos) if qos else [])
            bag.write(topic, data, log_time)
        return dict(bag.counts)
