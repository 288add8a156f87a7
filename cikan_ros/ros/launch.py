"""The graph launcher behind ``cikan mission`` (ROS mode) and the ROS benchmark.

Starts recorder_node, governor_node, controller_node and sim_node in the processes of a layout
(:data:`~cikan_ros.ros.graph_spec.LAYOUTS`; by default the simulator with the recorder and the
governor with the controller, two processes; ``separate``: one each; fresh interpreters, own
process groups) on an isolated domain: a ROS_DOMAIN_ID that no other live graph
of the machine uses (leased for the graph's lifetime, :mod:`cikan_ros.ros.domain`), DDS over
UDP on the loopback interface only (:func:`dds_environment`) and a private ROS_LOG_DIR. Every node gets the same
params file (the mission's configuration plus node parameters); ``governor_exec`` runs any
executable in place of governor_node with the same arguments (the governor contract, docs/governor_contract.md).
The simulator ends the lockstep; the launcher then stops the governor and the controller, then
the recorder (which drains and closes the bag), rebuilds the mission from the bag and returns
the offline metrics plus the bag path. Ctrl-C (or SIGTERM) stops every child in the same order
and leaves a closed bag; if the launcher itself is killed, its children get SIGTERM from the
kernel (PR_SET_PDEATHSIG) and end the same way.
"""

from __future__ import annotations

import os
import ctypes
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import yaml

from ..config import Config
from ..errors import CikanError, ConfigError, MissionError
from ..paths import shipped
from ..progress import Bar
from ..tsg import Predictor
from .bag_reader import SIM_TOPICS, check_messages, read_bag, recorded_metrics, sim_summary
from .domain import lease_domain
from .graph_spec import (ACCEL_CMD, ACK_BUDGET_S, ARGUMENTS, CLOCK, DEFAULT_LAYOUT, EXIT_BAD_INPUT, MAX_DRAIN_S,
                         NODE_BY_NAME, TIME_SHIFT, UTC_FORMAT, as_group, node_parameters, process_name,
                         processes)


def _nest(flat: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, value in flat.items():
        group, _, key = name.partition(".")
        out.setdefault(group, {})[key] = value
    return out


def write_params(path: Path, cfg: Config, node_params: dict[str, Any]) -> Path:
    """A ROS 2 params file (``/**: ros__parameters:``) with the configuration and node parameters."""
    params = _nest({**cfg.flat(), **node_params})
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}, sort_keys=False))
    return path


#: Fast DDS profile of every process of a graph: UDPv4 on the loopback interface, no shared memory
#: (the file says why).
FASTDDS_PROFILE = shipped("config/fastdds_udp_localhost.xml")


def dds_environment() -> dict[str, str]:
    """How every process of a graph talks: :data:`FASTDDS_PROFILE`, which rmw_fastrtps applies
    as it is only with ``ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT`` (``LOCALHOST`` would add
    the shared-memory transport)."""
    return {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT", "FASTRTPS_DEFAULT_PROFILES_FILE": str(FASTDDS_PROFILE)}


def ros_environment(domain_id: int, log_dir: Path) -> dict[str, str]:
    """Environment of the children: isolated domain, loopback-only transport
    (:func:`dds_environment`), private log directory."""
    env = dict(os.environ)
    # PYTHONSAFEPATH: `python -m cikan_ros...` would otherwise put the working directory first on
    # the nodes' sys.path, and a cikan_ros checkout there (another commit's) would fly in place
    # of the package the launcher imported.
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_LOG_DIR=str(log_dir), PYTHONUNBUFFERED="1",
               RCUTILS_COLORIZED_OUTPUT="0", PYTHONSAFEPATH="1", **dds_environment())
    return env


#: prctl(2) option: the signal a child gets when the thread that started it dies.
PR_SET_PDEATHSIG = 1


def die_with_parent() -> Callable[[], None]:
    """A ``preexec_fn`` that makes the child receive SIGTERM when this process dies (even by
    SIGKILL), so no node outlives its launcher. prctl is resolved here, in the parent: the child
    only makes the system call between fork and exec."""
    prctl = ctypes.CDLL(None, use_errno=True).prctl
    parent = os.getpid()

    def child() -> None:
        prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
        if os.getppid() != parent:   # the launcher died before prctl took effect
            os._exit(1)
    return child


def exec_command(command: str) -> list[str]:
    """``--governor-exec`` text as an argv; CikanError if it is empty or not an executable."""
    try:
        argv = shlex.split(command)
    except ValueError as exc:
        raise CikanError(f"--governor-exec {command!r}: {exc}") from None
    if not argv:
        raise CikanError("--governor-exec: empty command")
    if shutil.which(argv[0]) is None:
        raise CikanError(f"--governor-exec: {argv[0]!r} is not an executable file (or not on PATH)")
    return argv


def exec_governor_name(command: str) -> str:
    """The governor name of a mission flown by ``--governor-exec COMMAND`` (the bag's and the
    metrics')."""
    return f"exec:{command}"


def exec_environment(env: dict[str, str]) -> dict[str, str]:
    """Environment of an external governor: the graph's, without the ROS-wheels bootstrap guard
    (its interpreter, maybe of another venv, sets up its own ROS libraries) and with the user's
    own PYTHONSAFEPATH (a Python script beside its modules imports them)."""
    out = {k: v for k, v in env.items() if k not in ("_ROS_WHEELS_BOOTSTRAP_COMPLETE", "PYTHONSAFEPATH")}
    if "PYTHONSAFEPATH" in os.environ:
        out["PYTHONSAFEPATH"] = os.environ["PYTHONSAFEPATH"]
    return out


@dataclass
class Graph:
    """Running node processes of one mission (see the module docstring). ``procs`` and ``logs``
    by node name: the nodes of one process share its Popen and its log."""

    workdir: Path
    env: dict[str, str]
    params: Path
    procs: dict[str, subprocess.Popen] = field(default_factory=dict)
    logs: dict[str, Path] = field(default_factory=dict)
    #: argv (before ``--ros-args``) of a node run by another executable, e.g. ``{"governor": [...]}``.
    commands: dict[str, list[str]] = field(default_factory=dict)
    #: Descriptors every node inherits: the domain lease's, so the lease lasts while any node runs.
    pass_fds: tuple[int, ...] = ()

    def argv(self, group: str | Iterable[str]) -> list[str]:
        """Command line of a process (a node's name, or several): a node's module (``python -m``,
        :data:`graph_spec.NODES <cikan_ros.ros.graph_spec.NODES>`), its replacement, or for several
        nodes the container (:mod:`cikan_ros.ros.container`), + ``--ros-args --params-file``."""
        group = as_group(group)
        if len(group) > 1:
            head = [sys.executable, "-m", "cikan_ros.ros.container", *group]
        else:
            head = self.commands.get(group[0]) or [sys.executable, "-m", NODE_BY_NAME[group[0]].module]
        return [*head, "--ros-args", "--params-file", str(self.params)]

    def start(self, groups: Iterable[str | Iterable[str]]) -> None:
        """Start one process per group of node names (:func:`graph_spec.processes
        <cikan_ros.ros.graph_spec.processes>`; a name alone: that node in a process of its own)."""
        for group in map(as_group, groups):
            log = self.workdir / f"{process_name(group)}.log"
            env = exec_environment(self.env) if group[0] in self.commands else self.env
            with open(log, "wb") as out:
                proc = subprocess.Popen(
                    self.argv(group), env=env, stdout=out, stderr=subprocess.STDOUT,
                    stdin=subprocess.DEVNULL, start_new_session=True, preexec_fn=die_with_parent(),
                    pass_fds=self.pass_fds)
            for name in group:
                self.procs[name], self.logs[name] = proc, log

    def process_of(self, name: str) -> str:
        """What a node runs in, for messages: ``sim_node``, or ``sim_node (in recorder+sim)``."""
        group = [n for n, p in self.procs.items() if p is self.procs.get(name)]
        return f"{name}_node" if len(group) <= 1 else f"{name}_node (in {process_name(group)})"

    def tail(self, name: str, lines: int = 15) -> str:
        try:
            return "\n".join(self.logs[name].read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""

    def reason(self, name: str) -> str:
        """The last line of a node's log that names an error (else its last line), shortened."""
        lines = [ln.strip() for ln in self.tail(name, 40).splitlines() if ln.strip()]
        errors = [ln for ln in lines if "error" in ln.lower()]
        text = (errors or lines or ["no output"])[-1]
        return text if len(text) <= 300 else text[:297] + "..."

    def stop(self, names: Iterable[str], timeout_s: float = 10.0) -> None:
        """SIGINT the processes of the named nodes, wait, escalate to SIGKILL after ``timeout_s``."""
        procs = list({id(self.procs[n]): self.procs[n] for n in names if n in self.procs}.values())
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        deadline = time.monotonic() + timeout_s
        for p in procs:
            try:
                p.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()

    def stop_all(self) -> None:
        """Producers first, the recorder's process last so the bag gets everything and closes."""
        # each waits for its readers' acknowledgements before it ends (graph.wait_acknowledged)
        recorder = self.procs.get("recorder")
        self.stop([n for n in ("sim", "governor", "controller") if self.procs.get(n) is not recorder],
                  timeout_s=ACK_BUDGET_S + 10.0)
        self.stop(["recorder"], timeout_s=MAX_DRAIN_S + 30.0)   # it drains all it holds, then closes


@contextmanager
def node_environment(name: str, value: str) -> Iterator[None]:
    """Set the environment variable ``name`` for the node processes the block launches (they
    inherit this process's environment), and restore it after: e.g. the executor a benchmark
    mission runs (``CIKAN_ROS_EXECUTOR``) or where its nodes write their profiles."""
    previous = os.environ.get(name)
    os.environ[name] = value
    try:
        yield
    finally:
        if previous is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = previous


def default_bag_path(governor: str) -> Path:
    """The bag of a mission not told where to record (graph_spec.ARGUMENTS["bag"]), for ``governor``
    (a model path by its name)."""
    label = Path(governor).stem if os.sep in governor or governor.endswith((".json", ".safetensors")) \
        else governor
    return Path(ARGUMENTS["bag"].format(utc=datetime.now(timezone.utc).strftime(UTC_FORMAT), governor=label))


def discard_empty_bag(bag: Path) -> bool:
    """Remove a bag directory the recorder closed without a message (so a rerun may use the
    path); True if it was removed. A bag with messages is left as it is."""
    import yaml as _yaml

    try:
        meta = _yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    except (OSError, TypeError, KeyError, _yaml.YAMLError):
        return False
    if meta.get("message_count") != 0:
        return False
    names = {"metadata.yaml", *meta.get("relative_file_paths", [])}
    if any(p.name not in names for p in bag.iterdir()):
        return False   # something else lives there: leave it
    shutil.rmtree(bag, ignore_errors=True)
    return True


#: How often (wall) the launcher looks at the bag for its progress bar.
PROGRESS_PERIOD_S = 0.5


def recorded_steps_so_far(bag: Path) -> int:
    """Steps of a running mission the recorder has written to ``bag`` so far: its /clock messages
    after the first (t_0), from metadata.yaml, which the recorder rewrites atomically at every
    flush (``recorder.flush_period_s``). Read by the launcher alone: it costs the graph nothing.
    0 before the first flush."""
    try:
        meta = yaml.load((bag / "metadata.yaml").read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
        topics = meta["rosbag2_bagfile_information"]["topics_with_message_count"]
    except (OSError, TypeError, KeyError, yaml.YAMLError):
        return 0
    clock = [t["message_count"] for t in topics if t.get("topic_metadata", {}).get("name") == CLOCK]
    return max(0, int(clock[0]) - 1) if clock else 0


def run_ros_mission(cfg: Config, governor: str = "conventional", seed: int | None = None,
                    bag: str | os.PathLike | None = None, config_path: str | None = None,
                    overrides: list[str] | None = None, *, stop_on_dock: bool = False,
                    node_params: dict[str, Any] | None = None, timeout_s: float = 3600.0,
                    keep_logs: bool = False, on_started: Any = None,
                    governor_exec: str | None = None, progress: bool = False,
                    layout: str = DEFAULT_LAYOUT) -> dict[str, Any]:
    """Run one lockstep mission as the ROS graph; return the recorded metrics
    (:func:`cikan_ros.ros.bag_reader.recorded_metrics`) + ``bag`` + ``ros``.

    ``governor_exec``: a command line run in place of governor_node (the contract of docs/governor_contract.md); it
    gets ``--ros-args --params-file FILE`` appended, the graph's environment, and
    ``governor.name`` = ``exec:<command>`` (the name the bag and the metrics carry).
    ``config_path``/``overrides`` are accepted for the record (``cfg`` already contains them).
    ``node_params`` adds or overrides node parameters (e.g. deadlines); ``on_started(graph)`` is
    called once every process runs (tests use it to inject faults). A failure raises one
    CikanError line naming the node, its exit code, its last error line and where the logs are;
    a bag without a message is removed then, a bag with messages is kept (closed, readable).
    ``progress``: show a progress bar of the steps the recorder has written to the bag
    (:func:`recorded_steps_so_far`). ``layout``: how the nodes share processes
    (:data:`~cikan_ros.ros.graph_spec.LAYOUTS`; a governor run by ``governor_exec`` has a
    process of its own in any).
    """
    commands = {"governor": exec_command(governor_exec)} if governor_exec is not None else {}
    try:
        groups = processes(layout, commands)
    except ValueError as exc:
        raise CikanError(str(exc)) from None
    if governor_exec is not None:
        governor = exec_governor_name(governor_exec)
    bag_path = Path(bag) if bag is not None else default_bag_path(governor)
    if bag_path.exists() and (not bag_path.is_dir() or any(bag_path.iterdir())):
        raise CikanError(f"bag directory {bag_path} exists and is not empty")
    # The core caches the FTRE gain table on disk (cikan_ros.control.gain_table): filled here once,
    # every node then starts in a second with bit-identical gains.
    Predictor.from_config(cfg)
    workdir = Path(tempfile.mkdtemp(prefix="cikan_ros_"))
    params = {**node_parameters(governor, seed, bag_path.resolve(), stop_on_dock, cfg.mission.approach),
              **(node_params or {})}
    lease = lease_domain()   # held until every node has ended: no other graph flies on it
    graph = Graph(workdir, ros_environment(lease.domain, workdir / "ros_log"),
                  write_params(workdir / "params.yaml", cfg, params), commands=commands,
                  pass_fds=lease.fds())
    failure: str | None = None
    bad_input = False   # a node refused its input (exit code 2): cikan's bad input, not a failed mission
    wall0 = time.perf_counter()

    def terminate(_signum: int, _frame: Any) -> None:
        raise KeyboardInterrupt

    def exited(name: str, rc: int) -> str:
        nonlocal bad_input
        bad_input = rc == EXIT_BAD_INPUT
        who = f"governor ({governor})" if name in commands else graph.process_of(name)
        return f"{who} exited with code {rc}: {graph.reason(name)}"

    main_thread = threading.current_thread() is threading.main_thread()
    # SIGTERM stops the graph like Ctrl-C (signal handlers exist only in the main thread).
    previous = signal.signal(signal.SIGTERM, terminate) if main_thread else None
    bar = Bar(round(cfg.mission.duration_s / cfg.control.period_s), "cikan mission (ROS graph)", "steps",
              progress).start()
    bar.update(0, note="starting the nodes")
    try:
        graph.start(groups)
        if on_started is not None:
            on_started(graph)
        sim = graph.procs["sim"]
        looked = 0.0
        while sim.poll() is None and failure is None:
            for name, proc in graph.procs.items():
                rc = proc.poll()
                if proc is not sim and rc is not None and rc > 0:
                    failure = exited(name, rc)
                    break
            now = time.perf_counter()
            if now - wall0 > timeout_s:
                failure = f"mission did not finish within {timeout_s:g} s (wall)"
            if bar.show and now - looked >= PROGRESS_PERIOD_S:
                looked = now
                steps = recorded_steps_so_far(bag_path)
                if steps:
                    bar.update(steps, note="")
            time.sleep(0.05)
        if failure is None and sim.returncode != 0:
            failure = exited("sim", sim.returncode)
    finally:
        bar.update(bar.completed, note="stopping the nodes")
        graph.stop_all()
        if bar.show:
            bar.update(recorded_steps_so_far(bag_path), note="")
        bar.close()
        lease.release()
        if main_thread:
            signal.signal(signal.SIGTERM, previous)
        if failure is None and keep_logs:
            sys.stderr.write(f"cikan mission: node logs kept in {workdir}\n")
        elif failure is None:   # success, or interrupted (the bag is closed, the logs go)
            shutil.rmtree(workdir, ignore_errors=True)
    if failure is not None:
        kept = ("no bag was written" if not bag_path.exists() else
                "removed the empty bag" if discard_empty_bag(bag_path) else f"bag kept in {bag_path}")
        raise (CikanError if bad_input else MissionError)(f"{failure} ({kept}; node logs in {workdir})")
    wall = time.perf_counter() - wall0
    rc = graph.procs["recorder"].returncode
    if rc != 0:
        raise MissionError(f"recorder_node ended abnormally (exit code {rc}): the bag {bag_path} holds "
                         "the messages up to its last flushed chunk; no metrics computed")
    msgs = read_bag(bag_path)
    steps = recorded_steps(bag_path, msgs, cfg)
    _, metrics = recorded_metrics(bag_path, cfg, governor, msgs)
    metrics["bag"] = str(bag_path)
    metrics["ros"] = {"launch_wall_s": wall, **metrics.get("ros", {}), "domain_id": lease.domain,
                      "layout": layout, "processes": [process_name(g) for g in groups],
                      "exit_codes": {n: p.returncode for n, p in graph.procs.items()}}
    metrics = lockstep_verdict(metrics)
    if not metrics["lockstep_deadlines"]:
        # Every step was answered in the lockstep: the controller had each shift, the simulator
        # each command, so the bag must hold them too.
        lost = check_messages(msgs, cfg, steps, (TIME_SHIFT, ACCEL_CMD))["lost_on"]
        if lost:
            raise MissionError(f"the bag {bag_path} lacks messages the lockstep delivered ({lost} of "
                               f"{steps} steps): the recorder lost them; no metrics reported")
    return metrics


def recorded_steps(bag: Path, msgs: dict[str, list[tuple[int, Any]]], cfg: Config) -> int:
    """K, the steps the simulator flew, from its mission-complete record in the bag; MissionError
    (one line) if the bag lacks that record or any message of the simulator's topics at any of
    the K steps, or holds one twice or off the grid: a bag cut short or with holes is a failed
    mission, never a shorter one."""
    summary = sim_summary(msgs)
    if summary is None:
        raise MissionError(f"the bag {bag} lacks the simulator's mission-complete record: the recorder "
                           "stopped before the mission's end (bag kept; no metrics reported)")
    steps = int(summary["steps"])
    check = check_messages(msgs, cfg, steps, SIM_TOPICS)
    if check["lost"] or check["duplicated"] or check["off_grid"]:
        what = ", ".join(f"{n} {w}" for n, w in ((check["lost"], "lost"), (check["duplicated"], "duplicated"),
                                                 (check["off_grid"], "off the grid")) if n)
        raise MissionError(f"the bag {bag} does not hold the mission's {steps} steps: {what}"
                           + (f" ({check['lost_on']})" if check["lost_on"] else "")
                           + " (bag kept; no metrics reported)")
    return steps


def lockstep_verdict(metrics: dict[str, Any]) -> dict[str, Any]:
    """``lockstep_deadlines``: wall-clock deadlines that fired in the lockstep run (the sim's
    zero-thrust misses + the controller's holds). Each one made the physics depend on timing, so
    a run with any is a failed run (``success`` False, ``cikan mission`` exits 1), whatever the
    constraints say; the fault behaviour itself (hold, coast) stays what flew."""
    ros = metrics.get("ros", {})
    fired = int(ros.get("deadline_misses", 0)) + int(ros.get("controller_holds", 0))
    metrics["lockstep_deadlines"] = fired
    if fired:
        metrics["success"] = False
    return metrics
