"""``cikan replay BAG``: republish a recorded bag with /clock for other nodes or tools."""

from __future__ import annotations

import argparse

from ..strict_json import dumps


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay", help="republish a bag's topics with /clock",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Republish every message of a rosbag2 MCAP bag (directory or .mcap) in log-time "
                    "order, with /clock, on the current ROS domain (discovery limited to localhost "
                    "unless ROS_AUTOMATIC_DISCOVERY_RANGE says otherwise).",
        epilog="Delivery: the publishers are RELIABLE + KEEP_ALL. A reliable KEEP_ALL subscriber gets "
               "every\nmessage in order, also with --fast. A KEEP_LAST(N) subscriber keeps only its "
               "newest N\nmessages: if it falls more than N behind (likely with --fast) it loses the "
               "oldest ones\nwithout notice, so give it KEEP_ALL or use --rate; a best-effort one may "
               "lose messages at\nany rate (--fast names those; DDS does not tell a reader's depth).")
    p.add_argument("bag", metavar="BAG", help="bag directory or .mcap file")
    p.add_argument("--rate", type=float, default=1.0, help="playback rate x recorded time (default 1)")
    p.add_argument("--fast", action="store_true",
                   help="as fast as DDS takes the messages (ignores --rate); see 'Delivery' below")
    p.add_argument("--wait-subscribers", action="append", default=[], metavar="N|TOPIC=N",
                   help="before playing, wait until every topic (or TOPIC) has N subscribers, "
                        "saying for what (repeatable); without it: --discovery")
    p.add_argument("--wait-timeout", type=float, default=10.0, metavar="S",
                   help="play anyway after S seconds of --wait-subscribers (default 10)")
    p.add_argument("--discovery", type=float, default=None, metavar="S",
                   help="without --wait-subscribers: seconds to let DDS discover the subscribers "
                        "that already run before playing (default 2.5; 0: play at once)")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no notes on stderr")
    p.add_argument("--json", action="store_true", help="print the counts as one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..progress import on_terminal
    from ..ros.replay import DISCOVERY_S, replay

    counts = replay(args.bag, rate=args.rate, fast=args.fast, wait_subscribers=args.wait_subscribers,
                    wait_timeout_s=args.wait_timeout,
                    discovery_s=DISCOVERY_S if args.discovery is None else args.discovery,
                    progress=on_terminal(args.quiet or args.json),
                    say=(lambda _text: None) if args.quiet else None)
    if args.json:
        print(dumps(counts))
    else:
        for topic, n in sorted(counts.items()):
            print(f"{topic}: {n} messages")
    return 0
