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

A command that knows early that it will draw (``conformal-control run``) calls
:func:`prepare` before its computation: the figure process is forked then and imports
matplotlib (about half a second of CPU, what any matplotlib figure costs first) on the
second core while this process computes; the next :func:`draw_all` hands it the jobs (they
are pickled: the results they draw, not matplotlib objects) and waits for it, and the
process draws them as :func:`draw_all` does (on two cores: it forks once more). The same
figures, the same files; a figure process that dies or stops is handled as above (the
figures are drawn here), an exception raised by a drawing function is raised here.
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

__all__ = ["CHILD_TIMEOUT_S", "FigureJob", "can_fork", "draw_all", "prepare", "release"]

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
    prepared = _take_prepared()
    usable = jobs and (workers is None or workers > 1) and _cwd() == getattr(prepared, "cwd", None)
    if prepared is not None and usable:
        if prepared.draw(jobs):
            return "forked"
    elif prepared is not None:  # not wanted, or this process moved to another folder
        prepared.close()
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


# ------------------------------------------------------------- the prepared figure process
class _Prepared:
    """A forked process that imported matplotlib and waits for one list of jobs."""

    def __init__(self, pid: int, jobs_fd: int, reply_fd: int):
        self.pid = pid
        self.cwd = os.getcwd()  # the process's: relative paths of the jobs resolve there
        self.jobs_fd: int | None = jobs_fd  # write end: the pickled jobs, then EOF
        self.reply_fd: int | None = reply_fd  # read end: the pickled outcome
        self.reaped = False

    def close(self) -> None:
        """Let the process go (EOF without jobs: it exits) and reap it."""
        for name in ("jobs_fd", "reply_fd"):
            fd = getattr(self, name)
            if fd is not None:
                setattr(self, name, None)
                with contextlib.suppress(OSError):
                    os.close(fd)
        if not self.reaped:
            self.reaped = True
            with contextlib.suppress(OSError):
                os.waitpid(self.pid, 0)

    def kill(self) -> None:
        import signal

        with contextlib.suppress(OSError):
            os.kill(self.pid, signal.SIGKILL)
        self.close()

    def draw(self, jobs: Sequence[FigureJob]) -> bool:
        """Have the process draw ``jobs``; False (nothing drawn, the process gone) when they
        cannot be pickled or the process died or stopped, with a warning for the latter."""
        import pickle
        import select

        try:
            data = pickle.dumps(list(jobs), protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:  # a job holding a lambda, an open file...: drawn here
            self.close()
            return False
        assert self.jobs_fd is not None and self.reply_fd is not None
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(self.jobs_fd, view) :]
        except OSError:  # the process is gone
            self.kill()
            warnings.warn(
                "the figure process died; drawing the figures here", RuntimeWarning, stacklevel=3
            )
            return False
        os.close(self.jobs_fd)
        self.jobs_fd = None
        deadline = time.monotonic() + CHILD_TIMEOUT_S
        chunks: list[bytes] = []
        problem = None
        while True:
            ready, _, _ = select.select([self.reply_fd], [], [], 0.2)
            if ready:
                chunk = os.read(self.reply_fd, 1 << 16)
                if not chunk:
                    break
                chunks.append(chunk)
                continue
            if _state(self.pid) in ("T", "t"):
                problem = f"was stopped (pid {self.pid})"
            elif time.monotonic() > deadline:
                problem = f"took more than {CHILD_TIMEOUT_S:.0f} s and was killed"
            if problem is not None:
                break
        if problem is None:
            self.close()
            try:
                status, payload = pickle.loads(b"".join(chunks))
            except Exception:
                problem = "died"
            else:
                if status == "error":
                    raise payload
                return True
        self.kill()
        warnings.warn(
            f"the figure process {problem}; drawing its figures here", RuntimeWarning, stacklevel=3
        )
        return False


_PREPARED: _Prepared | None = None


def _cwd() -> str | None:
    try:
        return os.getcwd()
    except OSError:  # the folder was removed
        return None


def _take_prepared() -> _Prepared | None:
    global _PREPARED
    prepared, _PREPARED = _PREPARED, None
    return prepared


def prepare(imports: Sequence[str] = ()) -> bool:
    """Fork the figure process of the next :func:`draw_all` now (where :func:`can_fork`
    allows it): it imports matplotlib, the drawing modules and ``imports`` while this
    process goes on.

    Parameters
    ----------
    imports : sequence of str
        Modules the drawing functions live in (imported in the figure process now).

    Returns
    -------
    bool
        Whether a figure process is waiting (False: :func:`draw_all` works as without).
    """
    global _PREPARED
    if _PREPARED is not None:
        return True
    if not can_fork():
        return False
    import atexit

    import numpy  # noqa: F401 - both processes need it: imported once, before the fork

    jobs_r, jobs_w = os.pipe()
    reply_r, reply_w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the figure process: never returns into the caller's code
        code = 1
        try:
            os.close(jobs_w)
            os.close(reply_r)
            code = _serve(jobs_r, reply_w, imports)
        finally:
            os._exit(code)
    os.close(jobs_r)
    os.close(reply_w)
    _PREPARED = _Prepared(pid, jobs_w, reply_r)
    atexit.register(release)
    return True


def release() -> None:
    """Let the figure process of :func:`prepare` go if no :func:`draw_all` used it (it
    exits; called at exit too)."""
    prepared = _take_prepared()
    if prepared is not None:
        prepared.close()


def _serve(jobs_fd: int, reply_fd: int, imports: Sequence[str]) -> int:
    """The figure process: import, wait for the jobs, draw them, reply the outcome."""
    import importlib
    import pickle
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the caller's: it closes the pipe
    try:
        from .run import pyplot

        pyplot()
        for name in imports:
            importlib.import_module(name)
    except Exception:  # drawn by the caller, which reports what fails there
        pass
    chunks: list[bytes] = []
    while True:
        chunk = os.read(jobs_fd, 1 << 16)
        if not chunk:
            break
        chunks.append(chunk)
    os.close(jobs_fd)
    if not chunks:  # released without jobs
        return 0
    try:
        draw_all(pickle.loads(b"".join(chunks)))
        outcome: tuple[str, Any] = ("ok", None)
    except Exception as exc:
        outcome = ("error", exc)
    try:
        reply = pickle.dumps(outcome)
    except Exception:  # an exception that cannot be pickled: its text
        reply = pickle.dumps(("error", RuntimeError(f"{type(outcome[1]).__name__}: {outcome[1]}")))
    view = memoryview(reply)
    while view:
        view = view[os.write(reply_fd, view) :]
    os.close(reply_fd)
    return 0
