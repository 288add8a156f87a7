"""Replay a bag: republish every recorded message (raw CDR, in log-time order) with /clock.

The bag's own /clock is republished as recorded; a bag without /clock gets one synthesised from
the log times, published before the first message of each new time. Pacing: ``rate`` x the
recorded (sim) time, or ``fast``: as fast as DDS takes the messages.

Delivery, as measured with the shipped bag (8884 messages) and one reliable KEEP_ALL subscriber on
/tsg/time_shift in another process: the previous design (KEEP_LAST 1000 writers and
``wait_for_all_acked`` every 200 messages) took 132 s, of which 131.5 s in those waits: 44 of
the 264 lasted about 3 s each, i.e. until Fast DDS's next periodic heartbeat brought the
reader's acknowledgement. Now the publishers are RELIABLE + KEEP_ALL: the writer keeps every
sample until each reliable reader has acknowledged it, nothing waits during the replay, and the
only wait is the final one before the process leaves (0.3-0.8 s to publish, 0.2 s final
acknowledgement; the subscriber got all 1440 shifts, in order).

What a subscriber may miss: reliability never throttles the publisher for a KEEP_LAST(N) reader;
its history keeps the newest N samples, so a reader that falls more than N messages behind loses
the oldest ones silently (a depth-10 reader with a 20-ms callback got 681 of 1440 shifts). Use
KEEP_ALL for such readers, or ``rate`` pacing. Best-effort readers may lose messages at any rate.
This process only publishes, so it needs no executor.
"""

from __future__ import annotations

import os
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any, Callable

from ..errors import CikanError
from .graph_spec import CLOCK, message_class

#: The first bytes of every MCAP file.
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Seconds the last messages get to be acknowledged by every reliable reader before we leave.
FINAL_ACK_TIMEOUT_S = 60.0
#: Seconds to let DDS match subscribers that already run, before playing (unless waiting for
#: named ones): a publisher created beside a running subscriber was matched after 0.01-2.2 s
#: (localhost, 2 busy cores); messages published before that are not delivered to it.
DISCOVERY_S = 2.5


def qos_replay() -> Any:
    """RELIABLE, KEEP_ALL, VOLATILE (see the module docstring)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def mcap_file(bag: str | os.PathLike) -> Path:
    """The MCAP file of a bag directory (or the file itself); CikanError naming what is wrong."""
    path = Path(bag)
    if not path.exists():
        raise CikanError(f"bag not found: {path}")
    if path.is_dir():
        files = sorted(path.glob("*.mcap"))
        if not files:
            raise CikanError(f"no .mcap file in bag directory {path}")
        path = files[0]
    with open(path, "rb") as f:
        head = f.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise CikanError(f"{path} is not an MCAP file (it does not start with the MCAP magic bytes)")
    return path


def parse_wait(specs: list[str] | int | None, topics: list[str]) -> dict[str, int]:
    """``--wait-subscribers`` values as ``{topic: readers}``: ``N`` (every topic of the bag) or
    ``TOPIC=N`` (that topic); CikanError for anything else or a topic the bag does not have."""
    if isinstance(specs, int):
        specs = [str(specs)] if specs > 0 else []
    out: dict[str, int] = {}
    for spec in specs or []:
        topic, sep, count = spec.rpartition("=")
        try:
            n = int(count)
        except ValueError:
            n = -1
        if n < 1 or (sep and topic not in topics):
            raise CikanError(f"--wait-subscribers {spec!r}: expected N or TOPIC=N with N >= 1 and "
                             f"TOPIC one of the bag's topics ({', '.join(topics)})")
        out.update({topic: n} if sep else {t: n for t in topics})
    return out


def wait_for_subscribers(pubs: dict[str, Any], wanted: dict[str, int], timeout_s: float,
                         say: Callable[[str], None]) -> None:
    """Wait until each topic of ``wanted`` has its number of subscribers matched, saying what it
    waits for and, after ``timeout_s``, which topics still lack them (then play anyway)."""
    def missing() -> list[str]:
        return [f"{t} ({pubs[t].get_subscription_count()}/{n})" for t, n in wanted.items()
                if pubs[t].get_subscription_count() < n]

    if not missing():
        return
    say(f"waiting up to {timeout_s:g} s for subscribers: "
        + ", ".join(f"{n} on {t}" for t, n in wanted.items()))
    end = time.monotonic() + timeout_s
    while missing() and time.monotonic() < end:
        time.sleep(0.02)
    still = missing()
    if still:
        say(f"playing without all subscribers after {timeout_s:g} s; missing on: {', '.join(still)}")
def best_effort_readers(node: Any, topics: list[str]) -> list[str]:
    """Best-effort readers of ``topics``. (DDS discovery tells a reader's reliability, not its
    history: remote readers show history UNKNOWN, depth 0, so KEEP_LAST ones cannot be named.)"""
    from rclpy.qos import ReliabilityPolicy

    return [f"{info.node_name} on {topic}" for topic in topics
            for info in node.get_subscriptions_info_by_topic(topic)
            if info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT]


def replay(bag: str | os.PathLike, rate: float = 1.0, fast: bool = False,
           wait_subscribers: list[str] | int | None = None, wait_timeout_s: float = 10.0,
           discovery_s: float = DISCOVERY_S, progress: bool = False,
           say: Callable[[str], None] | None = None) -> dict[str, int]:
    """Republish ``bag``; return the number of messages published per topic.

    Before playing, it waits for the subscribers of ``wait_subscribers`` (see :func:`parse_wait`),
    or else ``discovery_s`` for DDS to match the subscribers already running.

    ``progress`` shows a progress bar on stderr; ``say`` receives the one-line notes (waits,
    what readers may miss); default: print them to stderr.
    """
    import rclpy
    from mcap.exceptions import McapError
    from mcap.reader import make_reader
    from rclpy.duration import Duration
    from rosgraph_msgs.msg import Clock

    from ..progress import Bar
    from .convert import clock_msg

    say = say or (lambda text: print(f"cikan replay: {text}", file=sys.stderr, flush=True))
    if not fast and not rate > 0:
        raise CikanError(f"--rate must be > 0, got {rate}")
    path = mcap_file(bag)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    counts: Counter[str] = Counter()
    with open(path, "rb") as f:
        try:
            reader = make_reader(f)
            summary = reader.get_summary()
        except McapError as exc:
            raise CikanError(f"{path} is not a readable MCAP file ({exc})") from None
        if summary is None:
            raise CikanError(f"{path} has no summary (not closed); nothing to replay")
        channels, schemas = summary.channels, summary.schemas
        total = summary.statistics.message_count if summary.statistics else None
        has_clock = any(ch.topic == CLOCK for ch in channels.values())
        wanted = parse_wait(wait_subscribers, [ch.topic for ch in channels.values()]
                            + ([] if has_clock else [CLOCK]))
        rclpy.init()
        node = rclpy.create_node("cikan_replay")
        bar = None
        try:
            qos = qos_replay()
            pubs: dict[int, Any] = {cid: node.create_publisher(message_class(schemas[ch.schema_id].name),
                                                               ch.topic, qos)
                                    for cid, ch in channels.items()}
            clock_pub = None if has_clock else node.create_publisher(Clock, CLOCK, qos)
            by_topic = {channels[cid].topic: p for cid, p in pubs.items()}
            if clock_pub is not None:
                by_topic[CLOCK] = clock_pub
            if wanted:
                wait_for_subscribers(by_topic, wanted, wait_timeout_s, say)
                time.sleep(0.2)   # the other topics of a subscriber matched last
            elif discovery_s > 0:
                say(f"waiting {discovery_s:g} s for DDS to discover running subscribers (or use "
                    "--wait-subscribers)")
                time.sleep(discovery_s)
            if fast:
                say("--fast: reliable KEEP_ALL readers get every message; a KEEP_LAST(N) reader that "
                    "falls more than N messages behind loses the oldest (see cikan replay --help)")
                lossy = best_effort_readers(node, list(by_topic))
                if lossy:
                    say("--fast: best-effort readers may lose messages: " + "; ".join(lossy))
            bar = Bar(total, "cikan replay", "messages", progress).start()
            start_wall = time.monotonic()
            first: int | None = None
            last_clock = None
            try:
                for _schema, channel, message in reader.iter_messages(log_time_order=True):
                    if first is None:
                        first = message.log_time
                    if not fast:
                        pause = start_wall + (message.log_time - first) / 1e9 / rate - time.monotonic()
                        if pause > 0:
                            time.sleep(pause)
                    if clock_pub is not None and message.log_time != last_clock:
                        clock_pub.publish(clock_msg(message.log_time))
                        counts[CLOCK] += 1
                        last_clock = message.log_time
                    pubs[channel.id].publish(message.data)
                    counts[channel.topic] += 1
                    bar.advance()
            except McapError as exc:
                raise CikanError(f"{path}: unreadable after {sum(counts.values())} messages ({exc})") \
                    from None
            bar.close()
            unacked = [t for t, p in by_topic.items()
                       if not p.wait_for_all_acked(Duration(seconds=FINAL_ACK_TIMEOUT_S))]
            if unacked:
                say(f"not every reliable reader acknowledged the last messages within "
                    f"{FINAL_ACK_TIMEOUT_S:g} s on: {', '.join(unacked)}")
        finally:
            if bar is not None:
                bar.close()
            node.destroy_node()
            rclpy.try_shutdown()
    return dict(counts)
