"""Monte Carlo evaluation (SPEC §6, §9): many missions from seeded starts, for one or more governors.

Run i of a campaign with base seed S starts from ``sample_start(seed = S + i)``, so every governor
flies the same starts and ``cikan mission --seed S+i`` replays one run. Each run leaves
``<out>/<governor>/seed_<n>.json`` (metrics and the configuration) and ``seed_<n>.npz`` (the
trajectory, constraint values and update records; numpy arrays only, loaded without pickle), so
tables can be rebuilt without re-running; a result whose configuration matches is reused.

A corner campaign (``corners=True``) flies every corner of the truth's declared bounds
(:func:`cikan_ros.config.corners`) on the same starts: the run of corner C is
``<out>/<C>/<governor>/seed_<n>.json``, its metrics labelled ``corner``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .config import Config, config_from_flat, corners
from .errors import CikanError, NoFeasibleShiftError
from .governor import Governor, warm_up
from .learn.governor import nn_accept_rate
from .mission import MissionResult, nominal_start, run_mission, sample_start
from .parallel import ordered_map
from .progress import Bar
from .registry import GOVERNOR_NAMES, make_governor
from .robust import UnstableLoopError
from .truth import Truth

_GOVERNORS: dict[tuple[str, str], Governor] = {}


@dataclass(frozen=True)
class RunTask:
    """One Monte Carlo run, as sent to a worker (plain data, picklable)."""

    config_json: str
    governor: str
    seed: int
    out_dir: str


def governor_label(name: str) -> str:
    """Directory name of a governor: its name, or the stem of a model path; a stem that names a
    governor (models/leo/cikan) takes its parent's name in front (leo-cikan), so it does not
    share the directory of the shipped model flown beside it."""
    if not ("/" in name or name.endswith(".safetensors")):
        return name
    p = Path(name)
    stem = p.name.removesuffix(".safetensors")
    return f"{p.parent.name}-{stem}" if stem in GOVERNOR_NAMES and p.parent.name else stem


def run_paths(out_dir: str | Path, governor: str, seed: int) -> tuple[Path, Path]:
    base = Path(out_dir) / governor_label(governor) / f"seed_{seed:05d}"
    return base.with_suffix(".json"), base.with_suffix(".npz")


def save_run(res: MissionResult, seed: int, json_path: Path, npz_path: Path,
             foreign: str | None = None) -> dict[str, Any]:
    """Write a run's metrics (JSON) and arrays (npz); return the metrics (with ``nn_accept_rate``
    where a learned governor flew, and ``foreign_model``, what its model was made for when it was
    flown with ``learned.foreign_model``, as ``cikan mission`` reports them)."""
    metrics = res.metrics()
    metrics["seed"] = seed
    if res.governor != "conventional":
        metrics["nn_accept_rate"] = nn_accept_rate(res.updates)
    if foreign:
        metrics["foreign_model"] = foreign
    json_path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        npz_path, t=res.t, x_d=res.x_d, x_c=res.x_c, u=res.u, tau=res.tau,
        h1=res.margins.h1, h1_normalised=res.margins.h1_normalised, h2=res.margins.h2, h3=res.margins.h3,
        update_t=res.update_t, update_tau=np.array([r.tau_s for r in res.updates]),
        update_k=np.array([r.k for r in res.updates], dtype=np.int64),
        update_tau_prev=np.array([r.tau_prev for r in res.updates]),
        update_path=np.array([r.path for r in res.updates], dtype=str),
        update_wall_s=np.array([r.wall_s for r in res.updates]),
        update_verify_calls=np.array([r.verify_calls for r in res.updates]),
        initial=np.array([res.initial.tau_s, res.initial.wall_s, res.initial.verify_calls]))
    tmp = json_path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps({"metrics": metrics, "config": res.config.flat()}, indent=1))
    tmp.replace(json_path)  # the JSON appears last and atomically: it marks a complete run
    return metrics


def load_run_arrays(npz_path: str | Path) -> dict[str, np.ndarray]:
    """A run's arrays (no pickle)."""
    with np.load(npz_path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


#: Parameters of how the truth draws its errors: the governor does not know them (a corner
#: campaign's governors are one per configuration of the bounds, whatever the corner).
_DRAW_KEYS = ("truth.draw", "truth.corner", "truth.corner_fraction")


def process_governor(config_json: str, name: str) -> Governor:
    """The governor ``name`` under a configuration (flat JSON), made once per worker process and
    warmed up, so that no run pays for loading the kernels or the network."""
    flat = {k: v for k, v in json.loads(config_json).items() if k not in _DRAW_KEYS}
    key = (json.dumps(flat, sort_keys=True), name)
    gov = _GOVERNORS.get(key)
    if gov is None:
        gov = _GOVERNORS[key] = make_governor(name, config_from_flat(flat))
        warm_up(gov, nominal_start(gov.predictor), gov.predictor.orbit.state(0.0))
    return gov


def run_one(task: RunTask) -> dict[str, Any]:
    """Fly one Monte Carlo run (or reuse its stored result); return its metrics."""
    json_path, npz_path = run_paths(task.out_dir, task.governor, task.seed)
    flat = json.loads(task.config_json)
    if json_path.exists():
        try:
            stored = json.loads(json_path.read_text())
            if stored.get("config") == flat and ("refused" in stored["metrics"] or npz_path.exists()):
                return stored["metrics"]
        except (json.JSONDecodeError, KeyError):
            pass  # an unreadable result is flown again
    try:
        gov = process_governor(task.config_json, task.governor)
        x0 = sample_start(gov.predictor, task.seed)
        truth = Truth(config_from_flat(flat), task.seed)   # the run's draws (or its corner)
        return save_run(run_mission(gov, x0, task.seed, truth), task.seed, json_path, npz_path,
                        getattr(gov, "foreign", None))
    except (NoFeasibleShiftError, UnstableLoopError) as exc:
        # Robust Verify refuses the start (no feasible shift) or the declared bounds (no tube):
        # a result of the campaign, not a failure of it.
        return save_refused(task, str(exc), json_path, npz_path)


def save_refused(task: RunTask, reason: str, json_path: Path, npz_path: Path | None = None) -> dict[str, Any]:
    """Record a run the governor refused to fly (``refused``: the one-line reason); the arrays of
    a run flown there before under another configuration go (they are not this run's)."""
    flat = json.loads(task.config_json)
    metrics = {"governor": governor_label(task.governor), "seed": task.seed, "refused": reason,
               "success": False}
    if flat.get("truth.draw") == "corner":
        metrics["corner"] = flat["truth.corner"]
    json_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = json_path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps({"metrics": metrics, "config": flat}, indent=1))
    tmp.replace(json_path)
    if npz_path is not None:
        npz_path.unlink(missing_ok=True)
    return metrics


def campaign_variants(cfg: Config, out_dir: str | Path, at_corners: bool = False
                      ) -> list[tuple[Config, Path]]:
    """The configurations a campaign flies and where their runs go: ``cfg`` into ``out_dir``,
    or with ``at_corners`` every corner of its truth's bounds into ``out_dir/<corner>``."""
    if not at_corners:
        return [(cfg, Path(out_dir))]
    return [(cfg.replace(**{"truth.draw": "corner", "truth.corner": c.name}), Path(out_dir) / c.name)
            for c in corners(cfg.truth)]


def run_campaign(cfg: Config, governors: list[str], runs: int, seed: int, out_dir: str | Path,
                 workers: int = 1, dask_address: str | None = None, progress: bool = False,
                 at_corners: bool = False) -> dict[str, list[dict[str, Any]]]:
    """All runs of all governors: {governor label: [metrics of run 0 .. runs-1]}; with
    ``at_corners``, of every corner in turn (each run's metrics name its ``corner``);
    ``progress``: show a progress bar (:mod:`cikan_ros.progress`)."""
    if runs < 1:
        raise CikanError(f"--runs must be >= 1, got {runs}")
    tasks = [RunTask(json.dumps(c.flat(), sort_keys=True), g, seed + i, str(d))
             for c, d in campaign_variants(cfg, out_dir, at_corners)
             for g in governors for i in range(runs)]
    out: dict[str, list[dict[str, Any]]] = {governor_label(g): [] for g in governors}
    results: Iterator[dict[str, Any]] = ordered_map(run_one, tasks, workers, dask_address)
    with Bar(len(tasks), "cikan montecarlo", "runs", progress) as bar:
        for task, metrics in zip(tasks, results):
            out[governor_label(task.governor)].append(metrics)
            bar.advance()
    return out


def between_total(runs: list[dict[str, Any]]) -> int | None:
    """Truth states violating between samples over flown runs (None: some run was stored
    before the truth was judged between samples)."""
    between = [r.get("violations_between") for r in runs]
    return None if None in between else sum(int(b) for b in between)


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Campaign figures of one governor (SPEC §9): success count, violations, dV, margins, times,
    over the runs it flew; ``refused``: runs it refused (no feasible start under robust Verify)."""
    refused = sum(1 for r in runs if "refused" in r)
    runs = [r for r in runs if "refused" not in r]
    if not runs:
        return {"runs": 0, "refused": refused, "successes": 0, "violations": 0, "violations_between": 0}

    def col(key: str) -> np.ndarray:
        return np.array([r[key] for r in runs if r.get(key) is not None], dtype=float)


    dv = col("delta_v_kmps")
    n_updates = col("updates")
    n_active = col("active_updates")
    # Means over all updates of all runs: weight each run's mean by its number of updates.
    mean_all = float((col("update_ms_mean") * n_updates).sum() / n_updates.sum()) if n_updates.sum() else 0.0
    mean_active = (float((col("active_update_ms_mean") * n_active).sum() / n_active.sum())
                   if n_active.sum() else 0.0)

    def weighted(key: str, n: np.ndarray) -> float:
        v = col(key)
        return float((v * n).sum() / n.sum()) if v.size == n.size and n.sum() else math.nan
    return {
        "runs": len(runs),
        "refused": refused,
        "successes": int(sum(bool(r["success"]) for r in runs)),
        "violations": int(col("violations").sum()),
        "violations_between": between_total(runs),
        "delta_v_kmps_mean": float(dv.mean()),
        "delta_v_kmps_std": float(dv.std(ddof=1)) if dv.size > 1 else 0.0,
        "delta_v_kmps_max": float(dv.max()),
        "min_h1_margin": float(col("min_h1_margin").min()),
        "max_h3": float(col("max_h3").max()) if col("max_h3").size else math.nan,
        "nn_accept_rate_mean": float(col("nn_accept_rate").mean()) if col("nn_accept_rate").size else math.nan,
        "tau0_s_mean": float(col("tau0_s").mean()),
        "t_tau_zero_s_mean": float(col("t_tau_zero_s").mean()) if col("t_tau_zero_s").size else math.nan,
        "t_tau_zero_s_max": float(col("t_tau_zero_s").max()) if col("t_tau_zero_s").size else math.nan,
        "final_distance_m_max": float(col("final_distance_m").max()),
        "update_ms_mean": mean_all,
        "update_ms_max": float(col("update_ms_max").max()),
        "active_update_ms_mean": mean_active,
        "active_update_ms_max": float(col("active_update_ms_max").max()),
        "update_cpu_ms_mean": weighted("update_cpu_ms_mean", n_updates),
        "update_cpu_ms_max": float(col("update_cpu_ms_max").max()) if col("update_cpu_ms_max").size else math.nan,
        "active_update_cpu_ms_mean": weighted("active_update_cpu_ms_mean", n_active),
        "active_update_cpu_ms_max": (float(col("active_update_cpu_ms_max").max())
                                     if col("active_update_cpu_ms_max").size else math.nan),
        "initial_ms_mean": float(col("initial_ms").mean()),
        "initial_ms_max": float(col("initial_ms").max()),
    }


def markdown_summary(summaries: dict[str, dict[str, Any]]) -> str:
    """A Markdown table of campaign figures, one row per governor (h3 in m/s; NN accept: the
    mean over runs of ``nn_accept_rate``, where a learned governor flew)."""
    head = ("| governor | runs | success | violations | between samples | ΔV mean (km/s) | ΔV max "
            "| min h1 margin | max h3 (m/s) | NN accept | update ms mean / max | active ms mean / max |")
    lines = [head, "|" + "---|" * 12]

    def num(v: float | None, fmt: str, scale: float = 1.0) -> str:
        return "-" if v is None or not math.isfinite(v) else format(v * scale, fmt)

    for g, s in summaries.items():
        if not s["runs"]:
            lines.append(f"| {g} | 0 ({s['refused']} refused) | 0 | 0 | 0 | - | - | - | - | - | - | - |")
            continue
        between = "-" if s["violations_between"] is None else s["violations_between"]
        lines.append(
            f"| {g} | {s['runs']}{f' ({r} refused)' if (r := s['refused']) else ''} | {s['successes']} "
            f"| {s['violations']} | {between} | {s['delta_v_kmps_mean']:.4f} "
            f"| {s['delta_v_kmps_max']:.4f} | {s['min_h1_margin']:.2e} | {num(s['max_h3'], '.2e', 1e3)} "
            f"| {num(s.get('nn_accept_rate_mean'), '.3f')} "
            f"| {s['update_ms_mean']:.3f} / {s['update_ms_max']:.2f} "
            f"| {s['active_update_ms_mean']:.3f} / {s['active_update_ms_max']:.2f} |")
    return "\n".join(lines) + "\n"
