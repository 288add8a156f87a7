"""``cikan models``: the shipped models' tables from their cards (and the loss breakdown on a
dataset); ``--out models/README.md`` rewrites that page."""

from __future__ import annotations

import argparse
from pathlib import Path

INTRO = Path(__file__).resolve().parents[2] / "docs" / "models_intro.md"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("models", help="tables of the shipped models (cards, loss breakdown)",
                       description="Print the table of every model directory under models/ from "
                                   "its card and, with --data, the loss by |tau*| band and by "
                                   "hold/move update on one split of a dataset.")
    p.add_argument("--data", metavar="PATH", default=None, nargs="+",
                   help="datasets (Parquet) for the breakdown, one table each for the models of "
                        "its scenario and side")
    p.add_argument("--split", default="val", choices=("train", "val", "test"))
    p.add_argument("--out", metavar="PATH", default=None,
                   help="write the whole page (introduction from docs/models_intro.md + tables)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..errors import CikanError
    from ..learn.cards import models_page

    if not INTRO.exists():
        raise CikanError(f"introduction not found: {INTRO}")
    page, _ = models_page(INTRO.read_text(), args.data, args.split, out=args.out)
    if args.out:
        Path(args.out).write_text(page)
        print(f"wrote {args.out}")
    else:
        print(page)
    return 0
