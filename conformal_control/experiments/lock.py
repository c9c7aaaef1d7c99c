"""One sweep at a time per folder: an OS-level lock on ``OUT/.lock`` naming its owner.

Two drivers writing one folder would run every configuration twice and interleave their
journal lines and table rewrites, so :func:`~conformal_control.experiments.runner.run_sweep`
holds an exclusive lock on ``OUT/.lock`` for as long as it runs. The lock is taken with
``fcntl.flock`` (``msvcrt.locking`` on Windows): the operating system releases it when
the owner's file descriptor closes, including when the owner is killed, so a crash never
leaves a stale lock behind. The file holds the owner's PID, host and start time so a
second sweep can say which process is in the way.

Written by hand rather than with ``filelock``: that library truncates the lock file on
every acquisition attempt, which would erase the owner's PID the refusal message names.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import time
from pathlib import Path
from typing import Any

__all__ = ["LOCK_NAME", "SweepLock", "SweepLockedError", "read_owner"]

LOCK_NAME = ".lock"

if sys.platform != "win32":  # POSIX
    import fcntl

    def _try_lock(fd: int) -> bool:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return False
        return True

    def _unlock(fd: int) -> None:
        fcntl.flock(fd, fcntl.LOCK_UN)

else:  # pragma: no cover - Windows
    import msvcrt

    def _try_lock(fd: int) -> bool:
        os.lseek(fd, 0, os.SEEK_SET)
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True

    def _unlock(fd: int) -> None:
        os.lseek(fd, 0, os.SEEK_SET)
        msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)


class SweepLockedError(RuntimeError):
    """Another live process holds the sweep folder's lock."""

    def __init__(self, out_dir: Path, owner: dict[str, Any] | None) -> None:
        self.out_dir = out_dir
        self.owner = owner or {}
        pid = self.owner.get("pid", "unknown")
        host = self.owner.get("host")
        who = f"PID {pid}" + (f" on {host}" if host else "")
        super().__init__(
            f"another sweep ({who}) is writing to {out_dir}; wait for it to finish, "
            "stop it, or use another --out folder"
        )


def read_owner(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The owner recorded in a lock file (``pid``, ``host``, ``started``), or None."""
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace")
        owner = json.loads(text)
    except (OSError, ValueError):
        return None
    return owner if isinstance(owner, dict) else None


def _alive_here(owner: dict[str, Any] | None) -> bool:
    """Whether the owner is a live process on this host (unknown owners count as alive)."""
    if not owner or owner.get("host") != socket.gethostname():
        return True
    try:
        os.kill(int(owner["pid"]), 0)
    except (ProcessLookupError, ValueError, TypeError, KeyError):
        return False
    except PermissionError:
        return True
    return True


class SweepLock:
    """Exclusive lock of a sweep folder, as a context manager.

    Parameters
    ----------
    out_dir : path
        The sweep folder (created if needed).
    grace_s : float
        When the recorded owner is a dead process on this host (its lock is about to be
        released, e.g. by orphaned children still exiting), wait up to this long.

    Raises
    ------
    SweepLockedError
        On entry, if another process holds the lock.
    """

    def __init__(self, out_dir: str | os.PathLike[str], grace_s: float = 5.0) -> None:
        self.out_dir = Path(out_dir)
        self.grace_s = grace_s
        self.path = self.out_dir / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)  # never O_TRUNC: see above
        deadline = None
        while not _try_lock(fd):
            owner = read_owner(self.path)
            if owner is None:  # the owner is between locking and writing its PID
                time.sleep(0.05)
                owner = read_owner(self.path)
            if _alive_here(owner):
                os.close(fd)
                raise SweepLockedError(self.out_dir, owner)
            deadline = deadline or time.monotonic() + self.grace_s
            if time.monotonic() > deadline:
                os.close(fd)
                raise SweepLockedError(self.out_dir, owner)
            time.sleep(0.1)
        owner = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.time()}
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, (json.dumps(owner) + "\n").encode())
        os.fsync(fd)
        self._fd = fd

    def release(self) -> None:
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            os.ftruncate(fd, 0)  # the file stays (removing it would race with a waiter)
            _unlock(fd)
        finally:
            os.close(fd)

    @property
    def locked(self) -> bool:
        return self._fd is not None

    def __enter__(self) -> SweepLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
