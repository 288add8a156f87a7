"""The `cikan` command as a user runs it: a subprocess, its output and exit code."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

REQUIRED = {"success", "violations", "final_distance_m", "final_speed_mps", "delta_v_kmps",
            "min_h1_margin", "max_h3", "tau0_s", "t_tau_zero_s", "updates", "update_ms_mean",
            "update_ms_max"}


def cikan(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "COLUMNS": "200"}  # rich wraps tables at the terminal width
    return subprocess.run([sys.executable, "-m", "cikan_ros.cli", *args], capture_output=True,
                          text=True, timeout=300, env=env)


def test_offline_mission_json():
    out = cikan("mission", "--offline", "--governor", "conventional", "--json")
    assert out.returncode == 0, out.stderr
    m = json.loads(out.stdout)
    assert REQUIRED <= m.keys()
    assert m["success"] is True and m["violations"] == 0 and m["seed"] is None


def test_offline_mission_summary_with_seed():
    out = cikan("mission", "--offline", "--seed", "4")
    assert out.returncode == 0, out.stderr
    assert "Monte Carlo start, seed 4" in out.stdout and "delta-V [km/s]" in out.stdout


@pytest.mark.parametrize("args, match", [
    (["--set", "orbit.e=1.5"], "orbit.e"),
    (["--set", "orbit.a_km=.nan"], "orbit.a_km"),
    (["--set", "tsg.initial_window_s=2"], "no feasible time shift"),
    (["--set", "nonsense"], "KEY=VALUE"),
    (["--config", "/nonexistent/cikan.yaml"], "not found"),
])
def test_bad_input_gives_a_clear_error(args, match):
    out = cikan("mission", "--offline", *args)
    assert out.returncode == 2
    assert match in out.stderr
    assert "Traceback" not in out.stderr + out.stdout


def test_bench_json_figures():
    out = cikan("bench", "--json", "--missions", "1", "--repeats", "1")
    assert out.returncode == 0, out.stderr
    b = json.loads(out.stdout.strip().splitlines()[-1])
    assert b["conventional_update_ms_max"] >= b["conventional_update_ms_mean"] > 0
    assert b["n_update_states"] > 10


@pytest.mark.parametrize("damage, match", [
    ("truncate", "truncated, corrupt or replaced"),
    ("features", "n_in must be 13"),
    ("rule", "learned.algorithm"),
])
def test_bad_model_file_or_rule_is_one_line_and_exit_2(tmp_path, damage, match):
    """A truncated weights file, a card whose architecture does not match the weights, and an
    unknown update rule each end the mission with one line naming the problem, exit 2."""
    import shutil

    from cikan_ros.learn.modelfile import MODELS_DIR

    model = tmp_path / "m"
    shutil.copytree(MODELS_DIR / "cikan", model)
    args = ["mission", "--offline", "--governor", str(model)]
    if damage == "truncate":
        w = model / "model.safetensors"
        w.write_bytes(w.read_bytes()[:1000])
    elif damage == "features":
        card = json.loads((model / "card.json").read_text())
        card["architecture"].update(features="vnb-prev", n_in=12)
        (model / "card.json").write_text(json.dumps(card))
    else:
        args += ["--set", "learned.algorithm=fast"]
    out = cikan(*args)
    assert out.returncode == 2, out.stderr
    assert match in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert "Traceback" not in out.stderr + out.stdout


def test_negative_seed_is_one_line(tmp_path) -> None:
    import subprocess
    import sys

    for cmd in (["mission", "--offline", "--seed", "-3"], ["montecarlo", "--seed", "-1", "--out", str(tmp_path)]):
        out = subprocess.run([sys.executable, "-m", "cikan_ros.cli", *cmd], capture_output=True, text=True,
                             timeout=120)
        assert out.returncode == 2 and "seed must be an integer >= 0" in out.stderr, out.stderr
        assert "Traceback" not in out.stderr


def _parser_vocabulary() -> tuple[list[str], list[str]]:
    """(every subcommand, every option string of every subcommand): taken from the parser itself,
    so a new subcommand or option is covered without editing the test."""
    from cikan_ros.cli import build_parser

    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    options = sorted({o for p in sub.choices.values() for a in p._actions for o in a.option_strings
                      if o not in ("-h", "--help")})
    return sorted(sub.choices), options


COMMANDS, OPTIONS = _parser_vocabulary()
VALUES = ["-3", "0", "1e9", "nan", "x=1", "abc", "", "--", "conventional", "a b"]


def test_vocabulary_covers_every_subcommand() -> None:
    from cikan_ros.cli import COMMAND_MODULES

    assert len(COMMANDS) == len(COMMAND_MODULES) and "soak" in COMMANDS and "--runs" in OPTIONS


@settings(max_examples=400, deadline=None)
@given(st.sampled_from(COMMANDS), st.lists(st.sampled_from(OPTIONS + VALUES), max_size=6))
def test_every_subcommand_parser_errors_are_one_line(command: str, rest: list[str]) -> None:
    """Any subcommand with generated arguments: accepted, or exit code 2 and one line."""
    check_one_line([command, *rest])


@settings(max_examples=150, deadline=None)
@given(st.lists(st.sampled_from(["mission", "montecarlo", "report", "bench", "--seed", "-3", "1e9", "nan",
                                 "--runs", "--out", "--truth", "--set", "x=1", "--robust", "--offline",
                                 "--governor", "--json", "--rate", "-1", "--missions", "abc", "", "--"]),
                max_size=6))
def test_parser_errors_are_one_line(argv: list[str]) -> None:
    """Whatever the argument list, the parser either accepts it or exits with code 2 and one line
    (never a traceback)."""
    check_one_line(argv)


def check_one_line(argv: list[str]) -> None:
    """``cikan ARGV`` parses, or exits with code 2 and one line naming the problem."""
    import contextlib
    import io

    from cikan_ros.cli import build_parser

    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            build_parser().parse_args(argv)
        except SystemExit as exc:
            if exc.code == 0:   # an option that prints and exits (--help, --version, abbreviated)
                assert out.getvalue().startswith(("usage: ", "cikan_ros ")) and not err.getvalue(), argv
                return
            assert exc.code == 2, (argv, exc.code)
            assert err.getvalue().count("\n") == 1 and "error:" in err.getvalue(), err.getvalue()


def test_offline_mission_refuses_a_bag(tmp_path):
    """An offline mission has no topics to record: --bag is refused with one line, nothing written."""
    out = cikan("mission", "--offline", "--bag", str(tmp_path / "bag"))
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and "--bag" in out.stderr
    assert not (tmp_path / "bag").exists() and "Traceback" not in out.stderr
