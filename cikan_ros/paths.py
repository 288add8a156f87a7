"""Where the package's shipped files (``config/``, ``models/``, ``launch/``) are found: beside the
library in a source tree or an editable install, else in the ``share/cikan_ros/`` directory of an
install (colcon/ament, or a wheel's data files)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

PACKAGE = "cikan_ros"
#: The source tree's root (holds config/, models/ when the library runs from a checkout).
SOURCE_ROOT = Path(__file__).resolve().parent.parent


def install_prefixes() -> list[Path]:
    """Install prefixes to search: $AMENT_PREFIX_PATH (set by colcon's setup.sh), the prefix this
    library is installed in (``<prefix>/lib/pythonX.Y/site-packages/cikan_ros``), this Python's."""
    out = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    here = Path(__file__).resolve().parents
    if len(here) > 4 and here[1].name == "site-packages":
        out.append(here[4])
    out.append(Path(sys.prefix))
    return out


def shipped(relative: str) -> Path:
    """``relative`` (e.g. ``"models"``, ``"config/cikan.yaml"``) in the source tree if it exists there,
    else in the first install prefix's ``share/cikan_ros/`` that has it; the source-tree path if none."""
    source = SOURCE_ROOT / relative
    if source.exists():
        return source
    for prefix in install_prefixes():
        candidate = prefix / "share" / PACKAGE / relative
        if candidate.exists():
            return candidate
    return source
