"""Local process pool (the default): ``concurrent.futures.ProcessPoolExecutor``.

Workers must not outlive the driver. Killed with SIGKILL, the driver cannot shut its pool
down, and the workers would wait for work forever: with the ``forkserver`` start method
their parent is the fork server, which itself stays up while they hold its pipe. Each
worker therefore runs a watchdog thread (:func:`watch_driver`) that polls the driver's PID
and exits the worker when the driver is gone. Polling is used rather than Linux's
``PR_SET_PDEATHSIG``, which fires on the death of the *parent* (the fork server here,
not the driver) and does not exist off Linux. When the driver stops on an exception
(SIGTERM, Ctrl-C), :meth:`ProcessExecutor.run` terminates the workers instead of waiting
for their runs.

With ``forkserver`` the fork server imports the simulation (:data:`PRELOAD`) once, with the
one-thread BLAS settings in its environment, and every worker starts from that copy instead
of importing it again.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any

from .base import Executor, Outcome

__all__ = ["ProcessExecutor", "default_workers", "process_alive", "watch_driver"]

#: Seconds between two checks of the driver by a worker's watchdog.
WATCHDOG_PERIOD_S = 0.25
#: Modules the fork server imports before it forks workers (``forkserver`` only).
PRELOAD = ("conformal_control.experiments.worker", "conformal_control.runs.episode")


def default_workers() -> int:
    """CPUs this process may use (affinity-aware), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _proc_stat(pid: int) -> tuple[str, str] | None:
    """(state, start time) of a process from ``/proc`` (Linux), or None if it is gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            text = fh.read().decode(errors="replace")
    except (FileNotFoundError, ProcessLookupError):
        return None
    fields = text[text.rfind(")") + 2 :].split()  # the name may hold spaces and ')'
    return fields[0], fields[19]


def process_alive(pid: int, start: str | None = None) -> bool:
    """Whether ``pid`` is a running process (not a zombie; same start time if given)."""
    if sys.platform.startswith("linux") and os.path.isdir("/proc"):
        stat = _proc_stat(pid)
        if stat is None or stat[0] in ("Z", "X"):
            return False
        return start is None or stat[1] == start
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def watch_driver(driver_pid: int, period_s: float = WATCHDOG_PERIOD_S) -> None:
    """Pool initializer: exit this worker process as soon as the driver is gone.

    A daemon thread checks every ``period_s`` seconds that ``driver_pid`` still runs (the
    same process: its start time is compared on Linux, so a reused PID does not count)
    and that this worker's parent has not changed; otherwise it ends the process at once
    with ``os._exit`` (the run in progress is lost; the driver never recorded it, so a
    resumed sweep redoes it).
    """
    parent = os.getppid()
    stat = _proc_stat(driver_pid) if sys.platform.startswith("linux") else None
    start = stat[1] if stat else None

    def watch() -> None:
        while True:
            time.sleep(period_s)
            if os.getppid() != parent or not process_alive(driver_pid, start):
                os._exit(75)

    threading.Thread(target=watch, name="sweep-driver-watchdog", daemon=True).start()


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Terminate the pool's workers now (their runs are abandoned) and shut it down."""
    terminate = getattr(pool, "terminate_workers", None)  # Python >= 3.14
    if terminate is not None:
        with contextlib.suppress(Exception):
            terminate()
            return
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(timeout=5)


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
    started and the remaining tasks go on. Workers exit by themselves when the driver
    process dies (see the module docstring); if the iteration stops early (an exception
    in the driver, the generator closed), the workers are terminated at once.

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
        self._live: set[ProcessPoolExecutor] = set()
        self._live_lock = threading.Lock()
        self._aborted = threading.Event()

    def abort(self) -> None:
        """Terminate the workers of every running :meth:`run` now, from any thread.

        Their runs are abandoned (never half-recorded: run files are written atomically);
        once this returns, no worker of this executor writes anything. A :meth:`run`
        iterated by another thread sees its tasks fail and ends.
        """
        self._aborted.set()  # a run() in another thread starts no new pool
        with self._live_lock:
            pools = list(self._live)
        for pool in pools:
            _stop_pool(pool)

    def close(self) -> None:
        self.abort()

    @property
    def n_workers(self) -> int:
        return int(self.workers or default_workers())

    def _pool(self) -> ProcessPoolExecutor:
        pool = self._new_pool()
        with self._live_lock:
            self._live.add(pool)
        return pool

    def _done(self, pool: ProcessPoolExecutor) -> None:
        with self._live_lock:
            self._live.discard(pool)

    def _new_pool(self) -> ProcessPoolExecutor:
        method = self.start_method or (
            "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
        )
        ctx = multiprocessing.get_context(method)
        if method == "forkserver" and PRELOAD:
            # import the simulation once in the fork server (if it is not running yet)
            # instead of once in every worker it forks
            ctx.set_forkserver_preload(["__main__", *PRELOAD])
        return ProcessPoolExecutor(
            max_workers=self.n_workers,
            mp_context=ctx,
            initializer=watch_driver,
            initargs=(os.getpid(),),
        )

    def run(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[Outcome]:
        if self.n_workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers!r}")
        self._aborted.clear()
        pending = list(enumerate(tasks))[::-1]  # pop() from the end keeps the order
        stack = contextlib.ExitStack()
        stack.enter_context(_single_threaded_children())
        pool = self._pool()
        inflight: dict[Future[Any], int] = {}
        completed = False
        try:
            while pending or inflight:
                if self._aborted.is_set():
                    return  # abort(): the pool is stopped below
                while pending and len(inflight) < 2 * self.n_workers:
                    i, args = pending.pop()
                    try:
                        inflight[pool.submit(fn, *args)] = i
                    except RuntimeError:  # pool broken between two submits
                        pending.append((i, args))
                        break
                if not inflight:  # broken pool and nothing running: start a new one
                    pool.shutdown(cancel_futures=True)
                    self._done(pool)
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
                    self._done(pool)
                    pool = self._pool()
            completed = True
        finally:
            if completed:
                pool.shutdown(cancel_futures=True)
            else:  # interrupted: do not wait for the runs in flight
                _stop_pool(pool)
            self._done(pool)
            stack.close()
