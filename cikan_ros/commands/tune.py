"""``cikan tune``: Optuna TPE search (with pruning) of a family's size and training settings."""

from __future__ import annotations

import argparse

from ..learn.features import FEATURE_SETS
from ..strict_json import dumps
from . import add_config_args, config_from_args, seed_arg


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tune", help="hyper-parameter search (Optuna TPE + pruning)",
                       description="Add trials to the Optuna study of a model family. Several "
                                   "processes or machines can share one study through --storage.")
    p.add_argument("--model", required=True, choices=("cikan", "grbf", "rswaf", "relu", "gelu"))
    p.add_argument("--trials", type=int, required=True, help="trials to run in this process")
    p.add_argument("--storage", default="sqlite:///runs/tune.sqlite3", metavar="URL",
                   help="Optuna storage URL (default: a SQLite file under runs/)")
    p.add_argument("--study-name", default=None,
                   help="study name (default cikan-tsg-MODEL[-FEATURES][-SCENARIO-APPROACH], the one "
                        "`cikan train --study` looks for)")
    p.add_argument("--data", default="runs/dataset.parquet", metavar="PATH", help="dataset (Parquet)")
    p.add_argument("--features", default="vnb", choices=FEATURE_SETS)
    p.add_argument("--epochs", type=int, default=8, help="epochs per trial (schedule length)")
    p.add_argument("--max-train", type=int, default=40000, help="training labels per trial (0: all)")
    p.add_argument("--trial-minutes", type=float, default=2.0, help="wall budget per trial")
    p.add_argument("--timeout", type=float, default=None, help="stop starting trials after S seconds")
    p.add_argument("--seed", type=seed_arg, default=None, help="sampler seed")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    p.add_argument("--json", action="store_true", help="print the study summary as JSON")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..learn.errors import DatasetError
    from ..learn.train import load_data
    from ..learn.tune import run_tune

    if args.trials < 1:
        raise DatasetError("--trials must be >= 1")
    if args.storage.startswith("sqlite:///"):
        Path(args.storage[len("sqlite:///"):]).parent.mkdir(parents=True, exist_ok=True)
    data = load_data(args.data, args.features)
    from ..learn.modelfile import check_dataset_scenario

    cfg = config_from_args(args)
    check_dataset_scenario(data.meta, data.path, cfg.scenario.name, cfg.mission.approach)
    if args.study_name is None:
        from ..learn.tune import study_name_for

        args.study_name = study_name_for(args.model, args.features, cfg.scenario.name, cfg.mission.approach)
    summary = run_tune(args.model, data, args.trials, args.storage, args.study_name, args.epochs,
                       args.max_train, args.trial_minutes, args.seed, args.threads, args.timeout)
    if args.json:
        print(dumps(summary))
    else:
        print(f"study {summary['study']}: {summary['trials']} trials ({summary['complete']} complete, "
              f"{summary['pruned']} pruned, {summary['failed']} failed)")
        if "best_value" in summary:
            print(f"  best val loss (theta_c=1) {summary['best_value']:.4e}, trial "
                  f"{summary['best_trial']}: {summary['best_params']}")
    return 0
