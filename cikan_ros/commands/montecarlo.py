"""``cikan montecarlo``: the paper's Monte Carlo evaluation on the same starts for each governor."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..strict_json import dumps
from . import add_config_args, config_from_args, seed_arg


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("montecarlo", help="Monte Carlo evaluation of one or all governors",
                       description="Fly --runs missions from seeded Monte Carlo starts (seeds S .. S+N-1) "
                                   "for each governor; keep per-run results in --out.")
    p.add_argument("--runs", type=int, default=100, help="runs per governor (paper: 100)")
    p.add_argument("--governor", default="conventional", metavar="NAME|PATH|all|shipped",
                   help="a governor name or model path (NAME@paper: under the paper's Algorithm 1), "
                        "a comma-separated list, 'all' (conventional, the five families under "
                        "the keep rule and under the paper's rule) or 'shipped' (conventional and "
                        "every family with a model for the scenario and approach side)")
    p.add_argument("--seed", type=seed_arg, default=1, help="seed of the first run (default 1)")
    p.add_argument("--workers", type=int, default=1, help="local worker processes")
    p.add_argument("--dask", metavar="ADDRESS", default=None, help="Dask scheduler, e.g. tcp://host:8786")
    p.add_argument("--out", required=True, metavar="DIR", help="directory for per-run results and summary")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument("--corners", action="store_true",
                   help="fly every corner of the truth's declared bounds (truth.draw=corner; "
                        "docs/robustness.md) on the same starts, into OUT/<corner>/; the summary "
                        "adds a table per corner")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..analysis.corners import corner_rows, markdown_corner_table
    from ..errors import CikanError
    from ..registry import campaign_names, shipped_models, shipped_names
    from ..montecarlo import markdown_summary, run_campaign, summarise
    from ..analysis.flown import flown_markdown, flown_rows, governors_text
    from ..progress import on_terminal

    cfg = config_from_args(args)
    if args.corners and cfg.truth.draw == "corner":
        raise CikanError("--corners flies every corner: leave truth.draw random")
    governors = (campaign_names() if args.governor == "all" else shipped_names(cfg)
                 if args.governor == "shipped" else args.governor.split(","))
    if args.governor == "shipped" and not cfg.learned.foreign_model:
        for name, why in shipped_models(cfg).items():
            if why is not None:   # a shipped model of another configuration: said, not flown
                print(f"cikan montecarlo: shipped model {name} not flown: {why} "
                      "(learned.foreign_model=true flies it)", file=sys.stderr)
    results = run_campaign(cfg, governors, args.runs, args.seed, args.out, args.workers, args.dask,
                           at_corners=args.corners, progress=on_terminal(args.json))
    summaries: dict = {g: summarise(runs) for g, runs in results.items()}
    text = markdown_summary(summaries)
    if args.corners:
        rows = corner_rows(results)
        for g in summaries:
            summaries[g]["corners"] = {r["corner"]: r for r in rows if r["governor"] == g}
        text += "\n" + markdown_corner_table(rows)
    out = Path(args.out)
    (out / "summary.json").write_text(dumps(summaries, indent=1))
    flown = flown_markdown(flown_rows(cfg, governors_text(governors, cfg)))
    (out / "summary.md").write_text(f"{flown}\n{text}")
    if args.json:
        print(dumps(summaries))
    else:
        print(f"{flown}\n{text}", end="")
        print(f"per-run results and summary in {out}/")
    return 0
