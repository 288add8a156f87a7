"""Compiled kernels cached per version of their sources (cikan_ros.kernel_cache): contracts, and
the stale kernel it exists to prevent, shown with real numba in fresh processes."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from cikan_ros import kernel_cache
from cikan_ros.kernel_cache import (KEEP_NEWEST, STALE_AFTER_S, remove_stale, sources_digest,
                                    use_source_keyed_cache)

CALLEE = "import numba\n\n@numba.njit(cache=True)\ndef value():\n    return {}\n"
CALLER = "import numba\nfrom .a import value\n\n@numba.njit(cache=True)\ndef twice():\n    return 2 * value()\n"
RUNNER = textwrap.dedent("""
    import os, sys
    sys.path.insert(0, sys.argv[1])
    from cikan_ros import kernel_cache           # the package's own import set NUMBA_CACHE_DIR
    os.environ.pop("NUMBA_CACHE_DIR", None)
    if sys.argv[2] == "keyed":
        kernel_cache.use_source_keyed_cache(kernel_cache.Path(sys.argv[1]) / "toy")
    from toy.b import twice
    print(twice())
""")


def toy_package(root: Path, value: int) -> Path:
    """A package whose kernel in b.py calls a kernel in a.py (as tsg's rollout calls orbit's)."""
    pkg = root / "toy"
    pkg.mkdir(exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text(CALLEE.format(value))
    (pkg / "b.py").write_text(CALLER)
    return pkg


def run_toy(root: Path, mode: str, cache: Path) -> int:
    env = {**os.environ, "CIKAN_CACHE_DIR": str(cache)}
    out = subprocess.run([sys.executable, "-c", RUNNER, str(root), mode], env=env, capture_output=True,
                         text=True, timeout=120, check=True)
    return int(out.stdout.strip())


@pytest.mark.parametrize("mode, after_edit", [("default", 2), ("keyed", 4)])
def test_an_edited_callee_reaches_its_cached_caller_only_with_the_keyed_cache(tmp_path: Path, mode: str,
                                                                              after_edit: int) -> None:
    """value() returns 1, then a.py is edited to return 2 and b.py is not: numba's own cache
    (beside the sources) runs twice() compiled with the old value() (2, stale); keyed by the
    sources' digest, twice() is compiled afresh (4)."""
    toy_package(tmp_path, 1)
    assert run_toy(tmp_path, mode, tmp_path / "cache") == 2
    time.sleep(0.01)
    (tmp_path / "toy" / "a.py").write_text(CALLEE.format(2))
    assert run_toy(tmp_path, mode, tmp_path / "cache") == after_edit


def test_the_digest_follows_the_kernel_modules_only(tmp_path: Path) -> None:
    """Editing a module that mentions numba changes the digest; one that does not, or a file
    that is not Python, leaves it; the digest is 16 hex digits and the same on a copy."""
    pkg = toy_package(tmp_path, 1)
    (pkg / "plain.py").write_text("X = 1\n")
    first = sources_digest(pkg)
    assert len(first) == 16 and int(first, 16) >= 0
    (pkg / "plain.py").write_text("X = 2\n")
    (pkg / "notes.txt").write_text("numba")
    assert sources_digest(pkg) == first
    copy = shutil.copytree(pkg, tmp_path / "copy")
    assert sources_digest(copy) == first
    (pkg / "a.py").write_text(CALLEE.format(3))
    assert sources_digest(pkg) != first


def test_a_set_numba_cache_dir_wins(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    monkeypatch.setenv("CIKAN_CACHE_DIR", str(tmp_path / "ours"))
    assert use_source_keyed_cache() is None
    assert os.environ["NUMBA_CACHE_DIR"] == str(tmp_path / "mine") and not (tmp_path / "ours").exists()


def test_numba_reads_the_digest_directory_in_a_fresh_process(tmp_path: Path) -> None:
    """Importing the package points numba at <CIKAN_CACHE_DIR>/numba/<digest of its sources>."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["CIKAN_CACHE_DIR"] = str(tmp_path)
    out = subprocess.run([sys.executable, "-c", "import cikan_ros, numba; print(numba.config.CACHE_DIR)"],
                         env=env, capture_output=True, text=True, timeout=120, check=True)
    assert Path(out.stdout.strip()) == tmp_path / "numba" / sources_digest(kernel_cache.PACKAGE)


def test_stale_digest_directories_go_the_current_and_the_newest_stay(tmp_path: Path) -> None:
    """Of 7 other digest directories, the KEEP_NEWEST - 1 newest stay whatever their age; of the
    rest those unused for more than STALE_AFTER_S go; the current one stays although oldest."""
    now = time.time()
    ages = [10.0, 2 * STALE_AFTER_S, 3 * STALE_AFTER_S, 4 * STALE_AFTER_S, 100.0, 5 * STALE_AFTER_S,
            6 * STALE_AFTER_S]
    dirs = []
    for i, age in enumerate(ages):
        d = tmp_path / f"d{i}"
        d.mkdir()
        os.utime(d, (now - age, now - age))
        dirs.append(d)
    current = tmp_path / "current"
    current.mkdir()
    os.utime(current, (now - 10 * STALE_AFTER_S,) * 2)
    removed = remove_stale(tmp_path, current, now)
    by_age = sorted(zip(ages, dirs))
    kept = {d for _, d in by_age[:KEEP_NEWEST - 1]} | {d for a, d in by_age if a <= STALE_AFTER_S}
    assert set(removed) == set(dirs) - kept
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([d.name for d in kept] + ["current"])
