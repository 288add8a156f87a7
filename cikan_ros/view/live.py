"""Following a mission as it flies, from the bag its recorder writes (``cikan mission --view``,
``cikan view BAG --follow``).

Why the bag rather than a subscription: the view then is no part of the graph. A reader on the
domain would be discovered, and every node waits at start for every reader of its topics it
discovers (:class:`cikan_ros.ros.graph.Readiness`) and, at its end, for their acknowledgements;
the bag is there anyway, and the recorder makes it readable at every flush
(``recorder.flush_period_s``, 1 s: each flush writes its chunk and a provisional summary with
the chunk indexes, :mod:`cikan_ros.ros.bag_writer`). The follower reads only chunks it has not
read yet (by their index), decodes them with rosbags' typestore (the objects :func:`read_bag
<cikan_ros.ros.bag_reader.read_bag>` returns) and rebuilds the mission flown so far with the
bag reader's :func:`~cikan_ros.ros.bag_reader.mission_from_bag`, cut at the last step every topic
has reached. A read that meets a flush half-written is tried again at the next poll.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import CikanError
from ..ros.bag_reader import bag_config, bag_governor, mission_from_bag, sim_summary
from ..ros.convert import Timeline, time_to_ns
from ..ros.graph_spec import (ACCEL_CMD, CHIEF_ODOM, DEPUTY_ODOM, DIAGNOSTICS, TIME_SHIFT, TRUTH_ACCEL,
                              TRUTH_CHIEF, TRUTH_DEPUTY)
from .data import payload, stored_dictionary, track_of

#: What the rebuilt mission reads (mission_from_bag), /clock left out.
TOPICS = (CHIEF_ODOM, DEPUTY_ODOM, TRUTH_CHIEF, TRUTH_DEPUTY, TIME_SHIFT, ACCEL_CMD, TRUTH_ACCEL, DIAGNOSTICS)
#: Topics with a message per state t_0..t_K (the others: per step t_0..t_{K-1}).
STATE_TOPICS = (CHIEF_ODOM, DEPUTY_ODOM, TRUTH_CHIEF, TRUTH_DEPUTY)


class BagFollower:
    """A bag being recorded, read as it grows (see the module docstring)."""

    def __init__(self, path: str | Path) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self.chunks: set[int] = set()
        self.msgs: dict[str, list[tuple[int, Any]]] = {}
        #: The mission has ended and every step of it is read (set by :meth:`payload`).
        self.complete = False

    def mcap_file(self) -> Path | None:
        files = sorted(self.path.glob("*.mcap"))
        return files[0] if files else None

    def poll(self) -> bool:
        """Read the chunks flushed since the last poll; True if any message came."""
        from mcap.data_stream import ReadDataStream
        from mcap.exceptions import McapError
        from mcap.reader import SeekingReader
        from mcap.records import Chunk, Message
        from mcap.stream_reader import breakup_chunk

        file = self.mcap_file()
        if file is None or not (self.path / "metadata.yaml").exists():
            return False
        new: list[tuple[int, list[tuple[str, int, Any]]]] = []
        try:
            with open(file, "rb") as f:
                summary = SeekingReader(f).get_summary()
                for ci in (summary.chunk_indexes if summary else []):
                    if ci.chunk_start_offset in self.chunks:
                        continue
                    f.seek(ci.chunk_start_offset + 1 + 8)
                    got = []
                    for rec in breakup_chunk(Chunk.read(ReadDataStream(f))):
                        if isinstance(rec, Message):
                            channel = summary.channels[rec.channel_id]
                            if channel.topic in TOPICS:
                                msg = self.typestore.deserialize_cdr(rec.data, summary.schemas[channel.schema_id].name)
                                got.append((channel.topic, rec.log_time, msg))
                    new.append((ci.chunk_start_offset, got))
        except (OSError, McapError, EOFError, ValueError, KeyError, IndexError, AttributeError):
            pass    # a flush half-written, or no summary yet: what was read whole is kept
        for offset, got in new:
            self.chunks.add(offset)
            for topic, log_time, msg in got:
                self.msgs.setdefault(topic, []).append((log_time, msg))
        return any(got for _, got in new)

    def flown(self, tl: Timeline) -> int:
        """Steps every recorded topic has reached without a gap: the states t_0..t_{n-1} of the
        mission flown so far (commands and shifts for t_0..t_{n-2})."""
        n = None
        for topic in TOPICS[:-1]:
            if topic not in self.msgs:
                continue
            ks = {tl.step(time_to_ns(m.header.stamp)) for _, m in self.msgs[topic]}
            reached = next(k for k in range(len(ks) + 1) if k not in ks)
            reached += 0 if topic in STATE_TOPICS else 1
            n = reached if n is None else min(n, reached)
        return n or 0

    def payload(self) -> dict[str, Any] | None:
        """The page's data of the mission flown so far, or None before its first time shift.
        Complete once the simulator's mission-complete record and every step it names are in."""
        cfg = bag_config(self.path, None)
        tl = Timeline(cfg.orbit.epoch_unix_s, cfg.control.period_s)
        n = self.flown(tl)
        summary = sim_summary(self.msgs)
        self.complete = summary is not None and n >= int(summary["steps"]) + 1
        end = tl.stamp_ns(n)   # the messages of t_0..t_{n-1}
        msgs = {t: [(lt, m) for lt, m in v if t == DIAGNOSTICS or time_to_ns(m.header.stamp) < end]
                for t, v in self.msgs.items()}
        try:
            result, _ = mission_from_bag(self.path, cfg, bag_governor(self.path), msgs)
        except CikanError:
            return None   # no shift yet, or no state yet
        return payload(cfg, [track_of(result, self.path.name)], str(self.path), "live", complete=self.complete,
                       stored=stored_dictionary(self.path))


#: Niceness of a view process started by ``cikan mission --view``: the graph's nodes come first
#: on a busy machine.
VIEW_NICENESS = 10


def start_view_process(bag: str | Path, port: int = 0, browser: bool = True) -> tuple[Any, str]:
    """(process, URL) of ``cikan view BAG --follow`` started in its own process, niced by
    :data:`VIEW_NICENESS` and ended with its parent (as the graph's nodes are); CikanError if it
    does not come up."""
    import os
    import subprocess
    import sys

    from ..ros.launch import die_with_parent

    with_parent = die_with_parent()

    def child() -> None:
        with_parent()
        os.nice(VIEW_NICENESS)

    argv = [sys.executable, "-m", "cikan_ros.cli", "view", str(bag), "--follow", "--port", str(port),
            *([] if browser else ["--no-browser"])]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
                            start_new_session=True, preexec_fn=child)
    with proc.stdout:   # the URL is all it prints
        line = proc.stdout.readline()
    if not line.startswith("cikan view: http"):
        proc.kill()
        proc.wait()
        raise CikanError(f"the view did not start (exit code {proc.returncode}{': ' + line.strip() if line else ''})")
    return proc, line.split()[2]
