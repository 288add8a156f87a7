"""Ordered parallel map for embarrassingly parallel work (Monte Carlo runs, dataset missions).

Runs in this process (workers = 1), in local spawned processes (the default for workers > 1;
"spawn" because forking after numba/rclpy initialisation is unsafe), or on a Dask cluster given
its scheduler address. Results come back in task order with a bounded number of tasks in flight,
so an unbounded task iterator works and a consumer may stop early.
"""

from __future__ import annotations

import multiprocessing as mp
from collections import deque
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Iterable, Iterator, TypeVar

from .errors import CikanError

T = TypeVar("T")
R = TypeVar("R")


def ordered_map(fn: Callable[[T], R], tasks: Iterable[T], workers: int = 1,
                dask_address: str | None = None, in_flight: int | None = None) -> Iterator[R]:
    """Yield ``fn(task)`` for each task, in order. ``fn`` must be a picklable top-level function.

    Closing the generator early cancels what is still pending and releases the workers.
    """
    if workers < 1:
        raise CikanError(f"workers must be >= 1, got {workers}")
    it = iter(tasks)
    if dask_address:
        try:
            from distributed import Client
        except ImportError as exc:  # pragma: no cover - distributed is a pinned dependency
            raise CikanError("--dask needs the 'distributed' package") from exc
        try:
            client = Client(dask_address, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise CikanError(f"cannot reach the Dask scheduler at {dask_address}: {exc}") from None
        slots = max(1, sum(client.nthreads().values()))
        try:
            yield from _pipeline(lambda t: client.submit(fn, t, pure=False), it, in_flight or 2 * slots)
        finally:
            client.close()
    elif workers > 1:
        with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
            try:
                yield from _pipeline(lambda t: pool.submit(fn, t), it, in_flight or 2 * workers)
            finally:
                pool.shutdown(wait=True, cancel_futures=True)
    else:
        for t in it:
            yield fn(t)


def _pipeline(submit: Callable[[Any], Any], tasks: Iterator[Any], depth: int) -> Iterator[Any]:
    pending: deque[Any] = deque()
    try:
        for t in tasks:
            pending.append(submit(t))
            if len(pending) >= depth:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
    finally:
        for fut in pending:
            fut.cancel()
