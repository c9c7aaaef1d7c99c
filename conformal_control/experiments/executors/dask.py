"""Dask distributed: a running scheduler (``--scheduler ADDRESS``) or a ``LocalCluster``.

Needs the ``sweep`` extra (``pip install "conformal-control[sweep]"``). Workers must be
able to import ``conformal_control`` (and the plugins the runs use), read the data root
and write the sweep's output folder (a shared file system on a real cluster).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any

from ...core.exceptions import ConformalControlError, InputError
from .base import Executor, Outcome

__all__ = ["CONNECT_TIMEOUT_S", "DaskExecutor", "SchedulerUnreachableError"]

#: How long connecting to a scheduler may take, in all (s). ``distributed``'s own default
#: (30 s per attempt) took 91 s on a refused port while its message said 30 s.
CONNECT_TIMEOUT_S = 30.0


class SchedulerUnreachableError(ConformalControlError, ConnectionError):
    """The Dask scheduler given cannot be reached (one line: the address and why)."""


def _reachable(address: str, timeout: float) -> None:
    """Refuse at once a scheduler whose port refuses connections or whose host is unknown
    (``distributed`` would retry until its timeout); a plain TCP connection, closed."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    if parts.scheme not in ("tcp", "tls"):
        return  # another transport (inproc, ucx): left to distributed
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        raise InputError(
            f"--scheduler {address!r} is not an address such as tcp://host:8786"
        ) from None
    if not host:
        raise InputError(f"--scheduler {address!r} is not an address such as tcp://host:8786")
    try:
        with socket.create_connection((host, port or 8786), timeout=timeout):
            pass
    except OSError as exc:
        why = exc.strerror or type(exc).__name__
        if isinstance(exc, TimeoutError):
            why = f"no answer within {timeout:g} s"
        raise SchedulerUnreachableError(
            f"cannot reach the Dask scheduler at {address}: {why} (is it running? start one "
            "with `dask scheduler`, or leave --scheduler out for a local cluster)"
        ) from None


#: The loggers ``distributed`` configures at import (and tornado's, under it).
_LOGGERS = ("distributed", "distributed.client", "distributed.gc", "tornado", "tornado.application")


def _distributed() -> Any:
    try:
        import distributed
    except ImportError as exc:  # pragma: no cover - exercised only without the extra
        raise ImportError(
            "the dask executor needs dask.distributed: pip install 'conformal-control[sweep]'"
        ) from exc
    from ...core.progress import is_quiet

    if is_quiet():  # -q: a lost scheduler is one line of the sweep's summary, not a traceback
        import logging

        for name in _LOGGERS:
            logging.getLogger(name).setLevel(logging.CRITICAL + 1)
    return distributed


class DaskExecutor(Executor):
    """Submit every run to a Dask cluster and collect results as they complete.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler (``tcp://host:8786``). Without it a
        ``distributed.LocalCluster`` is started (and closed at the end).
    workers : int, optional
        Workers of the LocalCluster (default: Dask's choice).
    processes : bool
        LocalCluster with worker processes (default) or threads in this process.
    client : distributed.Client, optional
        Use this client (not closed here).
    """

    name = "dask"
    distributed = True

    def __init__(
        self,
        scheduler: str | None = None,
        workers: int | None = None,
        processes: bool = True,
        client: Any = None,
    ) -> None:
        self.scheduler = scheduler
        self.workers = workers
        self.processes = processes
        self._client = client
        self._own_client = False
        self._cluster: Any = None

    @property
    def client(self) -> Any:
        if self._client is None:
            if self.scheduler is not None and not str(self.scheduler).strip():
                raise InputError(
                    "--scheduler is empty: give the scheduler's address (tcp://host:8786), or "
                    "leave --scheduler out to start a local cluster"
                )
            d = _distributed()
            if self.scheduler:
                _reachable(str(self.scheduler), CONNECT_TIMEOUT_S)
                try:
                    self._client = d.Client(self.scheduler, timeout=CONNECT_TIMEOUT_S)
                except OSError as exc:
                    raise SchedulerUnreachableError(
                        f"cannot connect to the Dask scheduler at {self.scheduler} within "
                        f"{CONNECT_TIMEOUT_S:g} s ({exc})"
                    ) from None
            else:
                self._cluster = d.LocalCluster(
                    n_workers=self.workers,
                    threads_per_worker=1,
                    processes=self.processes,
                    dashboard_address=None,
                    protocol="tcp://",
                    host="127.0.0.1",
                )
                self._client = d.Client(self._cluster)
            self._own_client = True
        return self._client

    @property
    def n_workers(self) -> int:
        try:
            return max(1, len(self.client.scheduler_info()["workers"]))
        except Exception:
            return 1

    def describe(self) -> str:
        where = self.scheduler or "LocalCluster"
        return f"dask at {where} ({self.n_workers} workers)"

    def run(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[Outcome]:
        d = _distributed()
        client = self.client
        futures = {client.submit(fn, *args, pure=False): i for i, args in enumerate(tasks)}
        try:
            for fut in d.as_completed(futures):
                i = futures[fut]
                try:
                    yield i, fut.result()
                except Exception as exc:  # task error or lost worker
                    yield i, exc
                fut.release()
        finally:
            for fut in futures:
                if not fut.done():
                    fut.cancel()

    def close(self) -> None:
        if self._own_client and self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None
