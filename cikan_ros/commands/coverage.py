"""``cikan coverage``: does the truth stay inside robust Verify's tube? Held first-instant shifts
flown at every corner of the declared bounds and for random draws (:mod:`cikan_ros.coverage`)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from . import add_config_args, config_from_args, int_at_least, seed_arg

if TYPE_CHECKING:
    from ..config import Config


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("coverage", help="the truth against robust Verify's tube, held shifts, every corner",
                       description="Fly Monte Carlo starts with the conventional TSG's first-instant shift "
                                   "held (robust Verify) in the truth's random draws and, with --corners, "
                                   "at every corner of its declared bounds, and compare the truth with the "
                                   "tube Verify predicted (docs/robustness.md, \"Coverage\"). Prints a table "
                                   "(or --json); --sweep runs every shipped scenario and side and writes "
                                   "the page --out.")
    add_config_args(p)
    p.add_argument("--runs", type=int_at_least(1, "--runs"), default=5, help="starts (seeds) per corner")
    p.add_argument("--seed", type=seed_arg, default=1, help="first seed (default 1: the Table 2 starts)")
    p.add_argument("--corners", action="store_true", help="also every corner of the declared bounds")
    p.add_argument("--sweep", action="store_true",
                   help="every scenario (paper, leo, geo) and side (behind, ahead)")
    p.add_argument("--workers", type=int_at_least(1, "--workers"), default=1, help="local worker processes")
    p.add_argument("--json", action="store_true", help="print the per-flight rows as JSON")
    p.add_argument("--out", metavar="FILE.md", default=None, help="write the coverage page here")
    p.set_defaults(func=run)


def sweep_configs(args: argparse.Namespace) -> list[tuple[str, Config]]:
    """(title, configuration) of every scenario and side of ``--sweep``: each scenario as
    ``--scenario`` gives it, with the truth, ``--robust`` and ``--set`` applied over it (a
    ``--set`` value wins over the scenario's own, e.g. ``tsg.tube`` over GEO's)."""
    from ..coverage import SWEEP

    return [(f"{scenario}, {side}",
             config_from_args(argparse.Namespace(**{**vars(args), "scenario": scenario}))
             .replace(**{"mission.approach": side}))
            for scenario, side in SWEEP]


def run(args: argparse.Namespace) -> int:
    import shlex
    import sys
    from pathlib import Path

    from ..coverage import _flight, coverage_tasks, markdown, summarise
    from ..errors import ConfigError
    from ..parallel import ordered_map
    from ..strict_json import dumps

    base = config_from_args(args)
    if not base.tsg.robust:
        raise ConfigError("cikan coverage checks robust Verify's tube: add --robust (and a truth, e.g. "
                          "--truth realistic)")
    if base.truth.draw == "corner":
        raise ConfigError("cikan coverage flies the random draws and, with --corners, every corner: "
                          "leave truth.draw random")
    seeds = list(range(args.seed, args.seed + args.runs))
    if args.sweep:
        if args.scenario is not None:
            raise ConfigError("--sweep flies every shipped scenario: leave out --scenario")
        configs = sweep_configs(args)
    else:
        configs = [(f"{base.scenario.name}, {base.mission.approach}", base)]
    sections = []
    all_rows = []
    for title, cfg in configs:
        rows = list(ordered_map(_flight, coverage_tasks(cfg, seeds, args.corners), args.workers))
        for r in rows:
            r["section"] = title
        all_rows += rows
        sections.append((title, summarise(rows)))
    if args.json:
        print(dumps(all_rows, indent=1))
    else:
        for title, summary in sections:
            print(f"{title}:")
            for s in summary:
                print(f"  {s['corner']:>18}  flights {s['flights']:3d}  refused {s['refused']:2d}  "
                      f"pos/rho {s['pos_ratio']:.2f}  vel/sigma {s['vel_ratio']:.2f}  "
                      f"ball {s['ball_pos_ratio']:.2f}/{s['ball_vel_ratio']:.2f}  ({s['worst_at']})")
    if args.out:
        command = "cikan coverage " + " ".join(shlex.quote(a) for a in sys.argv[2:])
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(markdown(sections, command))
    return 0
