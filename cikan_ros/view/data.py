"""What the mission-control view shows, as JSON: the runs of a bag or of a Monte Carlo directory
in the chief's LVLH frame (deputy path, virtual target, the line-of-sight cone of the run's own
half angle and side), and every telemetry point of the dictionary against its limits.

A run is a :class:`Track` (per control step: time, true deputy and chief states, applied thrust,
the shift in force). :func:`payload` turns tracks into the page's data; :func:`encode` writes it
as strict JSON (NaN: null) with 7 significant digits. Long runs are thinned to
:data:`MAX_POINTS` samples (a 4-h mission at T_c = 10 s has 1,441: all drawn), a Monte Carlo
directory to :data:`MAX_OVERLAY_POINTS` samples shared among its runs; a sample where a limit is
crossed is always kept.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from ..config import Config, config_from_flat
from ..constraints import margins
from ..errors import CikanError
from ..mission import violation_masks
from ..montecarlo import load_run_arrays
from ..scene import port_axis_lvlh, relative_lvlh
from ..telemetry import FRAME_LVLH, TelemetryPoint, dictionary, from_json, values
from ..tsg import ChiefAnchor, Predictor
from ..units import KM

#: Samples of one run drawn at most.
MAX_POINTS = 5000
#: Samples drawn at most over all the runs of a Monte Carlo directory (each run gets its share,
#: at least :data:`MIN_RUN_POINTS`).
MAX_OVERLAY_POINTS = 150_000
MIN_RUN_POINTS = 60


@dataclass(frozen=True)
class Track:
    """One run as the view draws it, per control step k = 0..K: ``t`` (s since the epoch), the
    true deputy and chief ``x_d``, ``x_c`` (km, km/s, ECI), the applied thrust ``u`` (km/s^2,
    ECI) and the shift in force ``tau`` (s, NaN before the first); ``x_c_seen``: the chief as the
    controller measured it (None: the truth), from which it propagated the virtual target."""

    label: str
    group: str
    t: NDArray
    x_d: NDArray
    x_c: NDArray
    u: NDArray
    tau: NDArray
    x_c_seen: NDArray | None = None


def track_of(result: Any, label: str) -> Track:
    """The track of a :class:`~cikan_ros.mission.MissionResult`."""
    return Track(label, result.governor, result.t, result.x_d, result.x_c, result.u, result.tau, result.x_c_seen)


#: Telemetry points that show a constraint: judged as the mission's metrics judge it (the
#: tolerances of :func:`cikan_ros.mission.violation_masks`: h1, h2, h3), not by the bare limit.
JUDGED_BY = {"h1": 0, "los_angle": 0, "h2": 1, "thrust": 1, "h3": 2, "speed": 2}
#: Relative position in LVLH: the deputy's place in the scene.
POSITION_KEYS = ("p_x", "p_y", "p_z")


def virtual_target(track: Track, predictor: Predictor) -> NDArray:
    """The virtual target x_c(t_k + tau_k) relative to the chief, in LVLH (K+1, 3), m, as the
    controller propagates it (its chief anchored on the measured chief,
    :class:`~cikan_ros.tsg.ChiefAnchor`); NaN where no shift is in force."""
    anchor = ChiefAnchor(predictor)
    seen = track.x_c if track.x_c_seen is None else track.x_c_seen
    target = np.full((len(track.t), 6), math.nan)
    for k, (t, tau) in enumerate(zip(track.t, track.tau)):
        if math.isfinite(tau):
            target[k] = anchor(seen[k], float(t)).orbit.state(float(t) + float(tau))
    return relative_lvlh(target, track.x_c)[0] * KM


def violations(cfg: Config, points: Sequence[TelemetryPoint], track: Track, table: NDArray) -> dict[str, NDArray]:
    """Key -> where the point is beyond its limits, of each point with limits: the constraints'
    points (:data:`JUDGED_BY`) as the metrics judge them, the others by their limits, from
    ``table`` (the values of ``points``, a column each; NaN: not evaluated, never beyond)."""
    m = margins(track.x_d, track.x_c, track.u, cfg.constraints, cfg.thrust_limit_kmps2, cfg.side)
    m.h2[-1] = math.nan   # no command is applied at the final instant
    masks = violation_masks(m, cfg, cfg.thrust_limit_kmps2 / cfg.control.u_max_kmps2)
    out = {}
    for i, p in enumerate(points):
        if p.key in JUDGED_BY:
            out[p.key] = masks[JUDGED_BY[p.key]]
        elif p.limit_low is not None or p.limit_high is not None:
            with np.errstate(invalid="ignore"):
                col = table[:, i]
                out[p.key] = ((col > p.limit_high) if p.limit_high is not None else False) | \
                    ((col < p.limit_low) if p.limit_low is not None else False)
    return out


def thin(n: int, most: int, keep: NDArray) -> NDArray:
    """Indices of at most about ``most`` evenly spaced samples of ``n`` (the first and last
    included), plus every index where ``keep`` is True."""
    if n <= most:
        return np.arange(n)
    return np.unique(np.r_[np.linspace(0, n - 1, most).round().astype(int), np.flatnonzero(keep)])


def plotted(points: Sequence[TelemetryPoint]) -> list[TelemetryPoint]:
    """The points the page plots against time: the scalar ones, but those that are another's
    limit (drawn as that point's limit line)."""
    limits = {p.limit_key for p in points if p.limit_key}
    return [p for p in points if not p.frame and p.key not in limits]


def payload(cfg: Config, tracks: Sequence[Track], source: str, kind: str, *,
            complete: bool = True, stored: Sequence[TelemetryPoint] | None = None) -> dict[str, Any]:
    """The page's data: the scene (m, LVLH), the telemetry dictionary's plotted points (with
    units and limits: ``stored``, the dictionary a bag carries, else the configuration's), and
    per run its time (s since the mission start), its LVLH positions, its telemetry values and
    where each crosses a limit. ``kind``: ``bag``, ``montecarlo`` or ``live``; ``complete``:
    False while a live mission still flies."""
    points = dictionary(cfg)
    column = {p.key: i for i, p in enumerate(points)}   # the columns of telemetry.values
    if stored is not None:   # its names, units and limits, for the values computed here
        points = [p for p in stored if p.key in column]
    shown = plotted(points)
    wanted = [p.key for p in shown] + [p.limit_key for p in shown if p.limit_key]
    single = len(tracks) == 1
    per_run = MAX_POINTS if single else max(MIN_RUN_POINTS, MAX_OVERLAY_POINTS // max(1, len(tracks)))
    predictor = Predictor.from_config(cfg) if single and tracks else None
    runs, reach = [], cfg.mission.dock_distance_km * KM
    for tr in tracks:
        table = values(cfg, tr.x_c, tr.x_d, tr.u, tr.tau)
        bad = violations(cfg, points, tr, table[:, [column[p.key] for p in points]])
        idx = thin(len(tr.t), per_run, np.any(list(bad.values()), axis=0))
        deputy = table[:, [column[k] for k in POSITION_KEYS]]
        reach = max(reach, float(np.nanmax(np.linalg.norm(deputy, axis=1))))
        run: dict[str, Any] = {
            "label": tr.label, "group": tr.group, "t": tr.t[idx] - tr.t[0], "deputy": deputy[idx].T,
            "values": {k: table[idx, column[k]] for k in wanted},
            "violations": {k: np.flatnonzero(b[idx]) for k, b in bad.items() if b.any()},
        }
        if predictor is not None:
            run["target"] = virtual_target(tr, predictor)[idx].T
        if not runs:   # the cone's axis turns in LVLH with the flight-path angle: one per sample
            run["axis"] = port_axis_lvlh(tr.x_c[idx], cfg.side).T
        runs.append(run)
    c = cfg.constraints
    return {
        "source": source, "kind": kind, "complete": complete, "frame": FRAME_LVLH, "side": cfg.mission.approach,
        "scene": {"half_angle_deg": c.los_half_angle_deg, "reach_m": reach,
                  "dock_distance_m": cfg.mission.dock_distance_km * KM, "gamma1_m": c.gamma1_km * KM},
        "axes": [f"{points[column[k]].name} ({points[column[k]].unit})" for k in POSITION_KEYS],
        "telemetry": [asdict(p) for p in shown],
        "runs": runs,
    }


def encode(data: Any) -> bytes:
    """Strict JSON of a payload: numpy arrays as lists with 7 significant digits, NaN and inf as
    null."""
    def fmt(v: float) -> str:
        return f"{v:.7g}" if math.isfinite(v) else "null"

    def default(obj: Any) -> Any:
        raise TypeError(f"not JSON serialisable: {type(obj).__name__}")

    def walk(obj: Any) -> str:
        if isinstance(obj, np.ndarray):
            if obj.ndim > 1:
                return "[" + ",".join(walk(row) for row in obj) + "]"
            if obj.dtype.kind in "iub":
                return "[" + ",".join(str(int(v)) for v in obj) + "]"
            return "[" + ",".join(fmt(float(v)) for v in obj) + "]"
        if isinstance(obj, dict):
            return "{" + ",".join(f"{json.dumps(str(k))}:{walk(v)}" for k, v in obj.items()) + "}"
        if isinstance(obj, (list, tuple)):
            return "[" + ",".join(walk(v) for v in obj) + "]"
        if isinstance(obj, float):
            return fmt(obj)
        if isinstance(obj, np.generic):
            return walk(obj.item())
        return json.dumps(obj, default=default)
    return walk(data).encode()


# -- sources ------------------------------------------------------------------------------------
def bag_directory(path: str | Path) -> Path | None:
    """The bag directory ``path`` names (itself, or the directory of its .mcap file), or None."""
    p = Path(path)
    if p.is_file() and p.suffix == ".mcap":
        p = p.parent
    return p if (p / "metadata.yaml").is_file() else None


def run_files(path: Path) -> list[Path]:
    """The per-run results of a Monte Carlo directory (``<governor>/seed_<n>.json``), in order."""
    return sorted(path.glob("*/seed_*.json"))


def stored_dictionary(path: Path) -> list[TelemetryPoint]:
    """The telemetry dictionary a bag carries (or its configuration's, for an older bag)."""
    from ..ros.bag_reader import bag_telemetry

    return from_json(bag_telemetry(path))


def load_bag(path: Path) -> tuple[Config, list[Track], list[TelemetryPoint]]:
    """The configuration, the run and the telemetry dictionary of a recorded mission; CikanError
    (one line) for a bag that cannot be read or does not hold a mission."""
    from ..ros.bag_reader import bag_config, bag_governor, mission_from_bag, read_bag

    try:
        cfg = bag_config(path, None)
        points = stored_dictionary(path)
        msgs = read_bag(path)
    except Exception as exc:   # rosbags, mcap, yaml and the file system each raise their own
        raise CikanError(f"{path}: not a readable bag ({type(exc).__name__}: {exc})") from None
    result, _ = mission_from_bag(path, cfg, bag_governor(path), msgs)
    return cfg, [track_of(result, path.name)], points


def load_montecarlo(path: Path) -> tuple[Config, list[Track]]:
    """The configuration and the flown runs of a Monte Carlo directory (refused runs left out)."""
    tracks, cfg = [], None
    for js in run_files(path):
        try:
            stored = json.loads(js.read_text())
            if "refused" in stored["metrics"]:
                continue
            a = load_run_arrays(js.with_suffix(".npz"))
            cfg = cfg or config_from_flat(stored["config"])
        except (OSError, ValueError, KeyError) as exc:
            raise CikanError(f"{js}: not a readable Monte Carlo result ({type(exc).__name__}: {exc})") from None
        seed = stored["metrics"].get("seed")
        tracks.append(Track(f"{js.parent.name} seed {seed}", js.parent.name, a["t"], a["x_d"], a["x_c"],
                            a["u"], a["tau"]))
    if cfg is None:
        raise CikanError(f"{path}: every Monte Carlo run was refused: nothing to show")
    return cfg, tracks


def load(path: str | Path) -> dict[str, Any]:
    """The page's data for a bag directory (or its .mcap file) or a Monte Carlo directory;
    CikanError (one line) for anything else."""
    p = Path(path)
    if not p.exists():
        raise CikanError(f"no such bag or directory: {p}")
    bag = bag_directory(p)
    if bag is not None:
        cfg, tracks, points = load_bag(bag)
        return payload(cfg, tracks, str(bag), "bag", stored=points)
    if p.is_dir() and run_files(p):
        cfg, tracks = load_montecarlo(p)
        return payload(cfg, tracks, str(p), "montecarlo")
    raise CikanError(f"{p} is neither a rosbag2 bag (no metadata.yaml) nor a Monte Carlo directory "
                     "(no <governor>/seed_*.json)")
