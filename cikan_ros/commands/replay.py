"""``cikan replay BAG``: republish a recorded bag with /clock for other nodes or tools."""

from __future__ import annotations

import argparse

from . import dumps


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="republish a bag's topics with /clock",
                       description="Republish every message of a rosbag2 MCAP bag (directory or .mcap) "
                                   "in log-time order, with /clock, on the current ROS domain "
                                   "(discovery limited to localhost unless ROS_AUTOMATIC_DISCOVERY_RANGE "
                                   "says otherwise).")
    p.add_argument("bag", metavar="BAG", help="bag directory or .mcap file")
    p.add_argument("--rate", type=float, default=1.0, help="playback rate x recorded time (default 1)")
    p.add_argument("--fast", action="store_true",
                   help="as fast as the readers acknowledge (ignores --rate)")
    p.add_argument("--wait-subscribers", type=int, default=0, metavar="N",
                   help="wait (up to 10 s) until every topic has N subscribers before playing")
    p.add_argument("--json", action="store_true", help="print the counts as one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..ros.replay import replay

    counts = replay(args.bag, rate=args.rate, fast=args.fast, wait_subscribers=args.wait_subscribers)
    if args.json:
        print(dumps(counts))
    else:
        for topic, n in sorted(counts.items()):
            print(f"{topic}: {n} messages")
    return 0
