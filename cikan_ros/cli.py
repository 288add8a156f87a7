"""The ``cikan`` command. Each subcommand lives in ``cikan_ros.commands.<name>`` and provides
``register(subparsers)``; heavy imports happen inside the command, so ``cikan --help`` is fast.

Errors the project raises on purpose (:class:`CikanError`) are printed as one line naming the
problem, with exit code 2 (bad input), or 1 for a mission that ran and failed
(:class:`~cikan_ros.errors.MissionError`); no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import NoReturn

from . import __version__
from .errors import CikanError

#: Subcommand modules, in the order of ``cikan --help``.
COMMAND_MODULES = (
    "cikan_ros.commands.mission",
    "cikan_ros.commands.montecarlo",
    "cikan_ros.commands.report",
    "cikan_ros.commands.view",
    "cikan_ros.commands.bench",
    "cikan_ros.commands.compare",
    "cikan_ros.commands.tube",
    "cikan_ros.commands.coverage",
    "cikan_ros.commands.dataset",
    "cikan_ros.commands.train",
    "cikan_ros.commands.tune",
    "cikan_ros.commands.models",
    "cikan_ros.commands.replay",
    "cikan_ros.commands.soak",
    "cikan_ros.commands.profile",
    "cikan_ros.commands.telemetry",
    "cikan_ros.commands.scene",
)


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line naming the problem (``cikan mission: error:
    argument --seed: ...``), exit code 2, as the project's own errors are; ``--help`` shows usage.
    Subcommand parsers are made of the same class."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="cikan", description="Learned time-shift governors for spacecraft rendezvous (cikan_ros).")
    parser.add_argument("--version", action="version", version=f"cikan_ros {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except CikanError as exc:
        print(f"cikan {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"cikan {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into e.g. `head`: stop quietly, as Unix tools do
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
