"""``cikan compare``: governors and configuration variants against the conventional TSG in closed loop."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from ..strict_json import dumps
from . import add_config_args, config_from_args

if TYPE_CHECKING:
    from ..config import Config


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compare", help="closed-loop ΔV, time to τ = 0 and speed of governors and "
                                       "configuration variants against the conventional TSG",
                       description="Fly each governor under each variant from the same Monte Carlo "
                                   "starts as the conventional TSG; print ΔV and time to τ = 0 "
                                   "relative to it, success, violations, Verify calls and speed-up.")
    p.add_argument("--governor", action="append", default=[], metavar="NAME",
                   help="governor (repeatable; default: the five shipped families)")
    p.add_argument("--seeds", default="1001-1100", metavar="A-B",
                   help="Monte Carlo seeds (default 1001-1100: not the seeds of Table 2, 1-100)")
    p.add_argument("--variant", action="append", default=[], metavar="K=V[;K=V...]",
                   help="a configuration variant: --set overrides separated by ';' (repeatable; "
                        "the configuration itself is always the first variant, 'default')")
    p.add_argument("--workers", type=int, default=1, help="local worker processes")
    p.add_argument("--dask", default=None, metavar="ADDRESS", help="Dask scheduler instead of local workers")
    p.add_argument("--json", action="store_true", help="print one JSON object per row")
    p.add_argument("--by-shift", action="store_true",
                   help="also print the figures by the shift each update started from (|tau_prev| "
                        "> 1 s, 0.1-1 s, < 0.1 s): where the updates and the CPU time are, searching "
                        "and network shares, the speed-up per band (in --json always, as by_shift)")
    add_config_args(p)
    p.set_defaults(func=run)


def parse_seeds(text: str) -> list[int]:
    """'A-B' (inclusive) or 'A' -> seeds."""
    from ..errors import ConfigError

    a, sep, b = text.partition("-")
    try:
        lo, hi = int(a), int(b) if sep else int(a)
    except ValueError:
        raise ConfigError(f"--seeds expects A-B or A, got {text!r}") from None
    if lo > hi or lo < 0:
        raise ConfigError(f"--seeds range is empty or negative: {text!r}")
    return list(range(lo, hi + 1))


def variant_configs(args: argparse.Namespace) -> dict[str, Config]:
    """``{"default": the command's configuration, text: it with the variant's overrides}``: each
    variant keeps every configuration option of the command (--config, --scenario, --truth,
    --robust, --set) and adds its own --set overrides after them."""
    variants = {"default": config_from_args(args)}
    for text in args.variant:
        extra = [s.strip() for s in text.split(";") if s.strip()]
        variants[text] = config_from_args(argparse.Namespace(**{**vars(args), "overrides": args.overrides + extra}))
    return variants


def run(args: argparse.Namespace) -> int:
    from ..compare import compare, markdown, markdown_by_shift
    from ..registry import LEARNED_NAMES

    variants = variant_configs(args)
    rows = compare(variants, args.governor or list(LEARNED_NAMES), parse_seeds(args.seeds),
                   args.workers, args.dask)
    if args.json:
        for r in rows:
            print(dumps(r))
    else:
        print(markdown(rows))
        if args.by_shift:
            print()
            print(markdown_by_shift(rows))
    return 0
