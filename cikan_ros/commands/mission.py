"""``cikan mission``: one rendezvous, offline (library only) or as the ROS 2 node graph."""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

from . import add_config_args, config_from_args, dumps, int_at_least, seed_arg

SUMMARY_KEYS = (
    ("success", "docked with zero violations", "{}"),
    ("violations", "control steps with a violation", "{}"),
    ("tau0_s", "first time shift tau_0 [s]", "{:.6f}"),
    ("t_tau_zero_s", "tau reached 0 at [s]", "{}"),
    ("t_docked_s", "docked (<{dock_distance_m:g} m, <{dock_speed_mps:g} m/s) at [s]", "{}"),
    ("final_distance_m", "final distance [m]", "{:.3e}"),
    ("final_speed_mps", "final relative speed [m/s]", "{:.3e}"),
    ("delta_v_kmps", "delta-V [km/s]", "{:.4f}"),
    ("min_h1_margin", "min LoS margin -h1/(|v_c||p|)", "{:.3e}"),
    ("max_h3", "max h3 [km/s]", "{:.3e}"),
    ("updates", "governor updates", "{}"),
    ("update_ms_mean", "update time mean / max [ms]", None),
    ("active_update_ms_mean", "active-phase update mean / max [ms]", None),
)
#: Governor contract audit of a ROS run (cikan_ros.mission.audit_shifts), shown when present.
AUDIT_KEYS = (
    ("unverified_shifts", "time shifts not verified (audit)", "{}"),
    ("off_schedule_shifts", "time shifts changed off schedule", "{}"),
    ("missing_shifts", "steps without a time shift", "{}"),
    ("lockstep_deadlines", "wall-clock deadlines fired (each fails the run)", "{}"),
)


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
                   help="ROS run: record to this bag directory (default: bags/<time>_<governor>)")
    p.add_argument("--view", action="store_true",
                   help="ROS run: follow the mission live in the mission-control view (cikan view BAG "
                        "--follow, its own process, reading the bag as the recorder flushes it); the "
                        "view stays after the mission until Ctrl-C")
    p.add_argument("--view-port", type=int_at_least(0, "--view-port"), default=0, metavar="N",
                   help="with --view: port on 127.0.0.1 (default: a free one)")
    p.add_argument("--no-browser", action="store_true",
                   help="with --view: do not open a browser (one opens only where a desktop session is)")
    add_config_args(p)
    p.set_defaults(func=run)


def print_summary(metrics: dict[str, Any], title: str) -> None:
    """A readable table of a mission's metrics."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    table = Table(show_header=False)
    for key, label, fmt in SUMMARY_KEYS + tuple(a for a in AUDIT_KEYS if a[0] in metrics):
        if fmt is None:
            stem = key.removesuffix("_mean")
            value = " / ".join("-" if metrics.get(k) is None else f"{metrics[k]:.3f}"
                               for k in (key, stem + "_max"))
        else:
            v = metrics.get(key)
            value = "-" if v is None else fmt.format(v)
        table.add_row(escape(label.format(**{k: metrics.get(k, math.nan) for k in
                                              ("dock_distance_m", "dock_speed_mps")})), value)
    if metrics.get("foreign_model"):
        table.add_row("model", f"FOREIGN: {metrics['foreign_model']} (learned.foreign_model)")
    if "bag" in metrics:
        table.add_row("bag", str(metrics["bag"]))
    console = Console()
    console.print(escape(title), style="bold")
    console.print(table)


def run(args: argparse.Namespace) -> int:
    from ..errors import ConfigError

    if args.governor_exec is not None and (args.offline or args.governor is not None):
        raise ConfigError("--governor-exec replaces governor_node in the ROS graph: it takes "
                          "neither --offline nor --governor")
    if args.view and args.offline:
        raise ConfigError("--view follows the bag of the ROS graph; --offline records none")
    args.governor = args.governor or "conventional"
    cfg = config_from_args(args)
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
        result = run_mission(governor, x0, args.seed)
        metrics = result.metrics()
        if governor.name != "conventional":  # fraction of consulted proposals that passed Verify
            from ..learn.governor import nn_accept_rate
            metrics["nn_accept_rate"] = nn_accept_rate(result.updates)
        if getattr(governor, "foreign", None):
            metrics["foreign_model"] = governor.foreign
        metrics.update(seed=args.seed, mode="offline")
    else:
        from ..ros.launch import run_ros_mission

        if args.governor_exec is None and args.governor != "conventional":
            from ..registry import make_governor

            make_governor(args.governor, cfg)  # a bad or foreign model: one line, before any node starts
        view = start_view(args) if args.view else None
        try:
            metrics = run_ros_mission(cfg, governor=args.governor, seed=args.seed, bag=args.bag,
                                      config_path=args.config, overrides=args.overrides,
                                      governor_exec=args.governor_exec)
        except BaseException:
            if view is not None:
                view[0].terminate()
            raise
        metrics.update(seed=args.seed, mode="ros")
    if args.json:
        print(dumps(metrics))
    else:
        start = "nominal start" if args.seed is None else f"Monte Carlo start, seed {args.seed}"
        print_summary(metrics, f"cikan mission: {metrics['governor']} governor, {start} ({metrics['mode']})")
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
