"""Run tasks one after the other in this process (debugging, tiny sweeps)."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any

from .base import Executor, Outcome

__all__ = ["SerialExecutor"]


class SerialExecutor(Executor):
    """In-process, in order. Exceptions are yielded, not raised."""

    name = "serial"

    def run(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]]) -> Iterator[Outcome]:
        for i, args in enumerate(tasks):
            try:
                yield i, fn(*args)
            except Exception as exc:
                yield i, exc
