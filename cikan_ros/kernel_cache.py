"""Where this package's compiled kernels and gain tables are cached on disk.

numba's own on-disk cache (``cache=True``) keys each kernel by its own source file, but a kernel
compiled into another is frozen into its caller's entry: ``tsg.rollout_kernel`` carries
``orbit.state_warm_kernel``'s machine code, so after orbit.py changes the cached rollout would go
on running the old Kepler solve, silently (seen while timing two versions of it). So unless
``NUMBA_CACHE_DIR`` is set, :func:`use_source_keyed_cache` (run when the package is imported)
points numba at ``<cache root>/numba/<digest>``, the digest of every module of the package that
mentions numba: any edit to a kernel compiles everything afresh, and an unchanged tree (an
install, a checkout between edits) reuses its entries. Directories of other digests unused for
a day are removed, the newest few kept. No numba import here: numba reads the variable when it
is first imported.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
import time
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
#: Digest directories kept whatever their age (the current one always is).
KEEP_NEWEST = 4
#: Older digest directories are removed once unused (not imported from) this long (s).
STALE_AFTER_S = 86400.0


def cache_root() -> Path:
    """The package's cache directory: $CIKAN_CACHE_DIR or ~/.cache/cikan_ros."""
    env = os.environ.get("CIKAN_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "cikan_ros"


def sources_digest(root: Path = PACKAGE) -> str:
    """16 hex digits of SHA-256 over the path and bytes of every ``*.py`` under ``root`` that
    mentions numba, in path order."""
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        data = path.read_bytes()
        if b"numba" in data:
            h.update(path.relative_to(root).as_posix().encode() + b"\0" + data + b"\0")
    return h.hexdigest()[:16]


def use_source_keyed_cache(root: Path = PACKAGE) -> Path | None:
    """Point numba's cache at this source tree's digest directory (module docstring) and return
    it; None, changing nothing, when NUMBA_CACHE_DIR is set already or the directory cannot be
    made (numba then caches beside the sources, as it does by default)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    here = cache_root() / "numba" / sources_digest(root)
    try:
        here.mkdir(parents=True, exist_ok=True)
        os.utime(here)   # in use: the newest, never removed below
    except OSError:
        return None
    os.environ["NUMBA_CACHE_DIR"] = str(here)
    numba = sys.modules.get("numba")
    if numba is not None:   # imported before this package: it read its configuration already
        numba.config.CACHE_DIR = str(here)
    remove_stale(here.parent, here)
    return here


def remove_stale(parent: Path, current: Path, now: float | None = None) -> list[Path]:
    """Remove the digest directories under ``parent`` other than ``current`` and the
    KEEP_NEWEST - 1 newest, that were last used more than STALE_AFTER_S ago; return them.
    Best effort: another process may be removing the same ones."""
    now = time.time() if now is None else now
    try:
        dirs = sorted((d for d in parent.iterdir() if d.is_dir() and d != current),
                      key=lambda d: d.stat().st_mtime, reverse=True)
    except OSError:
        return []
    removed = []
    for d in dirs[KEEP_NEWEST - 1:]:
        try:
            if now - d.stat().st_mtime > STALE_AFTER_S:
                shutil.rmtree(d)
                removed.append(d)
        except OSError:
            pass
    return removed
