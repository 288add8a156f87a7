"""``cikan profile``: where a lockstep step's CPU goes, per node process and per stage
(:mod:`cikan_ros.ros.profile`)."""

from __future__ import annotations

import argparse

from . import add_config_args, add_layout_arg, config_from_args, seed_arg


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("profile", help="profile one ROS lockstep mission per node and stage",
                       description="Fly one lockstep mission of the ROS graph with every node process "
                                   "under cProfile (main thread's CPU clock) and print, per node, the CPU "
                                   "microseconds per step of each stage: rclpy (executor, take, "
                                   "deserialise), publish (serialise, DDS write), messages (build, "
                                   "convert), record (bag), compute (governor, controller, simulator), "
                                   "other; the process's other threads (DDS) apart; beside them each "
                                   "process's CPU per step in the same mission flown just before without "
                                   "the profiler (docs/ros_profile.md).")
    add_config_args(p)
    p.add_argument("--governor", default="conventional", metavar="NAME|PATH", help="governor to fly")
    p.add_argument("--seed", type=seed_arg, default=None, help="Monte Carlo start (default: the nominal start)")
    p.add_argument("--json", action="store_true", help="print the table as JSON")
    p.add_argument("--out", metavar="FILE.md", default=None, help="also write the table as a Markdown page")
    add_layout_arg(p, "separate")   # one node per process: each node's CPU apart
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import shlex
    import shutil
    import sys
    import tempfile
    from pathlib import Path

    from ..errors import CikanError
    from ..ros.launch import node_environment, run_ros_mission
    from ..ros.profile import CPU_ONLY_ENV, PROFILE_ENV, markdown, profile_table, spin_cpu
    from ..strict_json import dumps

    cfg = config_from_args(args)
    tmp = Path(tempfile.mkdtemp(prefix="cikan_profile_"))
    try:
        # the same mission without the profiler first: each node's CPU as flown
        with node_environment(PROFILE_ENV, str(tmp / "cpu")), node_environment(CPU_ONLY_ENV, "1"):
            flown = run_ros_mission(cfg, governor=args.governor, seed=args.seed, bag=tmp / "bag0",
                                     layout=args.layout)
        with node_environment(PROFILE_ENV, str(tmp / "prof")):
            m = run_ros_mission(cfg, governor=args.governor, seed=args.seed, bag=tmp / "bag",
                                layout=args.layout)
        steps = round(cfg.mission.duration_s / cfg.control.period_s)
        table = profile_table(tmp / "prof", steps, spin_cpu(tmp / "cpu"))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if not table:
        raise CikanError("no node wrote a profile (were the nodes started from this installation?)")
    wall = float(m["ros"].get("wall_s", float("nan")))
    flown_wall = float(flown["ros"].get("wall_s", float("nan")))
    if args.json:
        print(dumps({"steps": steps, "lockstep_wall_s": wall, "flown_lockstep_wall_s": flown_wall,
                     "us_per_step": table}))
    else:
        print(markdown(table, steps, wall, "cikan profile", flown_wall, args.layout), end="")
    if args.out:
        command = "cikan profile " + " ".join(shlex.quote(a) for a in sys.argv[2:])
        Path(args.out).write_text(markdown(table, steps, wall, command, flown_wall, args.layout))
    return 0
