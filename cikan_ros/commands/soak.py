"""``cikan soak``: fly N ROS missions back to back and check every bag against the mission."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from ..strict_json import dumps
from . import add_config_args, add_layout_arg, config_from_args, int_at_least, seed_arg


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("soak", help="fly N ROS missions back to back; check every bag for lost messages",
                       description="Fly N lockstep ROS missions one after the other and check each bag "
                                   "against its mission: every topic holds one message per step it "
                                   "should, stamped t_0..t_K, none twice; no wall-clock deadline fired. "
                                   "Prints a table; exit code 1 if any message is lost or a mission "
                                   "failed.")
    p.add_argument("--runs", type=int_at_least(1, "--runs"), default=10, metavar="N", help="missions to fly (default 10)")
    p.add_argument("--load", action="store_true",
                   help="keep every core busy (one busy-loop process per core) during the soak")
    who = p.add_mutually_exclusive_group()
    who.add_argument("--governor", default="conventional", metavar="NAME|PATH",
                     help="governor of governor_node (default conventional)")
    who.add_argument("--governor-exec", metavar='"CMD ARGS"', default=None,
                     help="fly this executable in place of governor_node (as cikan mission)")
    p.add_argument("--seed", type=seed_arg, default=None,
                   help="Monte Carlo start of every run (default: the nominal start)")
    p.add_argument("--out", metavar="DIR", default=None,
                   help="keep the bags in DIR/run_NNN (default: a temporary directory, removed)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_layout_arg(p)
    add_config_args(p)
    p.set_defaults(func=run)


def check_bag(bag: Path, cfg: Any) -> dict[str, Any]:
    """Lost, duplicated and off-grid messages of a recorded mission, per the mission's K steps
    (``mission.duration_s`` / ``control.period_s``), the telemetry and scene markers included:
    :func:`cikan_ros.ros.bag_reader.check_messages`."""
    from ..ros.bag_reader import check_messages, read_bag

    return check_messages(read_bag(bag, scene=True), cfg, round(cfg.mission.duration_s / cfg.control.period_s),
                          scene=True)


def run(args: argparse.Namespace) -> int:
    import shutil

    from ..errors import CikanError
    from ..progress import Bar, on_terminal
    from ..ros.launch import die_with_parent, run_ros_mission

    cfg = config_from_args(args)
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="cikan_soak_"))
    out.mkdir(parents=True, exist_ok=True)
    # The busy loops end with the soak, however it ends (SIGKILL included).
    load = [subprocess.Popen([sys.executable, "-c", "while True: pass"], stdin=subprocess.DEVNULL,
                             preexec_fn=die_with_parent())
            for _ in range(os.cpu_count() or 1)] if args.load else []
    rows: list[dict[str, Any]] = []

    def terminate(_signum: int, _frame: Any) -> None:
        raise KeyboardInterrupt   # SIGTERM ends the soak as Ctrl-C does: the finally below cleans up

    previous = signal.signal(signal.SIGTERM, terminate)
    bar = Bar(args.runs, "cikan soak", "missions", on_terminal(args.json)).start()
    try:
        for i in range(args.runs):
            bag = out / f"run_{i:03d}"
            t0 = time.perf_counter()
            row: dict[str, Any] = {"run": i + 1}
            try:
                metrics = run_ros_mission(cfg, governor=args.governor, seed=args.seed, bag=bag,
                                          governor_exec=args.governor_exec, layout=args.layout)
                ros = metrics.get("ros", {})
                row.update(check_bag(bag, cfg), deadlines=metrics["lockstep_deadlines"],
                           violations=metrics["violations"], rtf=ros.get("rtf"), step_ms_p99=ros.get("step_ms_p99"),
                           **worst_step(ros))
                row["ok"] = not (row["lost"] or row["duplicated"] or row["off_grid"] or row["deadlines"])
                row["error"] = ""
            except CikanError as exc:
                row.update(ok=False, error=str(exc))
                if (bag / "metadata.yaml").exists():   # a failed mission's bag: what it lacks, counted
                    try:
                        row.update(check_bag(bag, cfg))
                    except Exception:   # an unreadable bag: the error above says enough
                        pass
            row["wall_s"] = time.perf_counter() - t0
            rows.append(row)
            if not args.json:
                print(_line(row), flush=True)
            bar.advance()
            if not args.out:
                shutil.rmtree(bag, ignore_errors=True)
    finally:
        bar.close()
        signal.signal(signal.SIGTERM, previous)
        for p in load:
            p.kill()
            p.wait()
        if not args.out:
            shutil.rmtree(out, ignore_errors=True)
    failed = [r for r in rows if not r["ok"]]
    summary = {"runs": len(rows), "failed": len(failed),
               "lost": sum(r.get("lost", 0) for r in rows),
               "duplicated": sum(r.get("duplicated", 0) for r in rows),
               "deadlines": sum(r.get("deadlines", 0) for r in rows),
               "load": bool(args.load), "governor": args.governor_exec or args.governor,
               "worst_step_ms": None, "worst_step_run": None, "worst_step_k": None}
    timed = [r for r in rows if r.get("worst_step_ms") is not None]
    if timed:
        worst = max(timed, key=lambda r: r["worst_step_ms"])
        summary.update(worst_step_ms=worst["worst_step_ms"], worst_step_run=worst["run"],
                       worst_step_k=worst["worst_step_k"])
    if args.json:
        print(dumps({**summary, "table": rows}))
    else:
        print(table(rows, summary))
    return 1 if failed else 0


def worst_step(ros: dict[str, Any]) -> dict[str, Any]:
    """The longest lockstep step of a mission (states published -> command received):
    ``worst_step_ms`` (ms), the longest of the steps where the governor holds and of those where
    it decides, and ``worst_step_k``, its step; None for both when the simulator's summary lacks
    them."""
    steps = [(float(ros[k]), int(float(ros[f"{k}_k"])) if ros.get(f"{k}_k") is not None else None)
             for k in ("step_ms_max", "update_step_ms_max") if ros.get(k) is not None]
    steps = [s for s in steps if s[0] == s[0]]
    ms, k = max(steps, key=lambda s: s[0]) if steps else (None, None)
    return {"worst_step_ms": ms, "worst_step_k": k}


def _line(row: dict[str, Any]) -> str:
    counts = (f"{row['messages']} messages, lost {row['lost']}, duplicated {row['duplicated']}, off grid "
              f"{row['off_grid']}" + (f" (lost on {row['lost_on']})" if row["lost_on"] else "")) \
        if "messages" in row else ""
    if row.get("error"):
        return f"run {row['run']}: FAILED: {row['error']}" + (f"; bag: {counts}" if counts else "")
    return f"run {row['run']}: {counts}, deadlines {row['deadlines']}, {row['wall_s']:.1f} s wall"


def table(rows: list[dict[str, Any]], summary: dict[str, Any]) -> str:
    """The soak as a Markdown table (one row per run) and a totals line."""
    head = ("| run | steps | messages | lost | duplicated | off grid | deadlines fired | violations | rtf | "
            "step p99 ms | worst step ms (k) | wall s | result |")
    lines = [head, "|" + "---|" * 13]
    for r in rows:
        def cell(key: str, fmt: str = "{}") -> str:
            return "" if r.get(key) is None else fmt.format(r[key])
        result = f"FAILED: {r['error'][:120]}" if r.get("error") else "ok" if r["ok"] else "FAILED"
        if r.get("lost_on"):
            result += f" (lost on {r['lost_on']})"
        lines.append(f"| {r['run']} | {cell('steps')} | {cell('messages')} | {cell('lost')} | {cell('duplicated')} | "
                     f"{cell('off_grid')} | {cell('deadlines')} | {cell('violations')} | {cell('rtf', '{:.0f}')} | "
                     f"{cell('step_ms_p99', '{:.2f}')} | {cell('worst_step_ms', '{:.2f}')}"
                     + (f" ({r['worst_step_k']})" if r.get("worst_step_k") is not None else "")
                     + f" | {r['wall_s']:.1f} | {result} |")
    lines.append(f"\n{summary['runs']} runs ({summary['governor']}, load {'on' if summary['load'] else 'off'}): "
                 f"{summary['failed']} failed, {summary['lost']} messages lost, {summary['duplicated']} "
                 f"duplicated, {summary['deadlines']} deadlines fired"
                 + (f"; worst step {summary['worst_step_ms']:.1f} ms (run {summary['worst_step_run']}, step "
                    f"{summary['worst_step_k']})" if summary.get("worst_step_ms") else ""))
    return "\n".join(lines)
