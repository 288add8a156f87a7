"""``cikan mission``: one rendezvous, offline (library only) or as the ROS 2 node graph."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ..strict_json import dumps
from . import add_config_args, add_layout_arg, config_from_args, int_at_least, seed_arg


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("mission", help="run one rendezvous (offline or as the ROS graph)",
                       description="Run one rendezvous mission and print its metrics.")
    p.add_argument("--governor", default=None, metavar="NAME|PATH",
                   help="conventional (default), cikan, grbf, rswaf, relu, gelu, or a model file/directory")
    p.add_argument("--governor-exec", metavar='"CMD ARGS"', default=None,
                   help="ROS run: start this executable in place of governor_node (the governor "
                        "contract in docs/governor_contract.md); it gets ARGS followed by --ros-args --params-file "
                        "FILE, the file every node gets; the bag and the metrics name the governor "
                        "exec:CMD ARGS, and the summary adds an audit of its time shifts")
    p.add_argument("--offline", action="store_true",
                   help="run the closed loop in-process without ROS (default: the ROS node graph)")
    p.add_argument("--seed", type=seed_arg, default=None,
                   help="draw the start from the Monte Carlo distribution with this seed "
                        "(default: the nominal start)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("--bag", metavar="DIR", default=None,
                   help="ROS run: record to this bag directory (default: runs/bags/<time>_<governor>); "
                        "not with --offline")
    p.add_argument("--view", action="store_true",
                   help="ROS run: follow the mission live in the mission-control view (cikan view BAG "
                        "--follow, its own process, reading the bag as the recorder flushes it); the "
                        "view stays after the mission until Ctrl-C")
    p.add_argument("--view-port", type=int_at_least(0, "--view-port"), default=0, metavar="N",
                   help="with --view: port on 127.0.0.1 (default: a free one)")
    p.add_argument("--no-browser", action="store_true",
                   help="with --view: do not open a browser (one opens only where a desktop session is)")
    add_layout_arg(p)
    add_config_args(p)
    p.set_defaults(func=run)


def print_summary(metrics: dict[str, Any], title: str, cfg: Any, model: str | None = None) -> None:
    """A readable table of what a mission flew (:func:`cikan_ros.analysis.flown.flown_rows`) and
    its metrics (:func:`~cikan_ros.analysis.flown.metric_rows`); the bag's path on a line of its
    own, whole."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from ..analysis.flown import flown_rows, metric_rows

    table = Table(show_header=False)
    flown = flown_rows(cfg, metrics["governor"], model, metrics.get("nn_accept_rate"))
    for label, value in flown:
        table.add_row(escape(label), escape(value))
    table.add_section()
    for label, value in metric_rows(metrics, cfg):
        table.add_row(escape(label), escape(value))
    console = Console()
    console.print(escape(title), style="bold")
    console.print(table)
    if "bag" in metrics:
        print(f"bag: {metrics['bag']}")


def run(args: argparse.Namespace) -> int:
    from ..errors import ConfigError

    if args.governor_exec is not None and (args.offline or args.governor is not None):
        raise ConfigError("--governor-exec replaces governor_node in the ROS graph: it takes "
                          "neither --offline nor --governor")
    if args.offline and args.bag is not None:
        raise ConfigError("--bag records the ROS graph's topics; an offline mission has none to record "
                          "(drop --offline to record it, or keep an offline run's whole record with "
                          "`cikan montecarlo --runs 1 --seed N --out DIR`, which `cikan report` reads)")
    if args.view and args.offline:
        raise ConfigError("--view follows the bag of the ROS graph; --offline records none")
    from ..progress import on_terminal

    args.governor = args.governor or "conventional"
    cfg = config_from_args(args)
    progress = on_terminal(args.json)
    view = None
    if args.offline:
        from ..governor import warm_up
        from ..mission import nominal_start, run_mission, sample_start
        from ..registry import make_governor

        governor = make_governor(args.governor, cfg)
        pred = governor.predictor
        # As every Monte Carlo worker and the governor node do: the kernels and the network load
        # before the mission, so that no update's time is compilation (measured cold: CIKAN's
        # first update 1,779 ms). The mission flies the same either way.
        warm_up(governor, nominal_start(pred), pred.orbit.state(0.0))
        x0 = nominal_start(pred) if args.seed is None else sample_start(pred, args.seed)
        result = run_mission(governor, x0, args.seed, progress=progress)
        metrics = result.metrics()
        if governor.name != "conventional":  # share of the active updates the network decided
            from ..learn.governor import nn_accept_rate
            metrics["nn_accept_rate"] = nn_accept_rate(result.updates)
        if getattr(governor, "foreign", None):
            metrics["foreign_model"] = governor.foreign
        metrics.update(seed=args.seed, mode="offline")
        model = getattr(governor, "model_dir", None)
    else:
        from ..ros.launch import run_ros_mission

        if args.governor_exec is None and args.governor != "conventional":
            from ..registry import make_governor

            make_governor(args.governor, cfg)  # a bad or foreign model: one line, before any node starts

        view = start_view(args) if args.view else None
        try:
            metrics = run_ros_mission(cfg, governor=args.governor, seed=args.seed, bag=args.bag,
                                      config_path=args.config, overrides=args.overrides,
                                      governor_exec=args.governor_exec, progress=progress,
                                      layout=args.layout)
        except BaseException:
            if view is not None:
                view[0].terminate()
            raise
        metrics.update(seed=args.seed, mode="ros")
        from ..ros.bag_reader import bag_model

        model = bag_model(metrics["bag"])
    if args.json:
        print(dumps(metrics))
    else:
        start = "nominal start" if args.seed is None else f"Monte Carlo start, seed {args.seed}"
        print_summary(metrics, f"cikan mission: {metrics['governor']} governor, {start} ({metrics['mode']})",
                      cfg, None if model is None else str(model))
    sys.stdout.flush()
    if metrics.get("lockstep_deadlines"):
        print(f"cikan mission: failed: {metrics['lockstep_deadlines']} wall-clock deadline(s) fired in the "
              "lockstep (a node answered late or not at all; see /diagnostics in the bag)", file=sys.stderr)
    if view is not None:
        keep_view(*view)
    return 0 if metrics["success"] else 1


def start_view(args: argparse.Namespace) -> tuple[Any, str]:
    """The view process following the mission's bag (``args.bag`` is set to the default bag if
    none was given, so the launcher records where the view reads) and its URL."""
    from ..ros.launch import default_bag_path, exec_governor_name
    from ..view.live import start_view_process

    if args.bag is None:
        label = exec_governor_name(args.governor_exec) if args.governor_exec is not None else args.governor
        args.bag = str(default_bag_path(label))
    proc, url = start_view_process(args.bag, args.view_port, not args.no_browser)
    print(f"cikan mission: following the mission at {url}", file=sys.stderr, flush=True)
    return proc, url


def keep_view(proc: Any, url: str) -> None:
    """Leave the view up after the mission until Ctrl-C (or until it ends), then stop it."""
    print(f"cikan mission: the view stays at {url} (Ctrl-C ends it)", file=sys.stderr, flush=True)
    try:
        proc.wait()
    except KeyboardInterrupt:
        pass
    finally:
        proc.terminate()
        proc.wait()
