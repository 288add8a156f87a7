"""cikan_container: several nodes of the graph in one process, on one executor.

``cikan_container recorder sim --ros-args --params-file FILE`` runs the recorder and the
simulator in one process (the launcher's process layouts, :data:`~cikan_ros.ros.graph_spec.LAYOUTS`;
ROS 2's component container, for rclpy nodes). Every node reads the same parameters, as when each
runs alone; messages between them skip the network (Fast DDS delivers them within the process),
which is what makes a layout of few processes faster (docs/ros_graph.md, "Processes"). The process
ends as :func:`~cikan_ros.ros.graph.run_nodes` says: when the simulator (if it is one of them) has
ended the mission, or on SIGINT/SIGTERM; a recorder among them then drains and closes the bag.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import ConfigError
from .graph import run_nodes
from .graph_spec import EXIT_BAD_INPUT, NODE_BY_NAME, layouts_text, load_object, process_name
from .params import check_params_files, ros_section

NAME = "cikan_container"


def parse(args: list[str]) -> list[str] | None:
    """The node names of a container's command line (``args`` without the program name), None
    after ``--help``; ConfigError for an unknown or repeated node, or none."""
    own, _ = ros_section(args)
    parser = argparse.ArgumentParser(
        prog=NAME, usage=f"{NAME} [-h] NODE [NODE ...] [--ros-args [-p NAME:=VALUE]... [--params-file FILE]...]",
        description=__doc__.strip().split("\n\n")[0] + f" Nodes: {', '.join(NODE_BY_NAME)}.",
        epilog=f"The launcher's process layouts ({layouts_text(' ')}). Each node's parameters: NODE_node --help.",
        exit_on_error=False, add_help=False)
    parser.add_argument("-h", "--help", action="store_true", help="show this help and exit")
    parser.add_argument("nodes", nargs="*", metavar="NODE")
    try:
        ns = parser.parse_args(own)
    except argparse.ArgumentError as exc:
        raise ConfigError(str(exc)) from None
    if ns.help:
        parser.print_help()
        return None
    unknown = [n for n in ns.nodes if n not in NODE_BY_NAME]
    if unknown:
        raise ConfigError(f"unknown node {unknown[0]!r}; known: {', '.join(NODE_BY_NAME)}")
    if not ns.nodes or len(set(ns.nodes)) != len(ns.nodes):
        raise ConfigError("name each node once, at least one: " + ", ".join(NODE_BY_NAME))
    return list(ns.nodes)


def main(args: list[str] | None = None) -> int:
    """Console entry point ``cikan_container``."""
    argv = list(sys.argv if args is None else args)
    try:
        names = parse(argv[1:])
        if names is None:
            return 0
        check_params_files(ros_section(argv[1:])[1])   # there and YAML, as for a node alone
    except ConfigError as exc:
        print(f"{NAME}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    # the nodes in the graph's start order: the recorder first, so it hears everything
    order = [n for n in NODE_BY_NAME if n in names]
    factories = [lambda _ctx, cls=load_object(NODE_BY_NAME[n].node_class): cls() for n in order]
    return run_nodes(factories, argv, name=NAME, process=process_name(order),
                     help_hint=", ".join(f"{NODE_BY_NAME[n].executable} --help" for n in order))


if __name__ == "__main__":
    sys.exit(main())
