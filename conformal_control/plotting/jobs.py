"""Draw several independent figures on two cores.

A report of the paper's tables is a handful of figures, each about a second of
matplotlib (ticks, text, rasterising): more than the runs behind them. ``draw_all``
splits the figures between this process and one forked child, which inherits the
imported matplotlib and the figures' data (nothing is pickled but the results).

Forking is used only where it is safe and cheap: on Linux, from a process with a single
thread (forking a multi-threaded process can deadlock the child), with more than one CPU
available. Anywhere else, or with ``workers=1``, the figures are drawn here one after the
other; the output is the same either way. A child that dies, is stopped (SIGSTOP, a
debugger, a job-control stop) or takes far longer than this process's share (more than
:data:`CHILD_TIMEOUT_S` seconds and ten times as long) is reported by a warning, killed, and
its figures are then drawn here: a figure never hangs a run.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["CHILD_TIMEOUT_S", "FigureJob", "can_fork", "draw_all"]

#: Least time (s) the figure process is given after this process finished its share.
CHILD_TIMEOUT_S = 120.0

#: a figure to draw: ``(function, args, kwargs)``; the function saves it and returns anything
FigureJob = tuple[Callable[..., Any], tuple[Any, ...], dict[str, Any]]

_JOBS: Sequence[FigureJob] = ()  # the jobs of the draw_all in progress (a forked child reads them)


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def can_fork() -> bool:
    """Whether :func:`draw_all` may fork here: Linux, one thread, more than one CPU."""
    return sys.platform.startswith("linux") and threading.active_count() == 1 and _cpus() > 1


def _draw(indices: Sequence[int]) -> list[int]:
    for i in indices:
        fn, args, kwargs = _JOBS[i]
        fn(*args, **kwargs)
    return list(indices)


def draw_all(jobs: Sequence[FigureJob], workers: int | None = None) -> str:
    """Draw every job; on two cores when :func:`can_fork` allows it.

    Parameters
    ----------
    jobs : sequence of (function, args, kwargs)
        Each call draws and saves one figure. Jobs alternate between this process (even
        positions) and the child (odd positions), so list them in order of cost.
    workers : int, optional
        1 draws everything here; None or 2 (the most used) splits when possible.

    Returns
    -------
    str
        ``"forked"`` or ``"serial"``: where the figures were drawn.

    Raises
    ------
    Exception
        Whatever a drawing function raised (in the child: re-raised here).
    """
    global _JOBS
    if workers is not None and (isinstance(workers, bool) or workers < 1):
        raise ValueError(f"workers must be a positive integer or None, got {workers!r}")
    split = len(jobs) > 1 and (workers is None or workers > 1) and can_fork()
    if not split:
        for fn, args, kwargs in jobs:
            fn(*args, **kwargs)
        return "serial"
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    import matplotlib.pyplot  # noqa: F401 - imported once, before the fork, for both

    mine, theirs = list(range(0, len(jobs), 2)), list(range(1, len(jobs), 2))
    _JOBS = jobs
    try:
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("fork")) as pool:
            child = pool.submit(_draw, theirs)  # forks now: the child sees _JOBS
            pids = list((getattr(pool, "_processes", None) or {}).keys())
            t0 = time.monotonic()
            _draw(mine)
            problem = _wait_child(child, pids, max(CHILD_TIMEOUT_S, 10 * (time.monotonic() - t0)))
            if problem is not None:
                warnings.warn(
                    f"the figure process {problem}; drawing its {len(theirs)} figures here",
                    RuntimeWarning,
                    stacklevel=2,
                )
                _draw(theirs)
    finally:
        _JOBS = ()
    return "forked"


def _state(pid: int) -> str | None:
    """The state letter of process ``pid`` from ``/proc`` (``T``: stopped), or None."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            text = fh.read().decode(errors="replace")
    except OSError:
        return None
    return text[text.rfind(")") + 2 :].split()[0]


def _wait_child(child: Any, pids: list[int], timeout: float) -> str | None:
    """Wait for the child's future; None when it finished, else what went wrong (the child
    is then killed)."""
    import signal
    from concurrent.futures import TimeoutError as FutureTimeout
    from concurrent.futures.process import BrokenProcessPool

    deadline = time.monotonic() + timeout
    while True:
        try:
            child.result(timeout=0.2)
            return None
        except BrokenProcessPool as exc:
            return f"died ({exc})"
        except FutureTimeout:
            pass
        stopped = [pid for pid in pids if _state(pid) in ("T", "t")]
        late = time.monotonic() > deadline
        if stopped or late:
            for pid in pids:
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
            return (
                f"was stopped (pid {stopped[0]})"
                if stopped
                else f"took more than {timeout:.0f} s and was killed"
            )
