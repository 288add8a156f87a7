"""``cikan view``: the mission-control view of a bag or a Monte Carlo directory in the browser."""

from __future__ import annotations

import argparse

from . import int_at_least


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="mission-control view of a bag or Monte Carlo directory (browser)",
                       description="Serve a local page (127.0.0.1 only) with the approach in the chief's "
                                   "LVLH frame, tau and every telemetry point against its limits, with a "
                                   "time slider; a Monte Carlo directory shows its runs overlaid. Ctrl-C ends it.")
    p.add_argument("source", metavar="BAG|DIR",
                   help="a rosbag2 bag directory (or its .mcap file), or a `cikan montecarlo --out` directory")
    p.add_argument("--port", type=int_at_least(0, "port"), default=0,
                   help="port on 127.0.0.1 (default: a free one)")
    p.add_argument("--no-browser", action="store_true",
                   help="do not open a browser (one opens only where a desktop session is)")
    p.add_argument("--follow", action="store_true",
                   help="follow a bag being recorded (it may not exist yet): the page updates at each "
                        "flush of the recorder (what `cikan mission --view` runs)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..view.data import encode, load
    from ..view.server import ViewData, plotly_js, serve

    plotly_js()   # a missing plotly: one line before anything is read
    view = ViewData()
    follow = None
    if args.follow:
        from ..view.live import BagFollower

        follower = BagFollower(args.source)

        def follow() -> bool:
            if follower.poll():
                data = follower.payload()
                if data is not None:
                    view.set(encode(data), follower.complete)
            return not follower.complete
    else:
        view.set(encode(load(args.source)), True)

    def announce(url: str) -> None:
        print(f"cikan view: {url} (Ctrl-C to stop)", flush=True)
    try:
        serve(view, args.port, not args.no_browser, follow, announce)
    except KeyboardInterrupt:
        pass
    return 0
