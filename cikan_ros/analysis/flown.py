"""What a run flew and how it ended, in words: the rows every summary shows (``cikan mission``'s
table, ``cikan montecarlo``'s summary, report.md), so each names the scenario, side, truth,
Verify mode, governor and model, the docking test and the network's acceptance, and shows every
quantity in one unit: distances m, speeds m/s, ΔV km/s, h2 m/s² against the limit it is judged
by, h3 m/s (the JSON metrics keep their keys' units: ``max_h3`` km/s, ``max_h2`` km/s²).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..config import Config
from ..orbit import KeplerOrbit
from .figures import thrust_limit_text


def eci_resolution_m(cfg: Config, t_s: float) -> float:
    """The float64 resolution of the chief's ECI position at ``t_s`` (s since the epoch), m:
    eps |r_c|. Two ECI positions closer than this are equal to the last bit: a final distance
    below it is rounding, not a distance."""
    r_km = float(np.linalg.norm(KeplerOrbit.from_config(cfg.orbit).state(t_s)[:3]))
    return float(np.finfo(float).eps) * r_km * 1e3


def distance_text(distance_m: float | None, resolution_m: float) -> str:
    """A final distance in m (no unit: the label says it); below ``resolution_m``
    (:func:`eci_resolution_m`) said as such."""
    if distance_m is None or not math.isfinite(distance_m):
        return "-"
    if distance_m < resolution_m:
        return f"< {resolution_m:.2g} (float64 resolution of ECI positions)"
    return f"{distance_m:.3e}"


def approach_text(cfg: Config) -> str:
    """``from behind (τ <= 0, cone 20° around -v_c)``: the side, and the cone it docks in."""
    behind = cfg.mission.approach == "behind"
    return (f"from {cfg.mission.approach} (τ {'<=' if behind else '>='} 0, cone "
            f"{cfg.constraints.los_half_angle_deg:g}° around {'-' if behind else '+'}v_c)")


def truth_text(cfg: Config) -> str:
    """The truth the simulator flew: its name, scale and what it declares beyond the nominal."""
    t = cfg.truth
    if t.is_nominal:
        return f"{t.name} ({t.effective_gravity}, exact measurements)"
    parts = [f"{t.effective_gravity} gravity"]
    if t.bound("thrust_bias_max"):
        parts.append(f"thrust bias <= {100 * t.bound('thrust_bias_max'):g} %")
    if t.bound("thrust_pointing_max_deg"):
        parts.append(f"pointing <= {t.bound('thrust_pointing_max_deg'):g}°")
    if t.bound("disturbance_max_kmps2"):
        parts.append(f"disturbance <= {1e3 * t.bound('disturbance_max_kmps2'):g} m/s²")
    if t.bound("nav_pos_floor_km") or t.bound("nav_pos_range_fraction"):
        parts.append("navigation errors")
    return f"{t.name} at scale {t.scale:g} ({', '.join(parts)})"


def flown_rows(cfg: Config, governor: str, model: str | None = None,
               nn_accept_rate: float | None = None) -> list[tuple[str, str]]:
    """(label, text) rows of what a run or campaign flew: scenario, side, truth, Verify mode,
    governor (with its model), the docking test and, where a learned governor flew, the
    network's acceptance (``nn_accept_rate``: the share of the active updates answered with its
    proposal, passed by Verify)."""
    m = cfg.mission
    rows = [("scenario", f"{cfg.scenario.name}: {cfg.scenario.description}"),
            ("approach", approach_text(cfg)),
            ("truth", truth_text(cfg)),
            ("Verify", "robust (constraints tightened by the truth's bounds)" if cfg.tsg.robust else "nominal"),
            ("governor", governor + (f" (model {shown_path(model)})" if model else "")),
            ("docking test", f"< {m.dock_distance_km * 1e3:g} m, < {m.dock_speed_kmps * 1e3:g} m/s at the "
                             "end, τ = 0, no violation")]
    if nn_accept_rate is not None and math.isfinite(nn_accept_rate):
        rows.append(("network acceptance", f"{nn_accept_rate:.3f} (nn_accept_rate)"))
    if cfg.learned.foreign_model and governor != "conventional":
        rows.append(("foreign models", "allowed (learned.foreign_model): a model made for another scenario, "
                                       "side or Verify flies (each run's foreign_model says what it was made for)"))
    return rows


def shown_path(path: str | Path) -> str:
    """A path as a user reads it: relative to the working directory when inside it."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def governors_text(names: list[str], cfg: Config) -> str:
    """Governors as a campaign names them, each learned family with the model it flies for the
    scenario and side (``scenario.models_dir``), e.g. ``conventional, cikan (models/leo/cikan-ahead)``."""
    from ..learn.arch import FAMILIES
    from ..learn.modelfile import flown_model_dir
    from ..registry import split_rule

    def one(name: str) -> str:
        base, _ = split_rule(name)
        if base not in FAMILIES:
            return name
        return f"{name} ({shown_path(flown_model_dir(cfg, base))})"
    return ", ".join(one(n) for n in names)


def flown_markdown(rows: list[tuple[str, str]]) -> str:
    """:func:`flown_rows` as a Markdown list."""
    return "".join(f"- {label}: {text}\n" for label, text in rows)


def _pair(metrics: dict[str, Any], key: str) -> str:
    stem = key.removesuffix("_mean")
    return " / ".join("-" if metrics.get(k) is None else f"{metrics[k]:.3f}" for k in (key, stem + "_max"))


def _value(metrics: dict[str, Any], key: str, fmt: str, scale: float = 1.0) -> str:
    v = metrics.get(key)
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return fmt.format(v * scale if scale != 1.0 else v)


#: The audit of a ROS run's time shifts (cikan_ros.mission.audit_shifts), shown when present.
AUDIT_ROWS = (("unverified_shifts", "time shifts not verified (audit)"),
              ("off_schedule_shifts", "time shifts changed off schedule"),
              ("missing_shifts", "steps without a time shift"),
              ("lockstep_deadlines", "wall-clock deadlines fired (each fails the run)"))


def metric_rows(metrics: dict[str, Any], cfg: Config) -> list[tuple[str, str]]:
    """(label with unit, text) rows of one run's metrics (:meth:`MissionResult.metrics`, plus
    ``nn_accept_rate`` and a ROS run's audit when present)."""
    m = cfg.mission
    u_name, u_text = thrust_limit_text(cfg)
    resolution = eci_resolution_m(cfg, float(metrics.get("duration_s") or m.duration_s))
    rows = [
        ("docked with zero violations", _value(metrics, "success", "{}")),
        ("control steps with a violation", _value(metrics, "violations", "{}")),
        ("truth states violating between samples", _value(metrics, "violations_between", "{}")),
        ("first time shift τ_0 [s]", _value(metrics, "tau0_s", "{:.6f}")),
        ("τ reached 0 at [s]", _value(metrics, "t_tau_zero_s", "{}")),
        (f"docked (< {m.dock_distance_km * 1e3:g} m, < {m.dock_speed_kmps * 1e3:g} m/s) at [s]",
         _value(metrics, "t_docked_s", "{}")),
        ("final distance [m]", distance_text(metrics.get("final_distance_m"), resolution)),
        *([("docking robust Verify certified: ball [m, m/s], reached",
            f"{metrics['dock_certified_m']:.4f}, {metrics['dock_certified_mps']:.2e}, "
            f"{'yes' if metrics['docked_certified'] else 'NO'}")] if "dock_certified_m" in metrics else []),
        ("final relative speed [m/s]", _value(metrics, "final_speed_mps", "{:.3e}")),
        ("delta-V [km/s]", _value(metrics, "delta_v_kmps", "{:.4f}")),
        ("min LoS margin -h1/(|v_c||p_rel|)", _value(metrics, "min_h1_margin", "{:.3e}")),
        (f"max h2 = |u| - {u_name} [m/s²], {u_text}", _value(metrics, "max_h2", "{:.3e}", 1e3)),
        ("max h3 [m/s]", _value(metrics, "max_h3", "{:.3e}", 1e3)),
        ("governor updates", _value(metrics, "updates", "{}")),
        ("update time mean / max [ms]", _pair(metrics, "update_ms_mean")),
        ("active-phase update mean / max [ms]", _pair(metrics, "active_update_ms_mean")),
    ]
    rows += [(label, _value(metrics, key, "{}")) for key, label in AUDIT_ROWS if key in metrics]
    if metrics.get("foreign_model"):
        rows.append(("model", f"FOREIGN: {metrics['foreign_model']} (learned.foreign_model)"))
    return rows
