"""Progress bars of the long commands (``cikan mission``, ``montecarlo``, ``dataset``, ``train``,
``soak``, ``replay``): one rich bar on stderr, shown only when stderr is a terminal and the
command was not asked for ``--json`` (or ``--quiet``). Piped or redirected output gets no byte of
it: stdout never carries it, and stderr only when a person watches it.

A hidden bar costs nothing: :class:`Bar` then does no work at all.
"""

from __future__ import annotations

import sys
from types import TracebackType
from typing import Any


def on_terminal(quiet: bool = False) -> bool:
    """Whether a command shows its progress bar: not ``quiet`` (``--json``, ``--quiet``) and
    stderr, where the bar goes, is a terminal."""
    return not quiet and sys.stderr.isatty()


class Bar:
    """A progress bar over ``total`` items of ``unit`` (``None``: unknown total), a context
    manager; ``show`` False (see :func:`on_terminal`): nothing is drawn. Lines printed to stdout
    while it runs appear above it when stdout is the same terminal (else they go where stdout
    goes, untouched)."""

    def __init__(self, total: float | None, description: str, unit: str, show: bool,
                 completed: float = 0.0) -> None:
        self.total, self.description, self.unit, self.show = total, description, unit, show
        self.completed = completed
        self._progress: Any = None
        self._task: Any = None

    def start(self) -> "Bar":
        """Draw the bar (when shown); :meth:`close` ends it (or use the bar as a context manager)."""
        if self.show and self._progress is None:
            from rich.console import Console
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                       TimeElapsedColumn, TimeRemainingColumn)

            self._progress = Progress(
                TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                TextColumn(self.unit), TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(),
                TextColumn("{task.fields[note]}"),
                console=Console(file=sys.stderr), redirect_stdout=sys.stdout.isatty(), redirect_stderr=False,
                refresh_per_second=4)
            self._progress.start()
            self._task = self._progress.add_task(self.description, total=self.total,
                                                 completed=self.completed, note="")
        return self

    def advance(self, n: float = 1.0, note: str | None = None) -> None:
        """``n`` more items done; ``note``: a short text shown after the bar (e.g. losses)."""
        self.completed += n
        self.update(self.completed, note)

    def update(self, completed: float, note: str | None = None) -> None:
        """``completed`` items done in all; ``note`` as in :meth:`advance`."""
        self.completed = completed
        if self._progress is not None:
            fields: dict[str, Any] = {} if note is None else {"note": note}
            self._progress.update(self._task, completed=completed, **fields)

    def close(self) -> None:
        """Stop drawing (the bar's last state stays on the terminal)."""
        if self._progress is not None:
            self._progress.stop()
            self._progress = None

    def __enter__(self) -> "Bar":
        return self.start()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
