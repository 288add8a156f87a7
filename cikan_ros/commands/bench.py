"""``cikan bench``: time the governors and the ROS graph on one machine in one run."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any, Callable

from ..config import Config
from ..strict_json import dumps
from . import add_config_args, config_from_args

if TYPE_CHECKING:
    from ..timing import BenchStates

#: A section of the report: (configuration, update states, repeats) -> {name: figure}.
Section = Callable[[Config, "BenchStates", int], dict[str, Any]]


def sections() -> list[Section]:
    """The report's sections, in order: the conventional TSG (under the configuration, then under
    the nominal one: ``cikan_ros.bench``), the learned governors (``cikan_ros.learn.bench``) and
    the ROS graph's lockstep (``cikan_ros.ros.bench``, which needs rclpy only when it runs)."""
    from ..bench import conventional_section, nominal_section
    from ..learn.bench import learned_section
    from ..ros.bench import ros_section

    def ros_with_view(cfg: Config, states: "BenchStates", repeats: int) -> dict[str, Any]:
        from ..view.live import start_view_process

        return ros_section(cfg, states, repeats, follow=lambda bag: start_view_process(bag, 0, False)[0])

    return [conventional_section, nominal_section, learned_section, ros_with_view]


def run_bench(cfg: Config, n_missions: int = 6, repeats: int = 3) -> dict[str, Any]:
    """All benchmark figures in one run (ratios are comparable only within one run), every
    section on the same update states (``cikan_ros.timing.collect_states``)."""
    from ..timing import collect_states

    states = collect_states(cfg, n_missions)
    out: dict[str, Any] = {}
    for section in sections():
        out.update(section(cfg, states, repeats))
    return out


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
