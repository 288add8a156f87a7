"""Where a lockstep step's time goes, per node process and per stage (``cikan profile``).

With ``CIKAN_PROFILE_DIR`` set, every node process of the graph (:func:`cikan_ros.ros.graph.run_node`)
runs its spin under cProfile with the main thread's CPU clock and writes, at its end,
``<dir>/<node>.prof`` (pstats) and ``<dir>/<node>.json`` (the main thread's and the whole process's
CPU seconds over the spin). :func:`profile_table` then splits each node's main-thread CPU by stage,
from every function's own time, classified by where it lives:

- ``rclpy``: the executor, taking and deserialising messages, timers, guard conditions;
- ``publish``: serialising and writing a message to DDS (rclpy's ``publish``);
- ``messages``: building and converting messages (``cikan_ros.ros.convert``, the scene stream,
  the message classes' own Python);
- ``record``: the recorder's bag writing (``bag_writer``, mcap);
- ``compute``: the project's own work (governor, controller, simulator, their numba kernels, numpy);
- ``other``: the rest of the interpreter's time (logging, the standard library).

The process's other threads (DDS's receive and event threads, rclpy's) are the process CPU less
the main thread's. cProfile adds its own cost to every Python call (2.1x the graph's CPU per
step here, docs/ros_profile.md), so its stages are shares to read; what each node costs as flown comes from a
mission without it: with :data:`CPU_ONLY_ENV` also set, each node only counts the CPU seconds of
its spin (:func:`spin_cpu`), which ``cikan profile`` shows beside the stages and ``cikan bench``
reports per node (``ros_cpu_per_step_ms_<node>``).
No rclpy here: the node processes import it, the command only reads files.
"""

from __future__ import annotations

import json
import math
import os
import resource
import time
from pathlib import Path
from typing import Any

#: The environment variable that turns node profiling on: the directory to write to.
PROFILE_ENV = "CIKAN_PROFILE_DIR"
#: Set (to anything) beside :data:`PROFILE_ENV`: no cProfile, only the CPU seconds of the spin.
CPU_ONLY_ENV = "CIKAN_PROFILE_CPU_ONLY"
STAGES = ("rclpy", "publish", "messages", "record", "compute", "other")


class NodeProfile:
    """Profile this process's spin when :data:`PROFILE_ENV` is set (a no-op otherwise):
    ``with NodeProfile(name): spin...``; with :data:`CPU_ONLY_ENV` too, only count its CPU
    (``<dir>/<node>.json``, no ``.prof``)."""

    def __init__(self, name: str) -> None:
        self.dir = os.environ.get(PROFILE_ENV)
        self.cpu_only = bool(os.environ.get(CPU_ONLY_ENV))
        self.name = name
        self.prof: Any = None

    def __enter__(self) -> "NodeProfile":
        if self.dir:
            if not self.cpu_only:
                import cProfile

                self.prof = cProfile.Profile(time.thread_time)
            self.cpu0 = time.thread_time(), _process_cpu()
            if self.prof is not None:
                self.prof.enable()
        return self

    def __exit__(self, *exc: Any) -> None:
        if not self.dir:
            return
        if self.prof is not None:
            self.prof.disable()
        main, proc = time.thread_time() - self.cpu0[0], _process_cpu() - self.cpu0[1]
        out = Path(self.dir)
        out.mkdir(parents=True, exist_ok=True)
        if self.prof is not None:
            self.prof.dump_stats(out / f"{self.name}.prof")
        (out / f"{self.name}.json").write_text(json.dumps({"main_cpu_s": main, "process_cpu_s": proc}))


def _process_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _whole_process_s(cpu: dict[str, float]) -> float:
    """A node's spin CPU, all threads, from its ``.json``: getrusage counts in coarser ticks than
    the thread clock, so never below the main thread's."""
    return max(float(cpu["process_cpu_s"]), float(cpu["main_cpu_s"]))


def spin_cpu(directory: Path) -> dict[str, float]:
    """CPU seconds of each node's spin, all its threads (``<dir>/<node>.json``), by node name."""
    return {path.stem: _whole_process_s(json.loads(path.read_text()))
            for path in sorted(Path(directory).glob("*.json"))}


def stage_of(filename: str, function: str) -> str:
    """The stage (:data:`STAGES`) a function's own time belongs to, from its file and name."""
    f = filename.replace("\\", "/")
    if "publish" in function and ("rclpy" in f or f == "~"):
        return "publish"
    if "/rclpy/" in f or "_rclpy" in function or "rclpy" in function:
        return "rclpy"
    if "cikan_ros/ros/bag_writer" in f or "/mcap" in f or "recorder_node" in f:
        return "record"
    if ("cikan_ros/ros/convert" in f or "scene_stream" in f or "_msgs/" in f
            or "/rosidl" in f or "builtin_interfaces" in f):
        return "messages"
    if "cikan_ros/" in f or "_node/" in f or "/numba/" in f or "/numpy/" in f or "/scipy/" in f:
        return "compute"
    if f == "~" and ("numpy" in function or "numba" in function):
        return "compute"
    return "other"


def node_stages(prof_path: Path) -> dict[str, float]:
    """Seconds of main-thread CPU per stage of one node's profile (own time of each function)."""
    import pstats

    stats = pstats.Stats(str(prof_path))
    out = {s: 0.0 for s in STAGES}
    for (filename, _line, function), (_cc, _nc, tottime, _ct, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        out[stage_of(filename, function)] += tottime
    return out


def profile_table(directory: Path, steps: int, flown: dict[str, float] | None = None) -> dict[str, dict[str, float]]:
    """Per node: microseconds per step of each stage of its main thread, ``main`` (their sum),
    ``threads`` (the process's other threads) and ``process`` (all of it); with ``flown`` (each
    node's spin CPU seconds in a mission without the profiler, :func:`spin_cpu`) also
    ``flown``, the process's microseconds per step there."""
    out: dict[str, dict[str, float]] = {}
    for prof in sorted(Path(directory).glob("*.prof")):
        cpu = json.loads(prof.with_suffix(".json").read_text())
        stages = node_stages(prof)
        row = {s: v / steps * 1e6 for s, v in stages.items()}
        row["main"] = cpu["main_cpu_s"] / steps * 1e6
        row["threads"] = max(0.0, cpu["process_cpu_s"] - cpu["main_cpu_s"]) / steps * 1e6
        row["process"] = _whole_process_s(cpu) / steps * 1e6
        if flown is not None:
            row["flown"] = flown.get(prof.stem, math.nan) / steps * 1e6
        out[prof.stem] = row
    return out


def markdown(table: dict[str, dict[str, float]], steps: int, wall_s: float, command: str,
             flown_wall_s: float | None = None, layout: str | None = None) -> str:
    """The profile page: CPU microseconds per step, per node process and stage (and as flown,
    without the profiler, when the table has it); ``layout``: the process layout flown, named."""
    flown = all("flown" in r for r in table.values()) and bool(table)
    cols = STAGES + ("main", "threads", "process") + (("flown",) if flown else ())
    where = f" in process layout `{layout}` (cikan_ros.ros.graph_spec.LAYOUTS)" if layout else ""
    text = (f"Regenerate: `{command}` (docs/usage.md, `cikan profile`). One lockstep mission of {steps} steps{where}, "
            f"{wall_s:.2f} s of lockstep wall time under the profiler; CPU microseconds per step (main thread "
            "by stage, from each function's own time; other threads; the whole process).")
    if flown:
        text += (f" **flown**: the whole process's CPU per step in the same mission flown just before without the "
                 f"profiler ({flown_wall_s:.2f} s of lockstep wall time; its spin from start to end, the readiness "
                 "handshake and the acknowledgements included): what each node costs as flown. The profiler's "
                 "stages are shares of it to read, not its microseconds.")
    lines = ["# Where a lockstep step goes: CPU per node process and stage", "", text, "",
             "| node | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for node, row in table.items():
        lines.append(f"| {node} | " + " | ".join(f"{row[c]:.0f}" for c in cols) + " |")
    total = {c: sum(r[c] for r in table.values()) for c in cols}
    lines.append("| **all** | " + " | ".join(f"**{total[c]:.0f}**" for c in cols) + " |")
    return "\n".join(lines) + "\n"
