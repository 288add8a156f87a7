"""Coverage of robust Verify's tube: does the truth stay where the tube says it can be?

The TSG's safety argument is that a shift in force was verified when it was set and is never
re-verified while it is held. So the check takes the first-instant shift robust Verify accepts
from the measured start, holds it for the whole mission (no update), flies the truth (a corner of
the declared bounds, or the run's random draw) and compares, sample by sample, the truth with
the prediction that Verify made when it accepted the shift:

- before the terminal sample (where Verify accepted the terminal set): |p_truth - p_pred| / rho_j
  and |v_truth - v_pred| / sigma_j;
- from the terminal sample on: |x_truth - x_v| against the terminal ball's radii, x_v the
  virtual target the controller tracks (under the ancillary tube, the ball certified for that
  sample, which shrinks as the loop settles: robust.terminal_ball_after).

A ratio above 1 is a sample where the tube is not a bound (docs/robustness.md, "Coverage").
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .ancillary import terminal_balls
from .config import Config
from .errors import ConfigError
from .governor import PATH_KEEP, Governor, UpdateRecord
from .mission import ClosedLoop, run_mission, sample_start, through_si
from .robust import HANDOFF_FTRE
from .registry import make_governor
from .truth import Truth


class HeldShift:
    """A governor that takes ``governor``'s first-instant shift and holds it for good: every
    update answers tau_prev without prediction (the held shift of the TSG's safety argument)."""

    def __init__(self, governor: Governor) -> None:
        self.inner = governor
        self.name = f"{governor.name}-held"
        self.predictor = governor.predictor
        self.anchor = governor.anchor

    def initial(self, x_d: ArrayLike, x_c: ArrayLike, t: float) -> UpdateRecord:
        return self.inner.initial(x_d, x_c, t)

    def update(self, x_d: ArrayLike, x_c: ArrayLike, t: float, tau_prev: float) -> UpdateRecord:
        return UpdateRecord(tau_prev, PATH_KEEP, 0, 0.0, tau_prev=tau_prev)


@dataclass(frozen=True)
class Coverage:
    """One held-shift flight against its tube. Ratios are maxima over the samples (NaN: none);
    ``*_sample`` the sample index (control step) of the maximum; ``terminal_sample`` where Verify
    accepted the terminal set (-1: the shift was not accepted). ``violations``: the truth's
    violating control steps (h1, h2, h3) over the whole mission."""

    seed: int
    corner: str
    tau_s: float
    pos_ratio: float
    vel_ratio: float
    pos_sample: int
    vel_sample: int
    terminal_sample: int
    ball_pos_ratio: float
    ball_vel_ratio: float
    ball_sample: int
    violations: int
    #: pos / rho at sample 0, the measured start (NaN: the shift was not accepted).
    first_pos_ratio: float = math.nan

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def worst(self) -> float:
        """The largest of the four ratios (NaN ratios ignored)."""
        vals = [v for v in (self.pos_ratio, self.vel_ratio, self.ball_pos_ratio, self.ball_vel_ratio)
                if math.isfinite(v)]
        return max(vals) if vals else math.nan


def _max_at(ratios: np.ndarray, offset: int = 0) -> tuple[float, int]:
    if ratios.size == 0 or not np.any(np.isfinite(ratios)):
        return math.nan, -1
    i = int(np.nanargmax(ratios))
    return float(ratios[i]), i + offset


def held_shift_coverage(cfg: Config, seed: int, governor: str = "conventional") -> Coverage:
    """Fly Monte Carlo start ``seed`` in the truth of ``cfg`` (its corner when ``truth.draw`` is
    corner) with ``governor``'s first-instant shift held, and compare it with robust Verify's tube
    (module docstring). ConfigError unless ``cfg`` flies robust Verify."""
    if not cfg.tsg.robust:
        raise ConfigError("the coverage check compares the truth with robust Verify's tube: "
                          "set tsg.robust (--robust)")
    gov = make_governor(governor, cfg)
    pred = gov.predictor
    held = HeldShift(gov)
    x0 = sample_start(pred, seed)
    truth = Truth(cfg, seed, round(cfg.mission.duration_s / cfg.control.period_s))
    result = run_mission(held, x0, truth=truth)
    tau = float(result.tau[0])
    # Verify's own prediction at the first instant, from what the governor saw.
    x_seen0 = through_si(result.x_d_seen[0] if result.x_d_seen is not None else result.x_d[0])
    xc_seen0 = through_si(result.x_c_seen[0] if result.x_c_seen is not None else result.x_c[0])
    anchored = ClosedLoop(pred).anchor(xc_seen0, 0.0)
    ok, trace = anchored.rollout_trace(x_seen0, 0.0, tau)
    corner = cfg.truth.corner if cfg.truth.draw == "corner" else "random"
    violations = int(result.metrics()["violations"])
    if not ok:
        return Coverage(seed, corner, tau, math.nan, math.nan, -1, -1, -1, math.nan, math.nan, -1,
                        violations)
    term = int(np.flatnonzero(trace[:, 8] >= HANDOFF_FTRE)[0])
    flown = min(term, len(result.x_d))  # a prediction may reach its terminal set after the mission
    err_p = np.linalg.norm(result.x_d[:flown, :3] - trace[:flown, :3], axis=1)
    err_v = np.linalg.norm(result.x_d[:flown, 3:] - trace[:flown, 3:6], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        pos, pos_at = _max_at(err_p / trace[:flown, 6])
        vel, vel_at = _max_at(err_v / trace[:flown, 7])
    # After it: the virtual target the controller tracks (its own anchor on the measured chief).
    loop = ClosedLoop(pred)
    seen_c = result.x_c if result.x_c_seen is None else result.x_c_seen
    k_end = len(result.t) - 1
    ball = np.full((max(0, k_end + 1 - term), 2), math.nan)
    # The terminal test's ball; under the ancillary tube the ball it certifies for each later
    # sample, which shrinks as the loop settles (robust.terminal_ball_after: the docking test).
    radii = np.broadcast_to(trace[term, 6:8], ball.shape)
    if pred.ancillary and len(ball):
        radii = terminal_balls(pred, trace[term], len(ball) - 1, anchored.band(x_seen0, 0.0))
    for i, k in enumerate(range(term, k_end + 1)):
        t = float(result.t[k])
        x_v = loop.anchor(through_si(seen_c[k]), t).orbit.state(t + tau)
        ball[i, 0] = np.linalg.norm(result.x_d[k, :3] - x_v[:3]) / radii[i, 0]
        ball[i, 1] = np.linalg.norm(result.x_d[k, 3:] - x_v[3:]) / radii[i, 1]
    bp, bp_at = _max_at(ball[:, 0], term)
    bv, bv_at = _max_at(ball[:, 1], term)
    worst_at = bp_at if not math.isfinite(bv) or (math.isfinite(bp) and bp >= bv) else bv_at
    return Coverage(seed, corner, tau, pos, vel, pos_at, vel_at, term, bp, bv, worst_at, violations,
                    float(err_p[0] / trace[0, 6]))


#: The scenarios and sides of the sweep (``cikan coverage --sweep``, ``make coverage``).
SWEEP = tuple((s, a) for s in ("paper", "leo", "geo") for a in ("behind", "ahead"))


def _flight(task: tuple[Config, int, str]) -> dict[str, Any]:
    """One held-shift flight (a worker's task): the :class:`Coverage` as a dict, or the error."""
    cfg, seed, governor = task
    try:
        return held_shift_coverage(cfg, seed, governor).as_dict()
    except ConfigError:
        raise
    except Exception as exc:  # a start robust Verify refuses, reported in the table as such
        corner = cfg.truth.corner if cfg.truth.draw == "corner" else "random"
        return {"seed": seed, "corner": corner, "error": str(exc).splitlines()[0]}


def coverage_tasks(cfg: Config, seeds: list[int], corners_too: bool,
                   governor: str = "conventional") -> list[tuple[Config, int, str]]:
    """Every (configuration, seed, governor) of a coverage campaign: the seeds' random draws
    and, with ``corners_too``, every corner of the declared bounds on the same seeds."""
    from .config import corners

    configs = [cfg]
    if corners_too:
        configs += [cfg.replace(**{"truth.draw": "corner", "truth.corner": c.name})
                    for c in corners(cfg.truth)]
    return [(c, s, governor) for c in configs for s in seeds]


#: A ratio within this of 1 is the bound itself: the errors are differences of ECI positions
#: (~1e4 km, measured through the SI conversion the nodes use), whose rounding, ~1e-12 of the
#: ~0.5-km navigation bound at 100 km, shows at the first sample, where the truth sits on the
#: bound at a navigation corner (measured: 1 + 3e-13).
ROUNDING = 1e-9


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per corner ("random" for the draws): flights, refused starts, and the largest ratios with
    the seed and sample where they occurred; ``covered``: something flew and every ratio is
    <= 1 (to :data:`ROUNDING`); ``flown``: flights not refused."""
    out: dict[str, dict[str, Any]] = {}
    for r in rows:
        s = out.setdefault(r["corner"], {"corner": r["corner"], "flights": 0, "refused": 0,
                                         "violations": 0, "pos_ratio": 0.0, "vel_ratio": 0.0,
                                         "ball_pos_ratio": 0.0, "ball_vel_ratio": 0.0, "worst_at": ""})
        s["flights"] += 1
        if "error" in r:
            s["refused"] += 1
            continue
        s["violations"] += r["violations"]
        for key, at in (("pos_ratio", "pos_sample"), ("vel_ratio", "vel_sample"),
                        ("ball_pos_ratio", "ball_sample"), ("ball_vel_ratio", "ball_sample")):
            v = r[key]
            if math.isfinite(v) and v > s[key]:
                s[key] = v
                if key in ("pos_ratio", "vel_ratio") and v >= max(s["pos_ratio"], s["vel_ratio"]):
                    s["worst_at"] = f"seed {r['seed']}, sample {r[at]}"
    for s in out.values():
        s["flown"] = s["flights"] - s["refused"]
        s["covered"] = s["flown"] > 0 and all(s[k] <= 1.0 + ROUNDING for k in ("pos_ratio", "vel_ratio",
                                                                             "ball_pos_ratio", "ball_vel_ratio"))
    return list(out.values())


def markdown(sections: list[tuple[str, list[dict[str, Any]]]], command: str) -> str:
    """The coverage page: per scenario and side, the worst corner, the random draws, and how many
    corners the tube covers, then the full per-corner table."""
    lines = ["# Coverage of robust Verify's tube at the corners of the declared bounds", "",
             f"Regenerate: `{command}` (docs/robustness.md, \"Coverage\"). Each flight holds the first-instant",
             "shift of the conventional TSG under robust Verify for the whole mission and compares the truth",
             "with Verify's prediction: position and velocity error over the tube radii rho_j, sigma_j up to",
             "the terminal sample, then the distance to the virtual target over the terminal ball (the ancillary",
             "tube: the ball certified for that sample, which shrinks as the loop settles). A ratio",
             "above 1 is a sample where the tube is not a bound (a corner counts as covered when some of its",
             f"flights flew and every ratio is <= 1 to {ROUNDING:g}, the rounding of the ECI positions the errors",
             "are measured from); \"-\": every flight refused.", "",
             "| scenario, side | corners covered | worst corner | pos / rho | vel / sigma | at | random draws: pos / rho, vel / sigma | terminal ball, worst | refused | violations |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for title, summary in sections:
        corners_ = [s for s in summary if s["corner"] != "random"]
        rand = next((s for s in summary if s["corner"] == "random"), None)
        flown = [s for s in corners_ or summary if s["flown"]]
        refused = sum(s["refused"] for s in summary)
        violations = sum(s["violations"] for s in summary)
        if not flown:   # every start refused: nothing to compare
            lines.append(f"| {title} | 0 / {len(corners_)} | - | - | - | - | - | - | {refused} | {violations} |")
            continue
        worst = max(flown, key=lambda s: max(s["pos_ratio"], s["vel_ratio"]))
        ball = max(max(s["ball_pos_ratio"], s["ball_vel_ratio"]) for s in summary if s["flown"])
        rand_txt = f"{rand['pos_ratio']:.2f}, {rand['vel_ratio']:.2f}" if rand and rand["flown"] else "-"
        lines.append(f"| {title} | {sum(s['covered'] for s in corners_)} / {len(corners_)} | `{worst['corner']}` | "
                     f"{worst['pos_ratio']:.2f} | {worst['vel_ratio']:.2f} | {worst['worst_at']} | {rand_txt} | "
                     f"{ball:.2f} | {refused} | {violations} |")
    for title, summary in sections:
        lines += ["", f"## {title}", "", "| corner | flights | refused | pos / rho | vel / sigma | worst at | ball pos | ball vel | violations |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for s in sorted(summary, key=lambda s: -max(s["pos_ratio"], s["vel_ratio"])):
            if not s["flown"]:
                lines.append(f"| `{s['corner']}` | {s['flights']} | {s['refused']} | - | - | - | - | - | "
                             f"{s['violations']} |")
                continue
            lines.append(f"| `{s['corner']}` | {s['flights']} | {s['refused']} | {s['pos_ratio']:.2f} | "
                         f"{s['vel_ratio']:.2f} | {s['worst_at']} | {s['ball_pos_ratio']:.2f} | "
                         f"{s['ball_vel_ratio']:.2f} | {s['violations']} |")
    return "\n".join(lines) + "\n"
