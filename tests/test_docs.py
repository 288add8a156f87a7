"""The README and the docs pages: every relative link resolves (to a file, and to a heading of it
when it names one); every `cikan` command they show in a sh block is accepted by the command's own
parser, and every `make` target they name exists. The README shows only `cikan` and `make` lines.

The README's first missions are flown by the tests of their commands: the offline mission by
test_cli.py, `cikan mission` as the ROS graph by test_ros_readiness.py (the command) and
test_ros_graph.py (learned governors too), `cikan replay` by test_ros_replay.py, `cikan report` of a
ROS bag by examples/custom_governor/test_custom_governor.py."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from cikan_ros.cli import build_parser

ROOT = Path(__file__).resolve().parent.parent
#: Notes inserted into a generated page (`cikan report --notes FILE` in the Makefile): their links are
#: relative to that page and are checked there.
FRAGMENTS = {ROOT / f for f in re.findall(r"--notes (\S+)", (ROOT / "Makefile").read_text())}
PAGES = sorted({ROOT / "README.md", ROOT / "models" / "README.md", *(ROOT / "docs").rglob("*.md")} - FRAGMENTS)
FENCE = re.compile(r"^```.*?^```[ \t]*$", re.M | re.S)
LINK = re.compile(r"\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def prose(text: str) -> str:
    """The page without its fenced blocks and inline code spans (links there are not links)."""
    return re.sub(r"`[^`\n]*`", "", FENCE.sub("", text))


def anchors(page: Path) -> set[str]:
    """The heading anchors of a page as GitHub makes them: lower case, punctuation dropped, spaces
    to hyphens, repeated anchors numbered -1, -2, ..."""
    seen: dict[str, int] = {}
    out = set()
    for line in FENCE.sub("", page.read_text()).splitlines():
        m = re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        slug = re.sub(r"[^\w\- ]", "", m.group(1).lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_resolve(page: Path) -> None:
    broken = []
    for target in LINK.findall(prose(page.read_text())):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):        # https:, mailto:, ...
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(target)
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(target)
    assert not broken, f"{page.relative_to(ROOT)}: {broken}"


def shell_lines(page: Path) -> list[list[str]]:
    """The commands of a page's sh blocks, split as the shell would (comments dropped)."""
    out = []
    for block in re.findall(r"^```sh\n(.*?)^```", page.read_text(), re.M | re.S):
        for line in block.replace("\\\n", " ").splitlines():      # continuation lines joined
            argv = shlex.split(line, comments=True)
            if argv:
                out.append(argv)
    return out


def make_targets() -> set[str]:
    text = (ROOT / "Makefile").read_text()
    return set(re.findall(r"^([A-Za-z][\w-]*):", text, re.M))


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_shown_commands_parse(page: Path) -> None:
    """`cikan ...` lines are accepted by the parser (a renamed option fails here), `make X` names a
    target of the Makefile. Lines with a placeholder (`[--a | --b]`) are templates, not commands."""
    parser = build_parser()
    targets = make_targets()
    for argv in shell_lines(page):
        if argv[0] == "cikan" and not any(a.startswith("[--") for a in argv):
            parser.parse_args(argv[1:])                   # SystemExit(2) with one line if refused
        elif argv[0] == "make":
            names = [a for a in argv[1:] if not a.startswith("-") and "=" not in a]
            assert set(names) <= targets, (page.name, argv)


def test_readme_shows_only_commands_that_are_checked() -> None:
    """Every command line of the README is a `cikan` command or a make target (both checked above)."""
    commands = shell_lines(ROOT / "README.md")
    assert commands and {argv[0] for argv in commands} <= {"cikan", "make"}
    assert {"run", "test"} <= {a for argv in commands if argv[0] == "make" for a in argv[1:]}
