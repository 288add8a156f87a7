"""Subcommands of ``cikan`` and the options they share."""

from __future__ import annotations

import argparse
from typing import Any

import yaml

from ..config import Config
from ..errors import ConfigError


def int_at_least(minimum: int, what: str) -> Any:
    """argparse type of an integer >= ``minimum`` (one-line error naming ``what``)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what} must be an integer >= {minimum}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{what} must be an integer >= {minimum}, got {value}")
        return value
    return parse


#: argparse type of a seed: an integer >= 0 (numpy's generators take no negative seed).
seed_arg = int_at_least(0, "seed")


def add_config_args(parser: argparse.ArgumentParser) -> None:
    """``--config PATH`` and repeatable ``--set group.key=value`` (YAML value)."""
    parser.add_argument("--config", metavar="PATH", default=None,
                        help="ROS 2 params YAML file (default: the shipped config/cikan.yaml)")
    parser.add_argument("--scenario", metavar="NAME|FILE", default=None,
                        help="mission scenario: paper (default), leo, geo, or a YAML file over the "
                             "configuration (config/scenarios/; docs/scenarios.md)")
    parser.add_argument("--truth", metavar="NAME|FILE", default=None,
                        help="truth model the simulator flies: nominal (default), realistic, or a "
                             "YAML file with a truth group (config/truth/); docs/robustness.md")
    parser.add_argument("--robust", action="store_true",
                        help="robust Verify: tighten the constraints by the truth's declared "
                             "error bounds (tsg.robust=true)")
    parser.add_argument("--set", metavar="KEY=VALUE", action="append", default=[], dest="overrides",
                        help="override one parameter, e.g. --set tsg.tolerance_s=1e-4 (repeatable; "
                             "applied after --truth and --robust)")


def add_layout_arg(parser: argparse.ArgumentParser, default: str | None = None) -> None:
    """``--layout``: how the ROS graph's nodes share processes (graph_spec.LAYOUTS)."""
    from ..ros.graph_spec import DEFAULT_LAYOUT, LAYOUTS, layouts_text

    default = default or DEFAULT_LAYOUT
    parser.add_argument("--layout", choices=list(LAYOUTS), default=default,
                        help=f"ROS run: the nodes' processes ({layouts_text('+')}; default {default}; "
                             'docs/ros_graph.md, "Processes")')


def config_from_args(args: argparse.Namespace) -> Config:
    """The configuration named by ``--config`` with ``--scenario``, ``--truth``, ``--robust`` and
    then the ``--set`` overrides applied."""
    from ..config import load_config, scenario_overrides, truth_overrides

    overrides: dict[str, Any] = {}
    if getattr(args, "scenario", None) is not None:
        overrides.update(scenario_overrides(args.scenario))
    if getattr(args, "truth", None) is not None:
        overrides.update(truth_overrides(args.truth))
    if getattr(args, "robust", False):
        overrides["tsg.robust"] = True
    for item in args.overrides:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set expects KEY=VALUE, got {item!r}")
        try:
            overrides[key.strip()] = yaml.safe_load(text)
        except yaml.YAMLError:
            raise ConfigError(f"--set {key}: value {text!r} is not valid YAML") from None
    return load_config(args.config, **overrides)
