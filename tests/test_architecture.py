"""Imports point down the layers of docs/architecture.md, and no module imports itself round a loop.

The table of layers below is the one place the layering is written down (docs/architecture.md
explains it). Imports are read with ``ast`` from the source of ``cikan_ros/`` and the node packages,
function-level ones included (an import inside a function runs too, only later), ``TYPE_CHECKING``
ones too. ``import a.b.c`` and ``from a.b import c`` also run the ``__init__`` of the packages
above the module named, so an import counts as one of those packages too (except the packages the
importing module itself lives in, which Python has initialised first).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("cikan_ros", "sim_node", "governor_node", "controller_node")

#: The layers, lowest first; each is one or more groups of modules ("a.b" is that module,
#: "a.b.*" the package a.b with everything under it). A module may import modules of lower
#: layers and of its own group: never of a higher layer, nor of another group of its layer.
LAYERS: list[dict[str, list[str]]] = [
    {"base": ["cikan_ros", "cikan_ros.errors", "cikan_ros.paths", "cikan_ros.units", "cikan_ros.config",
              "cikan_ros.kernel_cache",
              "cikan_ros.parallel", "cikan_ros.paired", "cikan_ros.progress",
              "cikan_ros.strict_json"]},
    {"physics": ["cikan_ros.orbit", "cikan_ros.dynamics", "cikan_ros.control", "cikan_ros.constraints",
                 "cikan_ros.truth"]},
    {"verify": ["cikan_ros.tsg", "cikan_ros.robust", "cikan_ros.ancillary"]},
    {"governor": ["cikan_ros.governor"]},
    {"mission": ["cikan_ros.mission", "cikan_ros.timing", "cikan_ros.bench",
                 "cikan_ros.scene"]},
    {"learned flight": ["cikan_ros.learn", "cikan_ros.learn.errors", "cikan_ros.learn.features",
                        "cikan_ros.learn.arch", "cikan_ros.learn.modelfile", "cikan_ros.learn.governor"]},
    {"registry": ["cikan_ros.registry"]},
    {"campaigns": ["cikan_ros.montecarlo", "cikan_ros.compare", "cikan_ros.coverage"]},
    {"learning pipeline": ["cikan_ros.learn.models", "cikan_ros.learn.loss", "cikan_ros.learn.schedule",
                           "cikan_ros.learn.dataset", "cikan_ros.learn.train", "cikan_ros.learn.tune",
                           "cikan_ros.learn.cards", "cikan_ros.learn.bench"],
     "ros": ["cikan_ros.ros.*", "cikan_ros.telemetry"]},
    {"nodes": ["sim_node.*", "governor_node.*", "controller_node.*", "cikan_ros.ros.container"],
     "analysis": ["cikan_ros.analysis.*"],
     "view": ["cikan_ros.view.*"]},
    {"commands": ["cikan_ros.commands.*", "cikan_ros.cli"]},
]


def modules() -> dict[str, Path]:
    """Dotted name -> source file of every module of the packages (a package is its __init__)."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


MODULES = modules()


def place(module: str) -> tuple[int, str] | None:
    """(layer index, group) of a module from the table (the longest matching entry), or None."""
    best: tuple[int, int, str] | None = None
    for i, layer in enumerate(LAYERS):
        for group, patterns in layer.items():
            for p in patterns:
                base = p.removesuffix(".*")
                if module == base or (p.endswith(".*") and module.startswith(base + ".")):
                    if best is None or len(base) > best[0]:
                        best = (len(base), i, group)
    return None if best is None else (best[1], best[2])


def _known(name: str) -> str | None:
    """The longest prefix of a dotted name that is one of our modules."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def imports(module: str) -> list[tuple[str, int]]:
    """(imported module of ours, line) for every import statement of ``module``, anywhere in it."""
    path = MODULES[module]
    is_pkg = path.name == "__init__.py"
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        named: list[str] = []
        if isinstance(node, ast.Import):
            named = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_pkg else module.split(".")[:-1]
                base = base[:len(base) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            # ``from pkg import sub`` imports the module pkg.sub; ``from mod import name`` mod.
            named = [f"{source}.{a.name}" if f"{source}.{a.name}" in MODULES else source for a in node.names]
        for name in named:
            target = _known(name)
            if target is None:
                continue
            parts = target.split(".")
            for k in range(1, len(parts) + 1):   # the packages above the target run first
                dep = ".".join(parts[:k])
                if dep in MODULES and dep != module and not module.startswith(dep + "."):
                    out.append((dep, node.lineno))
    return out


GRAPH = {m: sorted(set(imports(m))) for m in MODULES}


def test_every_module_has_a_layer() -> None:
    missing = [m for m in MODULES if place(m) is None]
    assert not missing, f"modules missing from LAYERS in {Path(__file__).name}: {missing}"
    entries = [p.removesuffix(".*") for layer in LAYERS for ps in layer.values() for p in ps]
    assert len(entries) == len(set(entries)), "an entry of LAYERS is listed twice"
    stale = [e for e in entries if e not in MODULES]
    assert not stale, f"LAYERS names modules that do not exist: {stale}"


def test_imports_point_down() -> None:
    """No module imports one of a higher layer or of another group of its own layer."""
    bad = []
    for m, deps in GRAPH.items():
        here = place(m)
        for dep, line in deps:
            there = place(dep)
            if here is None or there is None:
                continue   # test_every_module_has_a_layer names them
            if there[0] > here[0] or (there[0] == here[0] and there[1] != here[1]):
                bad.append(f"{MODULES[m].relative_to(ROOT)}:{line}: {m} ({here[1]}) imports {dep} ({there[1]})")
    assert not bad, "imports against the layers:\n" + "\n".join(bad)


def find_cycle(graph: dict[str, list[str]]) -> list[str] | None:
    """One cycle of the directed graph (its nodes, the first repeated at the end), or None."""
    state: dict[str, int] = {}   # 1 on the current path, 2 done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in graph.get(node, []):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)) is not None:
                return found
        path.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (found := visit(start)) is not None:
            return found
    return None


def test_find_cycle() -> None:
    """The cycle finder itself, on graphs whose answer is known."""
    assert find_cycle({"a": ["b"], "b": ["c"], "c": []}) is None
    assert find_cycle({"a": ["b", "c"], "b": ["d"], "c": ["d"], "d": []}) is None   # a diamond
    assert find_cycle({"a": ["b"], "b": ["c"], "c": ["a"]}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": ["a"]}) == ["a", "a"]
    assert find_cycle({"x": ["y"], "y": [], "p": ["q"], "q": ["p"]}) == ["p", "q", "p"]


def test_no_import_cycle() -> None:
    """The module import graph, function-level imports included, has no cycle."""
    cycle = find_cycle({m: [d for d, _ in deps] for m, deps in GRAPH.items()})
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def rclpy_lines(module: str) -> list[str]:
    """file:line of every statement of ``module`` that imports rclpy itself (anywhere in it)."""
    path = MODULES[module]
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                 else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
        out += [f"{path.relative_to(ROOT)}:{node.lineno}" for n in names if n.split(".")[0] == "rclpy"]
    return out


def test_rclpy_only_in_ros_and_the_nodes() -> None:
    """The library runs without ROS: rclpy is imported only under cikan_ros/ros/ and by the nodes."""
    bad = [line for m in MODULES if not m.startswith(("cikan_ros.ros", "sim_node", "governor_node",
                                                        "controller_node")) for line in rclpy_lines(m)]
    assert not bad, f"rclpy imported outside cikan_ros/ros/ and the nodes: {bad}"


#: What reads a graph's table or its bags without a running graph: the topic and node table, the
#: parameter files, the bag reader and writer, the launcher (``cikan mission`` starts the nodes as
#: processes; it never joins the graph), analysis/ (``cikan report BAG``) and view/ (``cikan view``,
#: which follows a live mission through its bag).
RCLPY_FREE = ("cikan_ros.ros.graph_spec", "cikan_ros.ros.params", "cikan_ros.ros.bag_reader",
              "cikan_ros.ros.bag_writer", "cikan_ros.ros.launch", "cikan_ros.ros.profile", "cikan_ros.analysis",
              "cikan_ros.view")


def test_table_and_bags_never_load_rclpy() -> None:
    """Nothing these modules import, at any depth and function-level imports included, imports
    rclpy (the launcher, the recorder and the report read the table and the bags without it)."""
    bad = []
    for root in RCLPY_FREE:
        seen, todo = set(), [m for m in MODULES if m == root or m.startswith(root + ".")]
        while todo:
            m = todo.pop()
            if m not in seen:
                seen.add(m)
                bad += [f"{root} -> ... {m}: {line}" for line in rclpy_lines(m)]
                todo += [d for d, _ in GRAPH[m]]
    assert not bad, "rclpy reached from an rclpy-free module:\n" + "\n".join(bad)
