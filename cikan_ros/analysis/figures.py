"""The paper's figures (Fig. 3a-e, Fig. 4) as PNG files, drawn with matplotlib (Agg, no screen).

Every function takes runs (:class:`RunData`) and a path, draws one figure, and returns the path.
Each run carries the configuration it flew: the cone (half-angle, the side its axis points to),
gamma1 of h3 and the thrust limit of h2 are drawn from it (the first run's, for a figure of
several). Times on the axes are hours since the mission epoch; distances km, speeds m/s; h1 is
normalised (h1 / (|v_c||p_rel|), <= 0 inside the cone); h2 m/s^2, h3 m/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from ..config import Config, Side  # noqa: E402
from ..orbit import vnb_frame  # noqa: E402

#: Line styles of the paper's Fig. 3 (governor -> matplotlib style).
STYLES = {
    "conventional": dict(color="black", linestyle="-"),
    "cikan": dict(color="tab:blue", linestyle="--"),
    "grbf": dict(color="goldenrod", linestyle="-"),
    "rswaf": dict(color="tab:green", linestyle=":"),
    "relu": dict(color="tab:cyan", linestyle="--"),
    "gelu": dict(color="tab:red", linestyle="-"),
}
LABELS = {"conventional": "conventional TSG", "cikan": "CIKAN", "grbf": "GRBF-CIKAN",
          "rswaf": "RSWAF-CIKAN", "relu": "CINN-ReLU", "gelu": "CINN-GELU"}


@dataclass
class RunData:
    """One run's time histories at the control steps (arrays of length K+1)."""

    governor: str
    t: NDArray            # s since epoch
    x_d: NDArray          # (K+1, 6) km, km/s, ECI
    x_c: NDArray          # (K+1, 6)
    u: NDArray            # (K+1, 3) km/s^2
    tau: NDArray          # s
    h1_normalised: NDArray
    h2: NDArray           # km/s^2, against the thrust limit of config (Config.thrust_limit_kmps2)
    h3: NDArray           # km/s
    config: Config        # what the run flew: scenario, side, constraints, truth
    label: str = ""
    model: str | None = None   # the model directory a learned governor flew, when known

    @property
    def hours(self) -> NDArray:
        return (self.t - self.t[0]) / 3600.0

    @property
    def distance_km(self) -> NDArray:
        return np.linalg.norm(self.x_d[:, :3] - self.x_c[:, :3], axis=1)

    @property
    def speed_mps(self) -> NDArray:
        return 1e3 * np.linalg.norm(self.x_d[:, 3:] - self.x_c[:, 3:], axis=1)

    def p_rel_vnb(self) -> NDArray:
        """Relative position in the chief's VNB frame (K+1, 3), km: [V, N, B]."""
        rot = vnb_frame(self.x_c)
        return np.einsum("kij,kj->ki", rot, self.x_d[:, :3] - self.x_c[:, :3])


def _style(gov: str) -> dict:
    """Line style of a governor; ``NAME@paper`` (Algorithm 1) keeps its family's colour, dotted
    thin, and ``NAME-prev`` dash-dotted."""
    from ..registry import split_rule
    from .table import family_of

    base, rule = split_rule(gov)
    family = family_of(base)
    style = dict(STYLES.get(family, dict(color="tab:purple", linestyle="-.")))
    if rule == "paper":
        style.update(linestyle=(0, (1, 1)), alpha=0.7)
    elif base != family:
        style.update(linestyle="-.")
    return style


def _label(gov: str) -> str:
    from ..registry import split_rule
    from .table import family_of

    base, rule = split_rule(gov)
    family = family_of(base)
    label = LABELS.get(family, family) + (" (τ_{k-1} input)" if base != family else "")
    return label + (" (Alg. 1)" if rule == "paper" else "")


def _legend_once(ax: plt.Axes, runs: Sequence[RunData]) -> None:
    seen: dict[str, plt.Line2D] = {}
    for gov in dict.fromkeys(r.governor for r in runs):
        seen[gov] = plt.Line2D([], [], **_style(gov), label=_label(gov))
    ax.legend(handles=list(seen.values()), loc="best", fontsize=8)


def _save(fig: plt.Figure, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def flown_title(cfg: Config) -> str:
    """``scenario leo, approach from ahead``: what a figure's runs flew."""
    return f"scenario {cfg.scenario.name}, approach from {cfg.mission.approach}"


def relative_trajectories(runs: Sequence[RunData], path: str | Path, zoom_km: float | None = None) -> Path:
    """Fig. 3a: deputy positions relative to the chief in the VNB frame, with the LoS cone.

    Two projections: along-track V against B (in-plane) and against N (out-of-plane). The cone of
    the run's half-angle (``constraints.los_half_angle_deg``) around the docking axis is shaded:
    -V from behind, +V from ahead (the port faces the approach, ``Config.side``). ``zoom_km``
    limits the axes.
    """
    cfg = runs[0].config
    alpha_deg = cfg.constraints.los_half_angle_deg
    axis = float(cfg.side)   # the cone opens along +V (ahead) or -V (behind)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), layout="constrained")
    p_all = [r.p_rel_vnb() for r in runs]
    extent = zoom_km or 1.1 * max(float(np.abs(p[:, 0]).max()) for p in p_all)
    end = axis * extent
    for ax, (j, name) in zip(axes, ((2, "B (km)"), (1, "N (km)"))):
        half = math.tan(math.radians(alpha_deg)) * extent
        ax.fill([0.0, end, end], [0.0, half, -half], color="tab:orange", alpha=0.15,
                label=f"LoS cone ({alpha_deg:g}°)")
        ax.plot([0.0, end], [0.0, half], color="tab:orange", lw=0.8)
        ax.plot([0.0, end], [0.0, -half], color="tab:orange", lw=0.8)
        for r, p in zip(runs, p_all):
            ax.plot(p[:, 0], p[:, j], lw=0.9, **_style(r.governor))
            ax.plot(p[0, 0], p[0, j], "o", ms=3, color=_style(r.governor)["color"])
        ax.plot(0, 0, "k*", ms=9, label="chief")
        ax.set_xlim(*sorted((end, -0.1 * end)))
        ax.set_ylim(-0.6 * extent, 0.6 * extent)
        ax.set_xlabel("V, along the chief's velocity (km)")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    _legend_once(axes[0], runs)
    axes[1].legend(loc="lower left" if cfg.side is Side.BEHIND else "lower right", fontsize=8)
    fig.suptitle(f"Relative trajectories of the deputy in the chief's VNB frame ({flown_title(cfg)})")
    return _save(fig, path)


def _history(runs: Sequence[RunData], path: str | Path, values: str, ylabel: str, title: str,
             log: bool = False) -> Path:
    fig, ax = plt.subplots(figsize=(7, 4))
    for r in runs:
        y = getattr(r, values)
        ax.plot(r.hours, y, lw=0.9, **_style(r.governor))
    if log:
        ax.set_yscale("log")
    ax.set_xlabel("time (h)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3, which="both")
    _legend_once(ax, runs)
    return _save(fig, path)


def tau_histories(runs: Sequence[RunData], path: str | Path) -> Path:
    """Fig. 3b: the time shift tau(t) of each run (s)."""
    return _history(runs, path, "tau", "time shift τ (s)", "Time shift histories")


def mean_tau(runs: Sequence[RunData], path: str | Path) -> Path:
    """Fig. 3c: mean of tau over the runs of each governor (s), with the 10-90 % band."""
    fig, ax = plt.subplots(figsize=(7, 4))
    for gov in dict.fromkeys(r.governor for r in runs):
        group = [r for r in runs if r.governor == gov]
        n = min(len(r.tau) for r in group)
        taus = np.array([r.tau[:n] for r in group])
        hours = group[0].hours[:n]
        st = _style(gov)
        ax.plot(hours, taus.mean(axis=0), lw=1.2, **st, label=f"{_label(gov)} (n = {len(group)})")
        if len(group) > 2:
            ax.fill_between(hours, np.percentile(taus, 10, axis=0), np.percentile(taus, 90, axis=0),
                            color=st["color"], alpha=0.12)
    ax.set_xlabel("time (h)")
    ax.set_ylabel("mean time shift E[τ] (s)")
    ax.set_title("Mean time shift over Monte Carlo runs (band: 10-90 %)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def relative_distance(runs: Sequence[RunData], path: str | Path) -> Path:
    """Fig. 3d: |p_d - p_c| (km, log scale)."""
    return _history(runs, path, "distance_km", "relative distance (km)", "Relative distance", log=True)


def relative_speed(runs: Sequence[RunData], path: str | Path) -> Path:
    """Fig. 3e: |v_d - v_c| (m/s, log scale)."""
    return _history(runs, path, "speed_mps", "relative speed (m/s)", "Relative speed", log=True)


def thrust_limit_text(cfg: Config) -> tuple[str, str]:
    """(name, text) of the limit h2 is judged against, in m/s^2: u_max, or u_lim = u_max (1 + the
    declared thruster bias bound) under a truth that declares one (``Config.thrust_limit_kmps2``)."""
    u_max, limit = 1e3 * cfg.control.u_max_kmps2, 1e3 * cfg.thrust_limit_kmps2
    if limit == u_max:
        return "u_max", f"u_max = {u_max:g} m/s²"
    return "u_lim", f"u_lim = {limit:.6g} m/s² = u_max (1 + bias {cfg.truth.bound('thrust_bias_max'):g})"


def constraint_histories(runs: Sequence[RunData], path: str | Path) -> Path:
    """Fig. 4: h1 (normalised), h2 (m/s^2) and h3 (m/s) histories; feasible is <= 0 (dashed line).
    h2 against the run's thrust limit (:func:`thrust_limit_text`), h3 within its gamma1.

    The paper shows one run here; pass one or a few runs for a readable figure.
    """
    cfg = runs[0].config
    limit = cfg.thrust_limit_kmps2
    u_name, u_text = thrust_limit_text(cfg)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2), layout="constrained")
    panels = (("h1_normalised", 1.0, "h1 / (|v_c||p_rel|)",
               f"(a) line-of-sight cone ({cfg.constraints.los_half_angle_deg:g}°)"),
              ("h2", 1e3, f"h2 = |u| - {u_name} (m/s²)", f"(b) thrust: {u_text}"),
              ("h3", 1e3, "h3 (m/s)", f"(c) approach velocity (within γ1 = {cfg.constraints.gamma1_km:g} km)"))
    for ax, (name, scale, ylabel, title) in zip(axes, panels):
        for r in runs:
            ax.plot(r.hours, getattr(r, name) * scale, lw=0.8, **_style(r.governor))
        ax.axhline(0.0, color="tab:red", lw=0.8, ls="--")
        ax.set_xlabel("time (h)")
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[1].set_ylim(-limit * 1e3 * 1.05, limit * 1e3 * 0.1)
    # h3 spans 1e-3 .. 1e5 m/s (gamma2 |p_rel| dominates far out): symmetric log scale.
    axes[2].set_yscale("symlog", linthresh=1e-3)
    _legend_once(axes[0], runs)
    fig.suptitle(f"Constraint histories (feasible: <= 0; {flown_title(cfg)})")
    return _save(fig, path)


def all_figures(runs: Sequence[RunData], out_dir: str | Path) -> dict[str, Path]:
    """Every figure of the paper's Fig. 3 and Fig. 4 into ``out_dir``: {name: path}."""
    out = Path(out_dir)
    return {
        "fig3a_relative_vnb": relative_trajectories(runs, out / "fig3a_relative_vnb.png"),
        "fig3a_relative_vnb_zoom": relative_trajectories(runs, out / "fig3a_relative_vnb_zoom.png",
                                                         zoom_km=runs[0].config.constraints.gamma1_km),
        "fig3b_tau": tau_histories(runs, out / "fig3b_tau.png"),
        "fig3c_mean_tau": mean_tau(runs, out / "fig3c_mean_tau.png"),
        "fig3d_distance": relative_distance(runs, out / "fig3d_distance.png"),
        "fig3e_speed": relative_speed(runs, out / "fig3e_speed.png"),
        "fig4_constraints": constraint_histories(runs[:1], out / "fig4_constraints.png"),
    }
