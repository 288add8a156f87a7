"""Node parameters as data: what each node declares, with defaults and descriptions from
``config/nodes.yaml`` (and the mission configuration from ``config/cikan.yaml``), so that the node,
its ``--help`` and the checks of a command line all read the same declarations.

- :func:`declare_config` declares the mission configuration (read-only, described by the comments
  of ``config/cikan.yaml``) and builds the node's :class:`~cikan_ros.config.Config`;
- :func:`declare_parameters` declares a node's groups (read-only unless named dynamic);
- :func:`parse_node_args` answers ``--help`` (usage and every parameter, without starting rclpy)
  and rejects stray arguments and unreadable params files before rclpy starts (exit code 2);
- :func:`unknown_overrides` finds the ``-p`` and params-file entries no node uses (typos).

A params file may carry the parameters of every node of the graph (``/**``): a node ignores the
groups of the other nodes, but an entry of one of its own groups that it does not declare, of an
unknown group, or any ``-p`` it does not declare, is an error.
"""

from __future__ import annotations

import argparse
import array
import difflib
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import yaml

from ..config import DEFAULT_CONFIG_PATH, Config, config_from_flat, load_config, read_params
from ..errors import ConfigError
from ..paths import shipped

#: Defaults and descriptions of the node parameters.
NODE_PARAMS_PATH = shipped("config/nodes.yaml")
#: Parameter groups of the nodes (the configuration groups of config/cikan.yaml come on top).
NODE_GROUPS = ("graph", "sim", "governor", "controller", "recorder")
#: Parameters rclpy itself declares or reads on every node.
ROS_BUILTIN = ("use_sim_time", "start_type_description_service")


@dataclass(frozen=True)
class Param:
    """One declared parameter: name ``group.key``, default, description, read-only or not."""

    name: str
    default: Any
    description: str
    read_only: bool = True


@dataclass(frozen=True)
class NodeSpec:
    """What a node executable declares: its node-parameter groups and whether it reads the mission
    configuration; ``doc`` (the node module's docstring) opens its ``--help``."""

    name: str
    doc: str
    groups: tuple[str, ...]
    config: bool = True
    dynamic: tuple[str, ...] = ()


_COMMENT = re.compile(r"^(\s*)([A-Za-z_]\w*):\s*(.*?)\s*(?:#\s*(.*))?$")


def parameter_descriptions(path: str | Path = DEFAULT_CONFIG_PATH) -> dict[str, str]:
    """``{"group.key": comment}`` from the end-of-line comments of a params YAML file."""
    out: dict[str, str] = {}
    stack: list[tuple[int, str]] = []
    try:
        lines = Path(path).read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        m = _COMMENT.match(line)
        if not m:
            continue
        indent, key, value, comment = len(m.group(1)), m.group(2), m.group(3), m.group(4)
        while stack and stack[-1][0] >= indent:
            stack.pop()
        if value == "":
            stack.append((indent, key))
            continue
        groups = [k for _, k in stack if k not in ("ros__parameters",)]
        name = ".".join(groups[-1:] + [key]) if groups else key
        if comment:
            out[name] = comment
    return out


def plain(value: Any) -> Any:
    """A parameter value as plain Python (rclpy gives arrays as array.array)."""
    if isinstance(value, (array.array, np.ndarray, tuple)):
        return list(value)
    return value


def node_defaults(path: str | Path = NODE_PARAMS_PATH) -> dict[str, Any]:
    """``{"group.key": default}`` of every node parameter in ``config/nodes.yaml``."""
    return read_params(path)


def parameters(spec: NodeSpec) -> list[Param]:
    """The node parameters ``spec`` declares, in file order."""
    desc = parameter_descriptions(NODE_PARAMS_PATH)
    defaults = node_defaults()
    return [Param(name, defaults[name], desc.get(name, name), name not in spec.dynamic)
            for group in spec.groups for name in defaults if name.partition(".")[0] == group]


def config_parameters() -> list[Param]:
    """The mission configuration as :func:`declare_config` declares it."""
    desc = parameter_descriptions()
    return [Param(name, value, desc.get(name, name)) for name, value in load_config().flat().items()]


def declare_parameters(node: Any, spec: NodeSpec) -> dict[str, Any]:
    """Declare the node parameters of ``spec`` on ``node``; return ``{name: value}`` as started."""
    from rcl_interfaces.msg import ParameterDescriptor

    out: dict[str, Any] = {}
    for p in parameters(spec):
        node.declare_parameter(p.name, p.default, ParameterDescriptor(description=p.description,
                                                                      read_only=p.read_only))
        out[p.name] = plain(node.get_parameter(p.name).value)
    return out


def declare_config(node: Any, defaults: Config | None = None) -> Config:
    """Declare every configuration value as a read-only parameter ``group.key`` with its
    description and the shipped default, then build and validate the Config from the values
    the node was started with (a params file or overrides). Raises ConfigError naming a bad value.
    """
    from rcl_interfaces.msg import ParameterDescriptor

    defaults = defaults or load_config()
    desc = parameter_descriptions()
    flat = defaults.flat()
    for name, value in flat.items():
        node.declare_parameter(name, value, ParameterDescriptor(
            description=desc.get(name, name), read_only=True, dynamic_typing=True))
    return config_from_flat({name: plain(node.get_parameter(name).value) for name in flat})


# -- command line -------------------------------------------------------------------------------
def _format(value: Any) -> str:
    if isinstance(value, str):
        return repr(value) if value == "" else value
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list):
        return "[" + ", ".join(_format(v) for v in value) + "]"
    return repr(value)


def help_text(spec: NodeSpec) -> str:
    """The parameter part of ``--help``: every parameter the node declares."""
    lines = ["parameters (-p NAME:=VALUE or --params-file FILE; defaults from config/nodes.yaml):"]
    for p in parameters(spec):
        lines.append(f"  {p.name} = {_format(p.default)}\n      {p.description}")
    if spec.config:
        lines.append("\nmission configuration (read-only; defaults from config/cikan.yaml):")
        for p in config_parameters():
            lines.append(f"  {p.name} = {_format(p.default)}\n      {p.description}")
    return "\n".join(lines)


def ros_section(args: Sequence[str]) -> tuple[list[str], list[str]]:
    """(arguments for the program, arguments inside ``--ros-args`` ... [``--``])."""
    own: list[str] = []
    ros: list[str] = []
    inside = False
    for a in args:
        if a == "--ros-args":
            inside = True
        elif inside and a == "--":
            inside = False
        elif inside:
            ros.append(a)
        else:
            own.append(a)
    return own, ros


def command_line_names(ros: Sequence[str]) -> list[str]:
    """Names given with ``-p NAME:=VALUE`` / ``--param NAME:=VALUE``."""
    names = []
    for flag, value in zip(ros, list(ros[1:]) + [""]):
        if flag in ("-p", "--param") and ":=" in value:
            names.append(value.split(":=", 1)[0])
    return names


def params_files(ros: Sequence[str]) -> list[str]:
    return [value for flag, value in zip(ros, list(ros[1:]) + [""]) if flag == "--params-file"]


def parse_node_args(spec: NodeSpec, args: Sequence[str]) -> bool:
    """Handle the non-ROS part of a node's command line (``args`` without the program name).

    Returns False when the node should not start (``--help`` was printed, exit 0). Raises
    :class:`ConfigError` for an unknown option or a params file that is missing or not YAML.
    """
    summary = spec.doc.strip().split("\n\n")[0]
    parser = argparse.ArgumentParser(
        prog=spec.name, usage=f"{spec.name} [-h] [--ros-args [-p NAME:=VALUE]... [--params-file FILE]...]",
        description=summary, epilog=help_text(spec), formatter_class=argparse.RawDescriptionHelpFormatter,
        exit_on_error=False, add_help=False)
    parser.add_argument("-h", "--help", action="store_true", help="show this help and exit")
    own, ros = ros_section(args)
    try:
        ns, extra = parser.parse_known_args(own)
    except argparse.ArgumentError as exc:  # pragma: no cover - only -h is defined
        raise ConfigError(str(exc)) from None
    if ns.help:
        parser.print_help()
        return False
    if extra:
        raise ConfigError(f"unrecognised arguments {' '.join(extra)} (ROS arguments go after --ros-args; "
                          f"see {spec.name} --help)")
    check_params_files(ros)
    return True


def check_params_files(ros: Sequence[str]) -> None:
    """ConfigError naming the first params file of the ``--ros-args`` part ``ros`` that is
    missing or not YAML."""
    for path in params_files(ros):
        try:
            yaml.safe_load(Path(path).read_text())
        except OSError as exc:
            raise ConfigError(f"params file {path}: {exc.strerror or exc}") from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"params file {path} is not valid YAML: {' '.join(str(exc).split())}") from None


def unknown_overrides(declared: Iterable[str], overrides: Iterable[str], command_line: Iterable[str]
                      ) -> list[str]:
    """Problems with the parameter overrides a node was started with (empty: none).

    ``declared``: names the node declared; ``overrides``: every override it received (params files
    and ``-p``); ``command_line``: the names given with ``-p`` on its own command line.
    """
    declared = set(declared)
    own_groups = {n.partition(".")[0] for n in declared if "." in n}
    known_groups = set(NODE_GROUPS) | {n.partition(".")[0] for n in Config().flat()}
    cli = set(command_line)
    problems = []
    for name in sorted(set(overrides)):
        group = name.partition(".")[0]
        if name in declared or name in ROS_BUILTIN or name.startswith("qos_overrides."):
            continue
        if name not in cli and group in known_groups and group not in own_groups:
            continue  # a parameter of another node of the graph (shared params file)
        close = difflib.get_close_matches(name, sorted(declared), n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        problems.append(f"{name!r}{hint}")
    return problems
