"""``cikan report``: the paper's figures and a Markdown page from bags or a Monte Carlo directory."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="figures and a Markdown page from recorded runs",
                       description="Draw the paper's Fig. 3a-e and Fig. 4 and write report.md from a "
                                   "rosbag2 bag, a directory of bags, or a `cikan montecarlo` directory.")
    p.add_argument("source", metavar="BAG|DIR", help="bag directory, directory of bags, or Monte Carlo --out")
    p.add_argument("--out", required=True, metavar="DIR", help="where the PNG files and report.md go")
    p.add_argument("--title", default=None, help="page title")
    p.add_argument("--notes", default=None, metavar="FILE",
                   help="a Markdown file inserted after the tables (e.g. what differs from the paper and why)")
    p.add_argument("--robustness", action="store_true",
                   help="DIR holds a robustness campaign (one `cikan montecarlo` output per truth "
                        "scale and Verify, `make robustness`): write robustness.md and .png")
    p.add_argument("--name", default="robustness", metavar="NAME",
                   help="with --robustness: the page's and figure's file name (NAME.md, NAME.png)")
    p.add_argument("--config", default=None, metavar="PATH",
                   help="configuration of bags that do not carry their own (default: the shipped one)")
    p.add_argument("--scenario", metavar="NAME|FILE", default=None,
                   help="scenario of bags that do not carry their configuration (paper, leo, geo "
                        "or a YAML file; a campaign's own configuration names its scenario)")
    p.add_argument("--tables-only", action="store_true", help="write the tables, no figures")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..analysis.report import write_report
    from ..config import load_config

    from ..config import scenario_overrides

    over = scenario_overrides(args.scenario) if args.scenario else {}
    cfg = load_config(args.config, **over) if (args.config or over) else None
    notes = None
    if args.notes:
        from pathlib import Path

        from ..errors import CikanError

        try:
            notes = Path(args.notes).read_text()
        except OSError as exc:
            raise CikanError(f"cannot read --notes file {args.notes}: {exc.strerror}") from None
    if args.robustness:
        from ..analysis.robustness import write_robustness
        from ..errors import CikanError

        if not args.name or "/" in args.name or args.name.startswith("."):
            raise CikanError(f"--name must be a plain file name, got {args.name!r}")

        page = write_robustness(args.source, args.out, notes, args.title, args.name)
    else:
        page = write_report(args.source, args.out, cfg, args.title, notes, figures=not args.tables_only)
    print(f"report: {page}")
    return 0
