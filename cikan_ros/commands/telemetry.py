"""``cikan telemetry``: the telemetry dictionary of a configuration (units, frames, limits, where
each value is published), as a table or as the JSON document shipped with each bag."""

from __future__ import annotations

import argparse

from ..strict_json import dumps
from . import add_config_args, config_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("telemetry", help="the telemetry dictionary: units, frames and limits of τ, "
                                         "the margins, the thrust and the relative state",
                       description="Print the telemetry dictionary of the configuration (every "
                                   "quantity a viewer plots: unit, frame, limits, topic and field), "
                                   "the one each bag of `cikan mission` carries.")
    p.add_argument("--json", action="store_true",
                   help="print the versioned JSON document (format cikan-telemetry) instead of a table")
    add_config_args(p)
    p.set_defaults(func=run)


def _bound(v: float | None) -> str:
    return "" if v is None else f"{v:g}"


def table(points: list, cfg) -> str:
    """A Markdown table of the points, headed by the configuration facts."""
    head = (f"telemetry of scenario {cfg.scenario.name}, approach {cfg.side.approach}, cone "
            f"{cfg.constraints.los_half_angle_deg:g}°; a margin <= 0 is within its limit\n\n"
            "| key | name | unit | frame | low | high | docked below | topic field |\n"
            "|---|---|---|---|---|---|---|---|")
    rows = []
    cell = lambda text: str(text).replace("|", "\\|")  # noqa: E731 - a pipe inside a cell
    for p in points:
        high = _bound(p.limit_high) or (f"= {p.limit_key}" if p.limit_key else "")
        where = f"{p.topic} {p.field}" if p.topic else ""
        rows.append(f"| {p.key} | {cell(p.name)} | {p.unit} | {p.frame} | {_bound(p.limit_low)} | {high} | "
                    f"{_bound(p.goal_high)} | {where} |")
    return "\n".join([head, *rows])


def run(args: argparse.Namespace) -> int:
    from ..telemetry import dictionary, to_json

    cfg = config_from_args(args)
    points = dictionary(cfg)
    print(dumps(to_json(points, cfg)) if args.json else table(points, cfg))
    return 0
