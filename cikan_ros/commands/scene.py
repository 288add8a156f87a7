"""``cikan scene BAG --out NEW``: a copy of a bag with the telemetry dictionary and the scene in
the chief's LVLH frame added (bags recorded before the graph published them)."""

from __future__ import annotations

import argparse

from ..strict_json import dumps


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scene", help="copy a bag with the telemetry dictionary and the LVLH scene added",
                       description="Write a copy of a bag recorded by `cikan mission` (any version) "
                                   "with the telemetry dictionary, /telemetry and the scene markers "
                                   "(/scene/markers, /scene/path, /scene/constraints; frame lvlh) "
                                   "recomputed from its recorded true states, applied thrust and "
                                   "time shifts, as the simulator publishes them; every other message "
                                   "is copied. Opens as a scene with config/foxglove/mission_layout.json.")
    p.add_argument("bag", metavar="BAG", help="the bag directory to read")
    p.add_argument("--out", metavar="DIR", required=True, help="the new bag directory (must not exist or be empty)")
    p.add_argument("--json", action="store_true", help="print the messages written per topic as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..errors import CikanError
    from ..ros.scene_stream import add_scene

    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise CikanError(f"--out {out} exists and is not an empty directory")
    if not (Path(args.bag) / "metadata.yaml").is_file():
        raise CikanError(f"{args.bag} is not a bag directory (no metadata.yaml)")
    counts = add_scene(args.bag, out)
    if args.json:
        print(dumps({"bag": str(out), "messages": counts}))
    else:
        print(f"wrote {out}: {sum(counts.values())} messages, "
              f"{sum(v for t, v in counts.items() if t.startswith('/scene/') or t == '/telemetry')} of "
              f"them telemetry and scene")
    return 0
