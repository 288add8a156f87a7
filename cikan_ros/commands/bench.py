"""``cikan bench``: time the governors (and later the ROS graph) on one machine in one run."""

from __future__ import annotations

import argparse

from . import add_config_args, config_from_args, dumps


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="time governors on the update states of fixed missions",
                       description="Benchmark: time the governors on the active-phase update states "
                                   "of a fixed set of conventional missions; ratios in one run.")
    p.add_argument("--missions", type=int, default=6, help="missions whose states are timed (>= 5)")
    p.add_argument("--repeats", type=int, default=3, help="timings per state (median kept)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..bench import run_bench
    from ..errors import ConfigError

    if args.missions < 1 or args.repeats < 1:
        raise ConfigError("--missions and --repeats must be >= 1")
    figures = run_bench(config_from_args(args), args.missions, args.repeats)
    if args.json:
        print(dumps(figures))
    else:
        from rich.console import Console
        from rich.table import Table

        table = Table(title="cikan bench", show_header=True)
        table.add_column("figure")
        table.add_column("value", justify="right")
        for k, v in figures.items():
            table.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
        Console().print(table)
    return 0
