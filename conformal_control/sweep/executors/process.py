"""Local process pool (the default): ``concurrent.futures.ProcessPoolExecutor``."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any

from .base import Executor, Outcome

__all__ = ["ProcessExecutor", "default_workers"]


def default_workers() -> int:
    """CPUs this process may use (affinity-aware), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def _single_threaded_children() -> Iterator[None]:
    """While the pool starts its workers, have them inherit one-thread BLAS settings.

    The variables must be in the environment before a worker imports numpy; they are set
    only where the user has not set them, and restored afterwards.
    """
    added = [v for v in _THREAD_VARS if v not in os.environ]
    for v in added:
        os.environ[v] = "1"
    try:
        yield
    finally:
        for v in added:
            os.environ.pop(v, None)


class ProcessExecutor(Executor):
    """A pool of ``workers`` processes started with ``forkserver`` (``spawn`` off Linux).

    At most ``2 * workers`` tasks are in flight, so a huge sweep does not pickle every
    task up front. A worker that dies (segfault, OOM kill) breaks the pool: the affected
    and pending tasks are yielded with the ``BrokenProcessPool`` error, a fresh pool is
    started and the remaining tasks go on.

    Parameters
    ----------
    workers : int, optional
        Number of processes (default: the CPUs available).
    start_method : str, optional
        ``multiprocessing`` start method.
    """

    name = "process"

    def __init__(self, workers: int | None = None, start_method: str | None = None) -> None:
        self.workers = workers
        self.start_method = start_method

    @property
    def n_workers(self) -> int:
        return int(self.workers or default_workers())

    def _pool(self) -> ProcessPoolExecutor:
        method = self.start_method or (
            "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
        )
        return ProcessPoolExecutor(
            max_workers=self.n_workers,
            mp_context=multiprocessing.get_context(method),
        )

    def run(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[Outcome]:
        if self.n_workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers!r}")
        pending = list(enumerate(tasks))[::-1]  # pop() from the end keeps the order
        stack = contextlib.ExitStack()
        stack.enter_context(_single_threaded_children())
        pool = self._pool()
        inflight: dict[Future[Any], int] = {}
        try:
            while pending or inflight:
                while pending and len(inflight) < 2 * self.n_workers:
                    i, args = pending.pop()
                    try:
                        inflight[pool.submit(fn, *args)] = i
                    except RuntimeError:  # pool broken between two submits
                        pending.append((i, args))
                        break
                if not inflight:  # broken pool and nothing running: start a new one
                    pool.shutdown(cancel_futures=True)
                    pool = self._pool()
                    continue
                done, _ = wait(inflight, return_when=FIRST_COMPLETED)
                broken = False
                for fut in done:
                    i = inflight.pop(fut)
                    exc = fut.exception()
                    if exc is not None:
                        broken |= type(exc).__name__ == "BrokenProcessPool"
                        yield i, exc
                    else:
                        yield i, fut.result()
                if broken:
                    pool.shutdown(cancel_futures=True)
                    pool = self._pool()
        finally:
            pool.shutdown(cancel_futures=True)
            stack.close()
