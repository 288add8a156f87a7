"""Progress bars of the long commands: drawn on a terminal (a pseudo-terminal here), not one byte
of them when the output is piped or with --json; and what the ROS launcher reads its progress
from (the bag's metadata, rewritten by the recorder at every flush)."""

from __future__ import annotations

import json
import os
import pty
import subprocess
import sys
from pathlib import Path

import pytest

from ros_helpers import ros_env

__all__ = ["ros_env"]

#: A short mission (60 steps): the command's behaviour, not the mission's result, is under test.
SHORT = ["--set", "mission.duration_s=600"]
#: What rich draws: the bar's line glyph and the cursor hiding of a live display.
BAR_BYTES = ("━", "\x1b[?25l")


def cikan_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "cikan_ros.cli", *args]


def on_pty(argv: list[str], stdout: int | None = None) -> str:
    """What a command writes to a terminal (stdout, unless ``stdout`` says where it goes, and
    stderr on one pseudo-terminal)."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(argv, stdin=slave, stdout=slave if stdout is None else stdout, stderr=slave,
                            close_fds=True, env={**os.environ, "COLUMNS": "160"})
    os.close(slave)
    out = bytearray()
    while True:
        try:
            data = os.read(master, 65536)
        except OSError:   # the child closed the terminal (EIO)
            break
        if not data:
            break
        out += data
    proc.wait(timeout=120)
    os.close(master)
    return out.decode(errors="replace")


def test_mission_on_a_terminal_shows_a_bar():
    text = on_pty(cikan_cmd("mission", "--offline", *SHORT))
    assert all(b in text for b in BAR_BYTES)
    assert "cikan mission" in text and "60/60" in text and "steps" in text


def test_piped_mission_writes_no_bar(tmp_path):
    out = subprocess.run(cikan_cmd("mission", "--offline", *SHORT), capture_output=True, text=True, timeout=120)
    assert out.returncode in (0, 1), out.stderr
    assert not any(b in out.stdout + out.stderr for b in BAR_BYTES)
    assert "final distance" in out.stdout
    # stdout to a file, stderr on a terminal: the bar on the terminal, not a byte of it in the file
    with open(tmp_path / "out.txt", "wb") as f:
        text = on_pty(cikan_cmd("mission", "--offline", *SHORT), stdout=f.fileno())
    written = (tmp_path / "out.txt").read_text()
    assert all(b in text for b in BAR_BYTES) and "final distance" not in text
    assert "final distance" in written and not any(b in written for b in BAR_BYTES)


@pytest.mark.parametrize("command", [["mission", "--offline", *SHORT],
                                     ["montecarlo", "--runs", "1", "--out", "OUT", *SHORT]])
def test_json_on_a_terminal_is_only_json(command, tmp_path):
    command = [str(tmp_path / "mc") if c == "OUT" else c for c in command]
    text = on_pty(cikan_cmd(*command, "--json"))
    assert not any(b in text for b in BAR_BYTES)
    assert isinstance(json.loads(text), dict)


def test_montecarlo_on_a_terminal_shows_a_bar(tmp_path):
    text = on_pty(cikan_cmd("montecarlo", "--runs", "2", "--out", str(tmp_path / "mc"), *SHORT))
    assert all(b in text for b in BAR_BYTES) and "2/2" in text and "runs" in text


def test_ros_mission_on_a_terminal_shows_the_recorded_steps(ros_env: int, tmp_path: Path):
    """Through the ROS graph the bar counts the steps in the bag, up to all K of them; the bag's
    path is printed whole, on its own line."""
    bag = tmp_path / ("a_bag_directory_with_a_name_longer_than_a_table_cell_" * 3)
    text = on_pty(cikan_cmd("mission", "--bag", str(bag), "--set", "mission.duration_s=100"))
    assert all(b in text for b in BAR_BYTES)
    assert "cikan mission (ROS graph)" in text and "10/10" in text
    assert f"bag: {bag}\r\n" in text


def test_launcher_reads_the_steps_the_recorder_flushed(tmp_path: Path):
    """recorded_steps_so_far: the /clock messages after t_0 in metadata.yaml, as flushed (not as
    written: what is still in the recorder's open chunk is not in the bag yet)."""
    from cikan_ros.ros.bag_writer import BagWriter
    from cikan_ros.ros.graph_spec import CLOCK, TOPIC_TYPES
    from cikan_ros.ros.launch import recorded_steps_so_far

    bag = tmp_path / "bag"
    assert recorded_steps_so_far(bag) == 0   # no bag yet
    with BagWriter(bag) as writer:
        writer.add_topic(CLOCK, TOPIC_TYPES[CLOCK], [])
        writer.add_topic("/chief/odom", TOPIC_TYPES["/chief/odom"], [])
        assert recorded_steps_so_far(bag) == 0
        clock = bytes(12)   # a Clock message's CDR bytes (header + builtin_interfaces/Time)
        for k in range(8):
            writer.write(CLOCK, clock, 10**9 * k)
        writer.flush()
        assert recorded_steps_so_far(bag) == 7
        for k in range(8, 11):
            writer.write(CLOCK, clock, 10**9 * k)
        assert recorded_steps_so_far(bag) == 7
    assert recorded_steps_so_far(bag) == 10
