"""Replay a bag: republish every recorded message (raw CDR, in log-time order) with /clock.

The bag's own /clock is republished as recorded; a bag without /clock gets one synthesised from
the log times, published before the first message of each new time. Pacing: ``rate`` x the
recorded (sim) time, or as fast as the readers acknowledge (``fast``: every 200 messages the
publishers wait until all reliable readers have the data, so nothing is dropped for a reader that
keeps all messages). This process only publishes, so it needs no executor.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from pathlib import Path
from typing import Any

from ..errors import CikanError
from .graph import CLOCK, QOS_RECORD, message_class

#: Messages published between acknowledgement waits in ``fast`` mode.
FAST_BATCH = 200


def _mcap_file(bag: Path) -> Path:
    if bag.is_file():
        return bag
    files = sorted(bag.glob("*.mcap"))
    if not files:
        raise CikanError(f"no .mcap file in bag directory {bag}")
    return files[0]


def replay(bag: str | os.PathLike, rate: float = 1.0, fast: bool = False, wait_subscribers: int = 0,
           wait_timeout_s: float = 10.0, delay_s: float = 0.2) -> dict[str, int]:
    """Republish ``bag``; return the number of messages published per topic."""
    import rclpy
    from mcap.reader import make_reader
    from rclpy.duration import Duration
    from rosgraph_msgs.msg import Clock

    from .convert import clock_msg

    if not fast and not rate > 0:
        raise CikanError(f"--rate must be > 0, got {rate}")
    path = _mcap_file(Path(bag))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    counts: Counter[str] = Counter()
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None:
            raise CikanError(f"{path} has no summary (not closed); nothing to replay")
        channels = summary.channels
        schemas = summary.schemas
        has_clock = any(ch.topic == CLOCK for ch in channels.values())
        rclpy.init()
        node = rclpy.create_node("cikan_replay")
        try:
            pubs: dict[int, Any] = {}
            for cid, ch in channels.items():
                pubs[cid] = node.create_publisher(message_class(schemas[ch.schema_id].name), ch.topic,
                                                  QOS_RECORD)
            clock_pub = None if has_clock else node.create_publisher(Clock, CLOCK, QOS_RECORD)
            every = list(pubs.values()) + ([clock_pub] if clock_pub else [])
            t_wait = time.monotonic()
            while wait_subscribers > 0 and time.monotonic() - t_wait < wait_timeout_s and \
                    any(p.get_subscription_count() < wait_subscribers for p in every):
                time.sleep(0.02)
            time.sleep(delay_s)
            start_wall = time.monotonic()
            first: int | None = None
            last_clock = None
            for n, (_schema, channel, message) in enumerate(reader.iter_messages(log_time_order=True)):
                if first is None:
                    first = message.log_time
                if not fast:
                    due = start_wall + (message.log_time - first) / 1e9 / rate
                    pause = due - time.monotonic()
                    if pause > 0:
                        time.sleep(pause)
                elif n and n % FAST_BATCH == 0:
                    for p in every:
                        p.wait_for_all_acked(Duration(seconds=5))
                if clock_pub is not None and message.log_time != last_clock:
                    clock_pub.publish(clock_msg(message.log_time))
                    counts[CLOCK] += 1
                    last_clock = message.log_time
                pubs[channel.id].publish(message.data)
                counts[channel.topic] += 1
            for p in every:
                p.wait_for_all_acked(Duration(seconds=5))
        finally:
            node.destroy_node()
            rclpy.try_shutdown()
    return dict(counts)
