"""``cikan dataset``: labels tau* = pi*(x_d, x_c) from conventional-TSG missions (or on-policy, from
another governor's), as Parquet."""

from __future__ import annotations

import argparse

from ..strict_json import dumps
from . import add_config_args, config_from_args, seed_arg


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("dataset", help="generate labelled data for the learned governor (Parquet)",
                       description="Run conventional-TSG missions (or another governor's: "
                                   "--governor) from the widened Monte Carlo distribution and store "
                                   "every active update with tau* < 0 as a label (x_d, x_c, t, "
                                   "tau*), split train/val/test by mission.")
    p.add_argument("--labels", type=int, required=True, help="number of labels N")
    p.add_argument("--out", required=True, metavar="PATH", help="output Parquet file")
    p.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: one per CPU; 1 runs in this process)")
    p.add_argument("--dask", metavar="ADDRESS", default=None,
                   help="run on the Dask cluster at this scheduler address (e.g. tcp://host:8786)")
    p.add_argument("--seed", type=seed_arg, default=0, help="dataset seed (the labels depend on it only)")
    p.add_argument("--sigma-min", type=float, default=None,
                   help="smallest start spread sigma [km] (default 0.5 x mission.mc_sigma_km: 5 km "
                        "in the paper's scenario)")
    p.add_argument("--sigma-max", type=float, default=None,
                   help="largest start spread sigma [km] (default 1.5 x mission.mc_sigma_km: 15 km)")
    p.add_argument("--val-fraction", type=float, default=0.05, help="fraction of missions for val")
    p.add_argument("--test-fraction", type=float, default=0.05, help="fraction of missions for test")
    p.add_argument("--min-split-missions", type=int, default=8,
                   help="fewest missions in val and in test each, up to a quarter of the missions (long "
                        "missions give few per dataset)")
    p.add_argument("--governor", default="conventional", metavar="NAME",
                   help="governor flying the missions (default conventional); another one gives "
                        "on-policy labels: pi* solved at the states it visited, from its own tau_prev")
    p.add_argument("--chunk", type=int, default=4, help="missions per task")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the metadata as one JSON object")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..learn.dataset import DatasetSpec, generate, scenario_sigma_km, write_parquet
    from ..learn.errors import DatasetError
    from ..progress import on_terminal

    if args.chunk < 1:
        raise DatasetError("--chunk must be >= 1")
    cfg = config_from_args(args)
    lo, hi = scenario_sigma_km(cfg)
    spec = DatasetSpec(seed=args.seed, sigma_min_km=lo if args.sigma_min is None else args.sigma_min,
                       sigma_max_km=hi if args.sigma_max is None else args.sigma_max,
                       val_fraction=args.val_fraction, test_fraction=args.test_fraction,
                       min_split_missions=args.min_split_missions)
    import os

    workers = args.workers if args.workers is not None else (os.cpu_count() or 1)
    df, meta = generate(cfg, args.labels, spec, workers=workers,
                        dask_address=args.dask, chunk=args.chunk, progress=on_terminal(args.quiet or args.json),
                        governor=args.governor)
    path = write_parquet(df, meta, args.out)
    summary = {k: v for k, v in meta.items() if k != "config"}
    summary["out"] = str(path)
    if args.json:
        print(dumps(summary))
    else:
        print(f"wrote {meta['labels']} labels from {meta['missions']} missions to {path} "
              f"({meta['labels_per_s']:.0f} labels/s; splits {meta['split_labels']})")
    return 0
