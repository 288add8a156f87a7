"""The telemetry and scene messages of a mission, step by step: what the simulator publishes on
/telemetry and /scene/* and what ``cikan scene`` adds to a bag recorded without them, from one
implementation (:class:`SceneStream`).

Per step k (stamp t_k): the truth's chief x_c and deputy x_d, the applied thrust u and the shift
tau in force. The virtual target is x_c(t_k + tau) on the chief orbit through x_c at t_k (the
prediction model's, anchored as the controller anchors it: :class:`cikan_ros.tsg.ChiefAnchor`).
"""

from __future__ import annotations

import math
from typing import Any

from numpy.typing import NDArray

from ..config import Config
from ..scene import SceneBuilder, relative_lvlh, virtual_target_lvlh
from ..telemetry import keys, values
from ..tsg import ChiefAnchor, Predictor
from . import convert as cv
from .graph_spec import SCENE_CONSTRAINTS, SCENE_MARKERS, SCENE_PATH, TELEMETRY

#: The topics a :class:`SceneStream` writes, in the order it writes them at a step.
SCENE_TOPICS = (TELEMETRY, SCENE_MARKERS, SCENE_PATH, SCENE_CONSTRAINTS)


class SceneStream:
    """Telemetry and scene messages of consecutive steps of one mission (see the module docstring)."""

    def __init__(self, cfg: Config, predictor: Predictor) -> None:
        self.cfg = cfg
        self.keys = keys(cfg)
        self.anchor = ChiefAnchor(predictor)
        every = round(cfg.tsg.update_period_s / cfg.control.period_s)
        self.scene = SceneBuilder(cfg, path_every=every)

    def step(self, k: int, stamp_ns: int, t: float, x_c: NDArray, x_d: NDArray, u: NDArray, tau: float,
             last: bool = False) -> list[tuple[str, Any]]:
        """(topic, message) pairs of step k at time t (s since the epoch; tau NaN: no shift yet,
        no virtual target); ``last``: the mission's last step (the path ends at it)."""
        out: list[tuple[str, Any]] = [
            (TELEMETRY, cv.telemetry_msg(self.keys, values(self.cfg, x_c, x_d, u, tau)[0], stamp_ns))]
        p_d = relative_lvlh(x_d, x_c)[0][0]
        p_v = None if math.isnan(tau) else virtual_target_lvlh(self.anchor(x_c, t).orbit, x_c, t, tau)[:3]
        out.append((SCENE_MARKERS, cv.markers_msg(self.scene.moving(p_d, p_v), stamp_ns)))
        trail = self.scene.trail(k, p_d, last)
        if trail is not None:
            out.append((SCENE_PATH, cv.markers_msg([trail], stamp_ns)))
        shapes = self.scene.constraints(x_c)
        if shapes is not None:
            out.append((SCENE_CONSTRAINTS, cv.markers_msg(shapes, stamp_ns)))
        return out

