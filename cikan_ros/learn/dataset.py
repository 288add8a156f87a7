"""Labelled data for the learned governor (SPEC §7): (x_d, x_c, t) -> tau* != 0 from closed loops
of the conventional TSG started from the widened Monte Carlo distribution.

Mission ``m`` of a dataset with seed ``S`` draws everything from ``numpy.random.default_rng([S, m])``:
its position spread sigma ~ U[sigma_min, sigma_max] km, its split (train/val/test by a uniform
draw against the split fractions) and the seed of its start (``mission.sample_start``). Each
mission is one conventional closed loop (``mission.run_mission``); every active update
(tau_{k-1} != 0) whose answer tau* = pi*(x) is not 0 gives one label (tau* < 0 behind the chief,
> 0 ahead of it; the file records its scenario and approach), with the states
as the governor saw them (through SI, ``MissionResult.update_states``). The dataset is
the labels of missions 0, 1, 2, ... in order, cut at exactly N labels, so the result depends on
the seed only: not on the number of workers nor on where they run (local processes or Dask).

On-policy labels (``governor`` other than "conventional"): the named governor flies each
mission, and each of its active updates is labelled with pi* solved at the state it visited,
from the tau_{k-1} it had (``Predictor.optimal_shift``).
"""

from __future__ import annotations

import functools
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np
from numpy.typing import NDArray

from ..config import Config, config_from_flat
from ..errors import NoFeasibleShiftError
from ..governor import ConventionalGovernor
from ..mission import MissionResult, run_mission, sample_start
from ..montecarlo import process_governor
from ..parallel import ordered_map
from ..registry import make_governor
from ..tsg import Predictor
from .errors import DatasetError

#: Parquet columns: state components as the governor saw them (km, km/s, ECI), labels in s.
XD_COLS = tuple(f"xd{i}" for i in range(6))
XC_COLS = tuple(f"xc{i}" for i in range(6))
COLUMNS = ("mission", "split", "t_s", "update_k", *XD_COLS, *XC_COLS, "tau_prev_s", "tau_star_s",
           "sigma_km")
SPLITS = ("train", "val", "test")
#: Version of the label recipe, stored in the file; bump when labels change meaning.
RECIPE = "conventional-updates-v2"  # v2: adds update_k, the update index


#: The start spread of a dataset's missions, as multiples of the scenario's Monte Carlo spread
#: ``mission.mc_sigma_km``: the paper's 5-15 km around its 10 km. (A fixed 5-15 km trained the
#: first LEO and GEO models on starts 1.1-3.4x and 2.5-7.5x wider than their Monte Carlo's.)
SIGMA_SCALE = (0.5, 1.5)


def scenario_sigma_km(cfg: Config) -> tuple[float, float]:
    """(sigma_min_km, sigma_max_km) of a dataset for ``cfg``'s scenario: SIGMA_SCALE x
    mission.mc_sigma_km."""
    return SIGMA_SCALE[0] * cfg.mission.mc_sigma_km, SIGMA_SCALE[1] * cfg.mission.mc_sigma_km


@dataclass(frozen=True)
class DatasetSpec:
    """What defines a dataset besides the configuration: seed, spread of starts, split fractions."""

    seed: int = 0
    sigma_min_km: float = 5.0
    sigma_max_km: float = 15.0
    val_fraction: float = 0.05
    test_fraction: float = 0.05
    #: Fewest missions in val and in test each (when a quarter of the dataset's missions allow it):
    #: long missions give few per dataset (GEO: ~1,000 labels each, 60 in a 60,000-label set), and
    #: a split of 2-3 missions made early stopping follow noise (GEO's CIKAN stopped at 10 of 30
    #: epochs).
    min_split_missions: int = 8

    def __post_init__(self) -> None:
        if not (0.0 <= self.sigma_min_km <= self.sigma_max_km and math.isfinite(self.sigma_max_km)):
            raise DatasetError(f"need 0 <= sigma_min_km <= sigma_max_km, got "
                               f"{self.sigma_min_km}, {self.sigma_max_km}")
        if not (0.0 < self.val_fraction and 0.0 < self.test_fraction
                and self.val_fraction + self.test_fraction < 1.0):
            raise DatasetError("val and test fractions must be > 0 and sum to < 1")
        if self.seed < 0:
            raise DatasetError(f"seed must be >= 0, got {self.seed}")
        if self.min_split_missions < 1:
            raise DatasetError(f"min_split_missions must be >= 1, got {self.min_split_missions}")


def mission_plan(spec: DatasetSpec, mission: int) -> tuple[float, str, int]:
    """(sigma_km, split, start seed) of mission number ``mission``; a pure function of the spec."""
    rng = np.random.default_rng([spec.seed, mission])
    sigma = float(rng.uniform(spec.sigma_min_km, spec.sigma_max_km))
    u = float(rng.uniform())
    split = "test" if u < spec.test_fraction else "val" if u < spec.test_fraction + spec.val_fraction \
        else "train"
    start_seed = int(rng.integers(0, 2**62))
    return sigma, split, start_seed


def top_up_splits(splits: dict[int, str], least: int) -> dict[int, str]:
    """Mission -> split with val and test holding at least ``least`` missions each, capped at a
    quarter of the missions: the missions :func:`mission_plan` drew, and where val or test is
    short, the highest-numbered train missions moved there (val first, then test). A dataset
    with enough missions keeps its draw unchanged."""
    out = dict(splits)
    want = min(least, len(out) // 4)
    for split in ("val", "test"):
        short = want - sum(1 for v in out.values() if v == split)
        for m in sorted((m for m, v in out.items() if v == "train"), reverse=True)[:max(short, 0)]:
            out[m] = split
    return out


def update_labels(res: MissionResult, predictor: Predictor | None = None) -> dict[str, NDArray]:
    """Labels of one mission: every active update (tau_{k-1} != 0) with tau* != 0.

    States are those the governor was given (through SI; ``MissionResult.update_states``, as the
    benchmark takes them). Without ``predictor`` the mission is the conventional TSG's and tau* is
    its answer, i.e. pi* over [tau_{k-1}, 0]; with it, tau* = pi* is solved at each state from the
    governor's own tau_{k-1} (on-policy labels of any governor).
    """
    states = res.update_states()
    stars = [s.tau if predictor is None else predictor.optimal_shift(s.x_d, s.t, s.tau_prev)[0]
             for s in states]
    keep = [(s, star) for s, star in zip(states, stars) if star != 0.0]
    n = len(keep)
    return {
        "t_s": np.array([s.t for s, _ in keep], dtype=float),
        "update_k": np.array([s.k for s, _ in keep], dtype=np.int64),
        "x_d": np.array([s.x_d for s, _ in keep], dtype=float).reshape(n, 6),
        "x_c": np.array([s.x_c for s, _ in keep], dtype=float).reshape(n, 6),
        "tau_prev_s": np.array([s.tau_prev for s, _ in keep], dtype=float),
        "tau_star_s": np.array([star for _, star in keep], dtype=float),
    }


_PREDICTORS: dict[str, Predictor] = {}


def _predictor(cfg_json: str) -> Predictor:
    """One Predictor per configuration per process (workers reuse it across tasks)."""
    pred = _PREDICTORS.get(cfg_json)
    if pred is None:
        pred = Predictor.from_config(config_from_flat(json.loads(cfg_json)))
        _PREDICTORS[cfg_json] = pred
    return pred


def label_missions(cfg_json: str, spec: DatasetSpec, missions: Sequence[int],
                   governor: str = "conventional") -> list[dict[str, Any]]:
    """Run the given missions with ``governor`` and return their labels, one dict per mission (in
    order).

    Top-level and argument-only so local processes and Dask workers can run it.
    """
    pred = _predictor(cfg_json)
    gov = ConventionalGovernor(pred) if governor == "conventional" else process_governor(cfg_json, governor)
    out = []
    for m in missions:
        sigma, split, start_seed = mission_plan(spec, m)
        try:  # a start may have no feasible shift (nominal admissibility, then robust Verify)
            res = run_mission(gov, sample_start(pred, start_seed, sigma), start_seed)
        except NoFeasibleShiftError:
            out.append({"mission": m, "split": split, "sigma_km": sigma, "n": 0})
            continue
        lab = update_labels(res, None if governor == "conventional" else pred)
        out.append({"mission": m, "split": split, "sigma_km": sigma, "n": len(lab["t_s"]), **lab})
    return out


def _chunks(size: int) -> Iterator[list[int]]:
    """Mission ids 0, 1, 2, ... in lists of ``size`` (an unbounded task stream)."""
    m = 0
    while True:
        yield list(range(m, m + size))
        m += size


def generate(cfg: Config, n_labels: int, spec: DatasetSpec, workers: int = 1,
             dask_address: str | None = None, chunk: int = 4, progress: bool = False,
             governor: str = "conventional") -> tuple["Any", dict[str, Any]]:
    """Generate exactly ``n_labels`` labels. Returns (pandas DataFrame, metadata).

    ``workers`` local processes (1: in this process) or the Dask cluster at ``dask_address``;
    ``governor`` flies the missions (on-policy labels when it is not the conventional TSG);
    ``progress``: show a progress bar (:mod:`cikan_ros.progress`).
    """
    import pandas as pd

    from ..progress import Bar

    if n_labels < 1:
        raise DatasetError(f"--labels must be >= 1, got {n_labels}")
    if workers < 1:
        raise DatasetError(f"--workers must be >= 1, got {workers}")
    cfg_json = json.dumps(cfg.flat(), sort_keys=True)
    if governor != "conventional":
        make_governor(governor, cfg)  # a bad name or model file fails here, before any worker starts
    start = time.perf_counter()
    # Chunks of missions, in mission order, on this process, local processes or Dask.
    stream = ordered_map(functools.partial(label_missions, cfg_json, spec, governor=governor),
                         _chunks(chunk), workers, dask_address)
    parts: list[dict[str, Any]] = []
    total = 0
    n_missions = 0
    with Bar(n_labels, "cikan dataset", "labels", progress) as bar:
        try:
            for res in (r for chunk_results in stream for r in chunk_results):
                n_missions += 1
                take = min(res["n"], n_labels - total)
                if take > 0:
                    parts.append({**res, "n": take})
                    total += take
                    bar.advance(take)
                if total >= n_labels:
                    break
        finally:
            stream.close()  # cancels what is still pending and releases the workers
    wall = time.perf_counter() - start
    splits = top_up_splits({p["mission"]: p["split"] for p in parts}, spec.min_split_missions)
    cols: dict[str, Any] = {c: [] for c in COLUMNS}
    for p in parts:
        n = p["n"]
        cols["mission"].append(np.full(n, p["mission"], dtype=np.int64))
        cols["split"].append(np.full(n, splits[p["mission"]], dtype=object))
        cols["t_s"].append(p["t_s"][:n])
        cols["update_k"].append(p["update_k"][:n])
        for i in range(6):
            cols[XD_COLS[i]].append(p["x_d"][:n, i])
            cols[XC_COLS[i]].append(p["x_c"][:n, i])
        cols["tau_prev_s"].append(p["tau_prev_s"][:n])
        cols["tau_star_s"].append(p["tau_star_s"][:n])
        cols["sigma_km"].append(np.full(n, p["sigma_km"]))
    df = pd.DataFrame({c: np.concatenate(v) for c, v in cols.items()})
    df["split"] = df["split"].astype(str)
    meta = {
        "recipe": RECIPE,
        "governor": governor,
        "scenario": cfg.scenario.name,
        "approach": cfg.mission.approach,
        "labels": int(len(df)),
        "missions": n_missions,
        "seed": spec.seed,
        "sigma_min_km": spec.sigma_min_km,
        "sigma_max_km": spec.sigma_max_km,
        "val_fraction": spec.val_fraction,
        "test_fraction": spec.test_fraction,
        "min_split_missions": spec.min_split_missions,
        "split_missions": {sp: sum(1 for v in splits.values() if v == sp) for sp in SPLITS},
        "split_labels": {s: int((df["split"] == s).sum()) for s in SPLITS},
        "wall_s": wall,
        "labels_per_s": len(df) / wall if wall > 0 else None,
        "workers": workers if not dask_address else f"dask:{dask_address}",
        "config": cfg.flat(),
    }
    return df, meta


def write_parquet(df: "Any", meta: dict[str, Any], path: str | Path) -> Path:
    """Write the labels with the metadata as JSON under the schema key ``cikan``."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    table = pa.Table.from_pandas(df, preserve_index=False)
    table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                          b"cikan": json.dumps(meta).encode()})
    tmp = p.with_name(p.name + ".tmp")
    pq.write_table(table, tmp)
    tmp.replace(p)
    return p


def read_parquet(path: str | Path) -> tuple["Any", dict[str, Any]]:
    """(DataFrame, metadata) of a dataset written by :func:`write_parquet`; checks the columns."""
    import pyarrow.parquet as pq

    p = Path(path)
    if not p.exists():
        raise DatasetError(f"dataset not found: {p}")
    try:
        table = pq.read_table(p)
    except Exception as exc:  # pyarrow raises several types for damaged files
        raise DatasetError(f"dataset {p} is not a readable Parquet file: {exc}") from None
    missing = [c for c in COLUMNS if c not in table.column_names]
    if missing:
        raise DatasetError(f"dataset {p} lacks columns {missing}")
    raw = (table.schema.metadata or {}).get(b"cikan")
    meta = json.loads(raw) if raw else {}
    return table.to_pandas(), meta
