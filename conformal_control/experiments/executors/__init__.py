"""Executors: one module each (serial, local process pool, Dask distributed)."""

from __future__ import annotations

from typing import Any

from .base import Executor, Outcome
from .process import ProcessExecutor, default_workers
from .serial import SerialExecutor

__all__ = [
    "EXECUTORS",
    "Executor",
    "Outcome",
    "ProcessExecutor",
    "SerialExecutor",
    "default_workers",
    "make_executor",
]

EXECUTORS = ("process", "serial", "dask")


def make_executor(
    name: str = "process",
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    **kwargs: Any,
) -> Executor:
    """Build an executor by name: ``process`` (default), ``serial`` or ``dask``.

    Parameters
    ----------
    name : {"process", "serial", "dask"}
        The executor.
    workers : int, optional
        Worker processes (process pool, Dask LocalCluster); default: the CPUs available.
    scheduler : str, optional
        Address of a running Dask scheduler (``dask`` only).
    **kwargs
        Further arguments of the executor's class.
    """
    if name == "process":
        return ProcessExecutor(workers=workers, **kwargs)
    if name == "serial":
        return SerialExecutor()
    if name == "dask":
        from .dask import DaskExecutor

        return DaskExecutor(scheduler=scheduler, workers=workers, **kwargs)
    raise ValueError(f"unknown executor {name!r}; use one of {', '.join(EXECUTORS)}")
