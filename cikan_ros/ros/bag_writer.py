"""The bag writer: rosbag2 bag directories (metadata.yaml version 9 + one MCAP file) written from
raw CDR bytes, by the recorder (:mod:`cikan_ros.ros.recorder_node`) and by tests. Reading a bag
back: :mod:`cikan_ros.ros.bag_reader`.

``with BagWriter(path) as bag:`` closes the bag when the block ends, also on an exception (what
was written is then a complete, readable bag).

What rosbag2 itself writes and what independent readers (rosbags, mcap, Foxglove) expect:
profile ``ros2``; one schema per type, encoding ``ros2msg``, text = the installed .msg file
followed, for every type it depends on, by a line of 80 '=' and ``MSG: pkg/Type`` and that
type's .msg text; message encoding ``cdr``; channel metadata ``offered_qos_profiles`` (the same
YAML text as in metadata.yaml) and ``topic_type_hash`` (RIHS01 from the installed .json).

Crash safety: messages go into MCAP chunks; :meth:`BagWriter.flush` closes the current chunk and
writes it, its message indexes and a provisional end of file (DataEnd, the summary with the chunk
indexes so far, Footer, magic: what the MCAP writer's ``finish`` would write now, produced by a
copy of the writer) in ONE write at the logical end of the data; the next flush overwrites that
trailer. The chunk indexes matter: messages are stored in arrival order, which differs slightly
from stamp order across topics, and rosbags refuses unindexed files that are not time-ordered.
metadata.yaml is rewritten atomically (temp file + rename) after each flush with the counts
flushed so far. So after a SIGKILL the directory is a complete, readable bag up to the last
flushed chunk, and a clean close writes the full summary.

Flushing in the background (``BagWriter(..., background=True)``, the recorder's): a flush (~3-4 ms
of CPU for a 1 MiB chunk: compressing it, its message indexes (packed: :class:`_PackedMessageIndex`),
the provisional summary (:func:`_provisional_trailer`), metadata.yaml) runs
in a thread of its own, as rosbag2's recorder writes from a cache consumer thread, so that the
executor thread that takes the messages (in the default process layout the simulator's too)
goes on meanwhile. Messages that arrive during a flush are held, in arrival order, and written
when it has ended (at the next write, flush or close); one flush at a time. The same bytes reach
the file in the same order as flushing in place, at most one flush later.
"""

from __future__ import annotations

import copy
import json
import os
import re
import struct
import threading
from pathlib import Path
from types import TracebackType
from typing import Any

import yaml
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.writer import CompressionType, Writer

from ..paths import install_prefixes

#: The YAML emitter of metadata.yaml: libyaml's when PyYAML has it (its wheels do), else PyYAML's.
YAML_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)

#: The name of the telemetry dictionary (:mod:`cikan_ros.telemetry`) in a bag: an MCAP metadata
#: record of this name (keys ``format``, ``version``, ``json``: the document) and an MCAP attachment
#: ``<name>.json`` (what the mcap tools list), and metadata.yaml custom_data
#: ``cikan_ros.telemetry`` (what rosbags reads).
TELEMETRY_RECORD = "cikan_telemetry"
TELEMETRY_CUSTOM_KEY = "cikan_ros.telemetry"

#: What metadata.yaml calls the files' distribution.
ROS_DISTRO = "jazzy"
_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
               "int32", "uint32", "int64", "uint64", "string", "wstring"}


def share_dirs() -> list[Path]:
    """Where installed interface packages live: ``share/`` of each install prefix (:mod:`cikan_ros.paths`)."""
    return [prefix / "share" for prefix in install_prefixes()]


def _msg_file(pkg: str, name: str, suffix: str) -> Path:
    for share in share_dirs():
        path = share / pkg / "msg" / f"{name}{suffix}"
        if path.exists():
            return path
    raise FileNotFoundError(f"message definition {pkg}/msg/{name}{suffix} not found in "
                            f"{[str(s) for s in share_dirs()]}")


def _dependencies(pkg: str, text: str) -> list[tuple[str, str]]:
    """(pkg, Type) of the non-primitive field types of a .msg text, in order of appearance."""
    out: list[tuple[str, str]] = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        ftype, _, rest = line.partition(" ")
        if "=" in rest.split(" ", 1)[0] or re.match(r"^\s*[A-Z0-9_]+\s*=", rest):
            continue  # a constant
        base = re.sub(r"\[.*\]$", "", ftype)
        base = re.sub(r"<=\d+$", "", base)
        if base in _PRIMITIVES:
            continue
        if base == "Header":
            out.append(("std_msgs", "Header"))
        elif "/" in base:
            parts = base.split("/")
            out.append((parts[0], parts[-1]))
        else:
            out.append((pkg, base))
    return out


def schema_text(type_name: str) -> str:
    """The ros2msg schema of ``pkg/msg/Type``: its .msg text, then each dependency once."""
    pkg, _, name = type_name.split("/")
    root = _msg_file(pkg, name, ".msg").read_text()
    parts = [root.rstrip("\n")]
    seen: set[tuple[str, str]] = set()
    queue = _dependencies(pkg, root)
    while queue:
        dep = queue.pop(0)
        if dep in seen:
            continue
        seen.add(dep)
        text = _msg_file(dep[0], dep[1], ".msg").read_text()
        parts.append("=" * 80 + f"\nMSG: {dep[0]}/{dep[1]}\n" + text.rstrip("\n"))
        queue.extend(_dependencies(dep[0], text))
    return "\n".join(parts) + "\n"


def type_hash(type_name: str) -> str:
    """RIHS01 type hash of ``pkg/msg/Type`` from the installed .json description."""
    pkg, _, name = type_name.split("/")
    data = json.loads(_msg_file(pkg, name, ".json").read_text())
    for entry in data.get("type_hashes", []):
        if entry.get("type_name") == type_name:
            return str(entry["hash_string"])
    raise ValueError(f"no type hash for {type_name} in its .json description")


# -- QoS ----------------------------------------------------------------------------------------
_INFINITE = {"sec": 2147483647, "nsec": 4294967295}


def _duration(d: Any) -> dict[str, int]:
    ns = int(d.nanoseconds)
    if ns <= 0 or ns >= 2147483647 * 10**9:
        return dict(_INFINITE) if ns != 0 else {"sec": 0, "nsec": 0}
    sec, nsec = divmod(ns, 10**9)
    return {"sec": sec, "nsec": nsec}


def qos_dict(qos: Any) -> dict[str, Any]:
    """rosbag2 (metadata version 9) form of an rclpy QoSProfile."""
    def name(policy: Any) -> str:
        return policy.name.lower()

    return {"history": name(qos.history), "depth": int(qos.depth), "reliability": name(qos.reliability),
            "durability": name(qos.durability), "deadline": _duration(qos.deadline),
            "lifespan": _duration(qos.lifespan), "liveliness": name(qos.liveliness),
            "liveliness_lease_duration": _duration(qos.liveliness_lease_duration),
            "avoid_ros_namespace_conventions": bool(qos.avoid_ros_namespace_conventions)}


def qos_text(profiles: list[dict[str, Any]]) -> str:
    """The one YAML text of a list of QoS dicts used both in the channel and in metadata.yaml."""
    return yaml.safe_dump(profiles, default_flow_style=False, sort_keys=False).strip() if profiles else ""


# -- the file sink ------------------------------------------------------------------------------
class _Capture:
    """Stream stand-in that keeps what a writer copy writes, at the sink's logical offsets."""

    def __init__(self, start: int) -> None:
        self.start = start
        self.data = bytearray()

    def write(self, data: Any) -> int:
        self.data += data
        return len(data)

    def tell(self) -> int:
        return self.start + len(self.data)

    def flush(self) -> None:
        pass


class _Sink:
    """File the MCAP writer writes to: bytes are kept until :meth:`commit` stores them, with a
    provisional trailer, in one write at the logical end (overwriting the previous trailer)."""

    def __init__(self, path: Path) -> None:
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self.pos = 0            # logical end of what the writer has written and we have stored
        self.pending = bytearray()

    def write(self, data: Any) -> int:
        self.pending += data
        return len(data)

    def tell(self) -> int:
        return self.pos + len(self.pending)

    def commit(self, trailer: bytes) -> None:
        data = bytes(self.pending) + trailer
        done = 0
        while done < len(data):
            done += os.pwrite(self.fd, data[done:], self.pos + done)
        self.pos += len(self.pending)
        self.pending.clear()
        if not trailer:
            os.ftruncate(self.fd, self.pos)

    def flush(self) -> None:  # the MCAP writer's stream.flush(): the BagWriter commits
        pass

    def close(self) -> None:
        if self.fd >= 0:
            self.commit(b"")
            os.fsync(self.fd)
            os.close(self.fd)
            self.fd = -1


class _PackedMessageIndex(MessageIndex):
    """mcap's MessageIndex record, its (log time, offset) entries packed in one ``struct.pack``
    rather than two calls per message: the same bytes (tests/test_ros_convert.py). The indexes
    of a 1 MiB chunk (~2,700 messages, nine topics) took 1.4 ms of Python, 0.35 ms packed; a
    flush of a mission's bag (its 16,387 messages written again, six flushes, three alternating
    rounds) 4.5-6.2 -> 3.7-3.8 ms of CPU (medians): GIL the recorder's flush thread no longer
    takes from the simulator beside it."""

    def write(self, stream: Any) -> None:
        n = len(self.records)
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(n * 16)
        stream.write(struct.pack(f"<{2 * n}Q", *[v for entry in self.records for v in entry]))
        stream.finish_record()


def _pack_message_indexes(writer: Writer) -> None:
    """Make the open chunk's message indexes :class:`_PackedMessageIndex` before mcap's writer
    writes them (its chunk builder is private: with an mcap that keeps it elsewhere, nothing
    changes and the library writes them itself)."""
    builder = getattr(writer, "_Writer__chunk_builder", None)
    for index in getattr(builder, "message_indices", {}).values():
        if type(index) is MessageIndex:
            index.__class__ = _PackedMessageIndex


#: The private state of mcap's Writer that ``finish`` changes (everything else it only reads).
_FINISH_WRITES = ("_Writer__stream", "_Writer__record_builder", "_Writer__summary_offsets",
                  "_Writer__should_close")


def _provisional_trailer(writer: Writer, stream: Any) -> bytes:
    """What ``writer.finish()`` would write now to ``stream``, the writer's output (DataEnd,
    summary, Footer, magic), its chunk closed; the writer and the stream are left as they were.

    ``finish`` of a shallow copy whose stream, record builder and summary offsets are its own:
    the same bytes as ``finish`` of a deep copy (tests/test_ros_convert.py), without copying the
    schemas, channels and chunk indexes: 0.42 -> 0.18 ms of CPU a flush (a mission's bag, its
    ten flushes of 1 MiB, medians). With an mcap whose writer keeps that state elsewhere, a deep
    copy."""
    capture = _Capture(stream.tell())
    if all(hasattr(writer, name) for name in _FINISH_WRITES):
        clone = copy.copy(writer)
        clone._Writer__stream = capture
        clone._Writer__record_builder = RecordBuilder()
        clone._Writer__summary_offsets = []
        clone._Writer__should_close = False
    else:
        clone = copy.deepcopy(writer, memo={id(stream): capture})
    clone.finish()
    return bytes(capture.data)


class BagWriter:
    """A rosbag2 MCAP bag directory written from raw CDR messages (see the module docstring); a
    context manager that closes it."""

    def __init__(self, path: str | Path, chunk_bytes: int = 256 * 1024,
                 custom_data: dict[str, str] | None = None, background: bool = False) -> None:
        self.dir = Path(path)
        #: :meth:`write` flushes once this many message bytes are unflushed (0: only when asked).
        self.chunk_bytes = int(chunk_bytes)
        #: Flush in a thread of its own (module docstring).
        self.background = background
        self._flusher: threading.Thread | None = None
        self._flush_error: BaseException | None = None
        self._held: list[tuple[str, bytes, int, int | None]] = []   # arrived during a background flush
        #: metadata.yaml ``custom_data`` (string -> string), e.g. the mission's configuration.
        self.custom_data = dict(custom_data or {})
        if self.dir.exists() and any(self.dir.iterdir()):
            raise FileExistsError(f"bag directory {self.dir} exists and is not empty")
        self.dir.mkdir(parents=True, exist_ok=True)
        self.file = self.dir / f"{self.dir.name}_0.mcap"
        self.sink = _Sink(self.file)
        # Chunks are closed by flush() (size or time), never by the MCAP writer itself.
        self.writer = Writer(self.sink, chunk_size=1 << 62, compression=CompressionType.ZSTD)
        self.writer.start(profile="ros2", library="cikan_ros recorder (mcap python)")
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.topics: dict[str, dict[str, Any]] = {}
        self.counts: dict[str, int] = {}
        self.flushed: dict[str, int] = {}
        self.qos_lists: dict[str, list[dict[str, Any]]] = {}   # metadata.yaml's form of the QoS text
        self.times: list[int] = []   # [first, last] log time
        self.flushed_times: list[int] = []
        self.unflushed_bytes = 0
        self.closed = False
        #: Each topic's metadata.yaml entry but its count, rendered once (:meth:`metadata_text`).
        self.topic_yaml: dict[str, str] = {}
        #: metadata.yaml's custom_data and ros_distro entries, rendered, and what they render.
        self._custom_yaml: tuple[tuple[dict[str, str], str] | None, str] = (None, "")
        self.write_metadata()

    def add_topic(self, topic: str, type_name: str, qos_profiles: list[dict[str, Any]]) -> None:
        """Register a topic (once) with the QoS profiles its publishers offer."""
        if topic in self.channels:
            return
        self.settle()
        if type_name not in self.schemas:
            self.schemas[type_name] = self.writer.register_schema(
                name=type_name, encoding="ros2msg", data=schema_text(type_name).encode())
        thash = type_hash(type_name)
        qtext = qos_text(qos_profiles)
        self.channels[topic] = self.writer.register_channel(
            topic=topic, message_encoding="cdr", schema_id=self.schemas[type_name],
            metadata={"offered_qos_profiles": qtext, "topic_type_hash": thash})
        self.topics[topic] = {"name": topic, "type": type_name, "serialization_format": "cdr",
                              "offered_qos_profiles": qtext, "type_description_hash": thash}
        self.qos_lists[topic] = list(qos_profiles) if qtext else []
        self.topic_yaml[topic] = _indented(yaml.dump([{"topic_metadata": self._topic_metadata(topic)}],
                                                     Dumper=YAML_DUMPER, sort_keys=False))
        self.counts[topic] = 0
        self.flushed[topic] = 0

    def add_telemetry(self, doc: dict[str, Any]) -> None:
        """Store the telemetry dictionary document (:func:`cikan_ros.telemetry.to_json`) in the bag
        (see :data:`TELEMETRY_RECORD`), once, before or among the messages."""
        text = json.dumps(doc, allow_nan=False, sort_keys=False)
        self.settle()
        self.writer.add_metadata(TELEMETRY_RECORD, {"format": str(doc["format"]),
                                                    "version": str(doc["version"]), "json": text})
        self.writer.add_attachment(create_time=0, log_time=0, name=f"{TELEMETRY_RECORD}.json",
                                   media_type="application/json", data=text.encode())
        self.custom_data[TELEMETRY_CUSTOM_KEY] = text
        self.write_metadata()

    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """Append one serialised message of a registered topic (held while a background flush runs);
        flush once ``chunk_bytes`` are unflushed."""
        if topic not in self.channels:
            raise KeyError(topic)
        if self._flusher is not None:
            if self._flusher.is_alive():
                self._held.append((topic, bytes(data), log_time_ns, publish_time_ns))
                return
            self.settle()
        self._write(topic, data, log_time_ns, publish_time_ns)
        if self.chunk_bytes and self.unflushed_bytes >= self.chunk_bytes:
            self.flush()

    def _write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None) -> None:
        self.writer.add_message(self.channels[topic], log_time=log_time_ns, data=bytes(data),
                                publish_time=log_time_ns if publish_time_ns is None else publish_time_ns,
                                sequence=self.counts[topic])
        self.counts[topic] += 1
        self.times = [min(self.times[0], log_time_ns), max(self.times[1], log_time_ns)] if self.times \
            else [log_time_ns, log_time_ns]
        self.unflushed_bytes += len(data)

    def settle(self) -> None:
        """Wait for a background flush to end (re-raising what it raised), then write the messages
        held meanwhile. What every change of the writer but a message's does first."""
        if self._flusher is not None:
            self._flusher.join()
            self._flusher = None
            error, self._flush_error = self._flush_error, None
            if error is not None:
                raise error
        held, self._held = self._held, []
        for message in held:
            self._write(*message)

    def flush(self) -> None:
        """Close the current chunk, store it with a provisional end of file, update metadata.yaml;
        in a thread when ``background`` (nothing if a flush is running: the next one takes what
        came since)."""
        if self._flusher is not None:
            if self._flusher.is_alive():
                return
            self.settle()
        if self.closed or self.unflushed_bytes == 0 and self.flushed == self.counts:
            return
        if not self.background:
            self._flush()
            return
        self._flusher = threading.Thread(target=self._flush_keeping_error, name="bag flush", daemon=True)
        self._flusher.start()

    def _flush_keeping_error(self) -> None:
        try:
            self._flush()
        except BaseException as exc:   # re-raised by settle() in the thread that uses the bag
            self._flush_error = exc

    def _flush(self) -> None:
        _pack_message_indexes(self.writer)
        self.writer.flush()   # finalize the chunk (kept in the sink)
        self.sink.commit(_provisional_trailer(self.writer, self.sink))
        self.flushed = dict(self.counts)
        self.flushed_times = list(self.times)
        self.unflushed_bytes = 0
        self._write_metadata()

    def close(self) -> None:
        """Finish the MCAP file (summary, footer) and write the final metadata.yaml."""
        if self.closed:
            return
        try:
            self.settle()
        except BaseException:
            self._held.clear()   # the file ends at the last flush that succeeded; close it all the same
        try:
            _pack_message_indexes(self.writer)
            self.writer.finish()
        finally:
            self.sink.close()
            self.closed = True
        self.flushed = dict(self.counts)
        self.flushed_times = list(self.times)
        self._write_metadata()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        """Close the bag, whether the block ended normally or by an exception (which propagates)."""
        self.close()

    def _flushed_span(self) -> tuple[int, int, int]:
        """(first, last log time, messages) of what is flushed."""
        start, end = self.flushed_times if self.flushed_times else (0, 0)
        return start, end, sum(self.flushed.values())

    def metadata_info(self) -> dict[str, Any]:
        """metadata.yaml's ``rosbag2_bagfile_information`` (version 9) for what is flushed."""
        start, end, total = self._flushed_span()
        return {
            **self._metadata_head(start, end, total),
            "topics_with_message_count": [
                {"topic_metadata": self._topic_metadata(t), "message_count": self.flushed[t]}
                for t in self.topics],
            **self._metadata_tail(start, end, total),
        }

    def _topic_metadata(self, topic: str) -> dict[str, Any]:
        return {**self.topics[topic], "offered_qos_profiles": self.qos_lists[topic]}

    @staticmethod
    def _metadata_head(start: int, end: int, total: int) -> dict[str, Any]:
        return {"version": 9, "storage_identifier": "mcap", "duration": {"nanoseconds": end - start},
                "starting_time": {"nanoseconds_since_epoch": start}, "message_count": total}

    def _metadata_tail(self, start: int, end: int, total: int) -> dict[str, Any]:
        return {"compression_format": "", "compression_mode": "", "relative_file_paths": [self.file.name],
                "files": [{"path": self.file.name, "starting_time": {"nanoseconds_since_epoch": start},
                           "duration": {"nanoseconds": end - start}, "message_count": total}],
                "custom_data": self.custom_data, "ros_distro": ROS_DISTRO}

    def metadata_text(self) -> str:
        """The YAML text of :meth:`metadata_info` (under ``rosbag2_bagfile_information``).

        Each topic's entry is rendered once, when the topic is added, and only its message count
        each time: PyYAML represents a document in Python (libyaml only emits it), and the thirteen
        topics' QoS profiles took 1.8 of the 1.9 ms a rewrite cost, inside the recorder's flush,
        whose burst of CPU lengthened the lockstep steps it fell on by 3-5 ms (2 cores). The custom
        data (the configuration and the telemetry dictionary, ~8 kB of text) likewise, rendered
        again only when they change: the text of a rewrite 0.21 -> 0.13 ms of CPU (median of 200,
        every topic of the graph). The keys of a block mapping are rendered one by one, so the
        tail's parts joined are the tail's text."""
        start, end, total = self._flushed_span()
        head = yaml.dump({"rosbag2_bagfile_information": self._metadata_head(start, end, total)},
                         Dumper=YAML_DUMPER, sort_keys=False)
        if self.topics:
            topics = "  topics_with_message_count:\n" + "".join(
                self.topic_yaml[t] + f"    message_count: {self.flushed[t]}\n" for t in self.topics)
        else:
            topics = "  topics_with_message_count: []\n"
        tail = self._metadata_tail(start, end, total)
        custom, distro = tail.pop("custom_data"), tail.pop("ros_distro")   # the tail's last two keys
        if self._custom_yaml[0] != (custom, distro):   # rendered again only when they change
            self._custom_yaml = ((dict(custom), distro), yaml.dump({"custom_data": custom, "ros_distro": distro},
                                                                   Dumper=YAML_DUMPER, sort_keys=False))
        tail_text = yaml.dump(tail, Dumper=YAML_DUMPER, sort_keys=False) + self._custom_yaml[1]
        return head + topics + _indented(tail_text)

    def write_metadata(self) -> None:
        """metadata.yaml for what is flushed (:meth:`metadata_text`), atomically (after a background
        flush that runs: change ``custom_data`` only after :meth:`settle`)."""
        self.settle()
        self._write_metadata()

    def _write_metadata(self) -> None:
        tmp = self.dir / "metadata.yaml.tmp"
        tmp.write_text(self.metadata_text())
        os.replace(tmp, self.dir / "metadata.yaml")


def _indented(text: str, spaces: int = 2) -> str:
    """``text`` (a YAML block) with every line indented by ``spaces`` more: the same node, nested."""
    pad = " " * spaces
    return "".join(pad + line for line in text.splitlines(keepends=True))
