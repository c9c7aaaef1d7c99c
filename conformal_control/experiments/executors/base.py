"""The executor interface: run tasks, yield each outcome as soon as it completes."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from typing import Any

__all__ = ["Executor", "Outcome"]

#: (index of the task, its return value or the exception that ended it)
Outcome = tuple[int, Any]


class Executor(ABC):
    """Runs ``fn(*args)`` for every task and yields outcomes in completion order.

    Subclasses implement :meth:`run`. An exception raised by the task itself, or by the
    machinery running it (a worker process that died, a lost Dask worker), is yielded as
    the outcome's value instead of being raised, so the caller can record it and go on.
    Use as a context manager so pools and clusters are shut down.
    """

    name = "base"
    #: whether the workers are other processes, maybe on other machines, that take chunks of
    #: batched runs (the sweep runner sends them
    #: :func:`~conformal_control.experiments.batch.run_chunk`)
    distributed = False

    @abstractmethod
    def run(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[Outcome]:
        """Yield ``(index, result_or_exception)`` for each task as it completes."""

    @property
    def n_workers(self) -> int:
        return 1

    def describe(self) -> str:
        return f"{self.name} ({self.n_workers} worker{'s' if self.n_workers != 1 else ''})"

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release pools, clients and clusters."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
