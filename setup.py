"""ament_python entry for colcon (`colcon build [--symlink-install]`, then the node executables in
``install/cikan_ros/lib/cikan_ros/``; with a ROS 2 install also ``ros2 run cikan_ros sim_node``).

Metadata, dependencies and the node console scripts live in pyproject.toml; this file adds what
colcon and ament need:

- the files of ``share/cikan_ros``: the ament index marker, package.xml, the default params
  (``config/``), the launch file and the shipped models (the governor looks them up there when the
  source tree is not beside the installed library);
- an explicit package list: ``colcon build --symlink-install`` runs ``setup.py develop`` in
  ``build/cikan_ros``, where setuptools' automatic discovery sees a flat layout with several
  top-level directories and refuses;
- setup() values that are Python literals: colcon-python-setup-py reads them back with
  ``ast.literal_eval``, and setuptools turns ``requires-python`` into a ``SpecifierSet``;
- the metadata when pyproject.toml is not beside this file: ``--symlink-install`` links only
  setup.py, setup.cfg, the packages and the data files into ``build/cikan_ros``, so setuptools
  would make a package "UNKNOWN" without the node executables.
"""

import tomllib
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.dist import Distribution

HERE = Path(__file__).resolve().parent
PACKAGE = "cikan_ros"


class LiteralDistribution(Distribution):
    """setuptools' Distribution with ``python_requires`` kept as its string (see the docstring)."""

    def parse_config_files(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        super().parse_config_files(*args, **kwargs)
        for holder in (self, self.metadata):
            value = getattr(holder, "python_requires", None)
            if value is not None:
                holder.python_requires = str(value)


def metadata_without_pyproject() -> dict:
    """The metadata of pyproject.toml's [project] when setuptools cannot see that file (see above)."""
    if (Path(__file__).parent / "pyproject.toml").exists():
        return {}
    project = tomllib.loads((HERE / "pyproject.toml").read_text())["project"]
    return {"name": project["name"], "version": project["version"],
            "description": project["description"], "python_requires": project["requires-python"],
            "install_requires": project["dependencies"],
            "entry_points": {"console_scripts": [f"{k} = {v}" for k, v in project["scripts"].items()]}}


def share_files() -> list[tuple[str, list[str]]]:
    """(install dir, files) of everything installed under ``share/cikan_ros``, relative paths."""
    share = f"share/{PACKAGE}"
    out = [("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
           (share, ["package.xml"]),
           (f"{share}/config", sorted(str(p.relative_to(HERE)) for p in (HERE / "config").glob("*.*")
                                      if p.suffix in (".yaml", ".xml"))),
           (f"{share}/config/truth", sorted(str(p.relative_to(HERE))
                                            for p in (HERE / "config" / "truth").glob("*.yaml"))),
           (f"{share}/config/scenarios", sorted(str(p.relative_to(HERE))
                                                for p in (HERE / "config" / "scenarios").glob("*.yaml"))),
           (f"{share}/config/foxglove", sorted(str(p.relative_to(HERE))
                                               for p in (HERE / "config" / "foxglove").glob("*.json"))),
           (f"{share}/launch", sorted(str(p.relative_to(HERE)) for p in (HERE / "launch").glob("*.launch.*"))),
           (f"{share}/models", ["models/README.md"])]
    # Every model directory (a card beside its weights), the scenarios' subdirectories included.
    for model in sorted(p.parent for p in (HERE / "models").rglob("card.json")):
        files = [str((model / name).relative_to(HERE)) for name in ("model.safetensors", "card.json")]
        out.append((f"{share}/{model.relative_to(HERE).as_posix()}", files))
    return [(d, files) for d, files in out if files]


setup(
    distclass=LiteralDistribution,
    packages=find_packages(include=["cikan_ros", "cikan_ros.*", "sim_node", "governor_node",
                                    "controller_node"]),
    data_files=share_files(),
    **metadata_without_pyproject(),
)
