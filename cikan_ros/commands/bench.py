"""``cikan bench``: time the governors and the ROS graph on one machine in one run."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any, Callable

from ..config import Config
from ..errors import ConfigError
from ..strict_json import dumps
from . import add_config_args, config_from_args

if TYPE_CHECKING:
    from ..timing import BenchStates

#: A section of the report: (configuration, update states, repeats) -> {name: figure}.
Section = Callable[[Config, "BenchStates", int], dict[str, Any]]


#: The report's sections by name, in the order they run (``cikan bench --section``).
SECTION_NAMES = ("conventional", "nominal", "learned", "ros")


def sections(names: tuple[str, ...] = SECTION_NAMES) -> list[Section]:
    """The report's sections ``names`` (all by default), in order: the conventional TSG (under the
    configuration, then under the nominal one: ``cikan_ros.bench``), the learned governors
    (``cikan_ros.learn.bench``) and the ROS graph's lockstep (``cikan_ros.ros.bench``, which
    needs rclpy only when it runs). The learned section reads the conventional one's timings,
    so asking for it runs the conventional section too."""
    from ..bench import conventional_section, nominal_section
    from ..learn.bench import learned_section
    from ..ros.bench import ros_section

    def ros_with_view(cfg: Config, states: "BenchStates", repeats: int) -> dict[str, Any]:
        from ..view.live import start_view_process

        return ros_section(cfg, states, repeats, follow=lambda bag: start_view_process(bag, 0, False)[0])

    unknown = sorted(set(names) - set(SECTION_NAMES))
    if unknown:
        raise ConfigError(f"unknown bench section(s) {', '.join(unknown)}; known: {', '.join(SECTION_NAMES)}")
    if "learned" in names:
        names = tuple(set(names) | {"conventional"})
    by_name = dict(zip(SECTION_NAMES, (conventional_section, nominal_section, learned_section, ros_with_view)))
    return [by_name[n] for n in SECTION_NAMES if n in names]


def run_bench(cfg: Config, n_missions: int = 6, repeats: int = 3,
              names: tuple[str, ...] = SECTION_NAMES) -> dict[str, Any]:
    """The benchmark figures of sections ``names`` (all by default) in one run (ratios are
    comparable only within one run), every section on the same update states
    (``cikan_ros.timing.collect_states``)."""
    from ..timing import collect_states

    chosen = sections(names)   # a bad name fails before any mission flies
    states = collect_states(cfg, n_missions)
    out: dict[str, Any] = {}
    for section in chosen:
        out.update(section(cfg, states, repeats))
    return out


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="time governors on the update states of fixed missions",
                       description="Benchmark: time the governors on the active-phase update states "
                                   "of a fixed set of conventional missions; ratios in one run.")
    p.add_argument("--missions", type=int, default=6, help="missions whose states are timed (>= 5)")
    p.add_argument("--repeats", type=int, default=3, help="timings per state (median kept)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--section", action="append", choices=SECTION_NAMES, default=None,
                   help="run only this section (repeatable; default: all): conventional (the conventional "
                        "TSG and the oracle ceiling), nominal (the conventional TSG under the nominal "
                        "configuration, for the ratios), learned (the shipped models; runs conventional "
                        "too), ros (the graph's lockstep)")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.missions < 1 or args.repeats < 1:
        raise ConfigError("--missions and --repeats must be >= 1")
    from ..timing import EveryStartRefusedError

    cfg = config_from_args(args)
    try:
        figures = run_bench(cfg, args.missions, args.repeats, tuple(args.section or SECTION_NAMES))
    except EveryStartRefusedError as exc:
        # A result, not a failure: what the scenario index shows for this configuration.
        figures = {"refused": str(exc), "n_missions": args.missions, "n_missions_infeasible": args.missions,
                   "scenario": cfg.scenario.name, "approach": cfg.mission.approach,
                   "truth": cfg.truth.name, "robust": cfg.tsg.robust}
    if args.json:
        print(dumps(figures))
    else:
        from rich.console import Console

        console = Console()
        for table in report_tables(figures):
            console.print(table)
    return 0


#: (column, figure suffix, format) of the learned governors' tables: whole missions as flown
#: first, then the per-update figures with the network trusted.
AS_FLOWN = (("active update ms", "_mission_update_ms_mean", ".3f"),
            ("mission speed-up mean", "_mission_speedup_mean", ".2f"),
            ("worst mission", "_mission_speedup_worst", ".2f"),
            ("all missions' CPU", "_mission_cpu_speedup", ".2f"),
            ("per update as flown", "_flown_update_speedup", ".2f"),
            ("Verify calls / update", "_mission_verify_calls_mean", ".2f"),
            ("searching", "_search_rate", ".1%"),
            ("NN accept", "_mission_nn_accept_rate", ".1%"))
PER_UPDATE = (("update ms mean", "_update_ms_mean", ".3f"), ("update ms max", "_update_ms_max", ".3f"),
              ("speed-up mean", "_speedup_mean", ".2f"), ("speed-up worst", "_speedup_worst", ".2f"),
              ("Verify calls mean", "_verify_calls_mean", ".2f"), ("NN accept", "_nn_accept_rate", ".1%"),
              ("RMSE tau (s)", "_rmse_tau_s", ".3g"))


def report_tables(figures: dict[str, Any]) -> list[Any]:
    """The human report of ``cikan bench``: whole missions as flown (the conventional TSG's row,
    then each learned model's), the learned models' per-update figures with the network trusted,
    then every other figure by name."""
    from rich.table import Table

    from ..registry import LEARNED_NAMES

    models = [m for m in LEARNED_NAMES if f"{m}_mission_speedup_mean" in figures]
    used: set[str] = set()

    def cell(key: str, spec: str) -> str:
        used.add(key)
        v = figures.get(key)
        return "-" if v is None else format(v, spec) if isinstance(v, (int, float)) else str(v)

    tables = []
    if models:
        flown = Table(title="Whole missions as flown (active updates; trust, audits and stall rule included)")
        flown.add_column("governor")
        for col, _, _ in AS_FLOWN:
            flown.add_column(col, justify="right")
        flown.add_row("conventional", cell("mission_conventional_update_ms_mean", ".3f"), "1.00", "1.00",
                      "1.00", "1.00", cell("mission_conventional_verify_calls_mean", ".2f"), "-", "-")
        for m in models:
            flown.add_row(m, *(cell(m + suffix, spec) for _, suffix, spec in AS_FLOWN))
        if "oracle_mission_speedup_mean" in figures:   # the ceiling of any governor tracking pi*
            flown.add_row("oracle: pi* verified once (ceiling)", cell("oracle_update_ms_mean", ".3f"),
                          cell("oracle_mission_speedup_mean", ".2f"), cell("oracle_mission_speedup_worst", ".2f"),
                          cell("oracle_cpu_speedup", ".2f"), "-", "-", "-", "-")
        per = Table(title="Per update on the benchmark's states, the network trusted")
        per.add_column("governor")
        for col, _, _ in PER_UPDATE:
            per.add_column(col, justify="right")
        per.add_row("conventional", cell("learned_conventional_update_ms_mean", ".3f"),
                    cell("learned_conventional_update_ms_max", ".3f"), "1.00", "1.00",
                    cell("conventional_verify_calls_mean", ".2f"), "-", "-")
        for m in models:
            per.add_row(m, *(cell(m + suffix, spec) for _, suffix, spec in PER_UPDATE))
        tables += [flown, per]
    rest = Table(title="cikan bench: every other figure", show_header=True)
    rest.add_column("figure")
    rest.add_column("value", justify="right")
    for k, v in figures.items():
        if k not in used:
            rest.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
    return tables + [rest]
