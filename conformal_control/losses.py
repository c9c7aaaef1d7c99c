"""Generic losses: miscoverage of prediction sets, and any user function with a range.

A loss scores one interval once its truth is revealed, *with the conformal variable
lambda it is evaluated at* (``loss(record, truth, lam)``); losses that can be evaluated at
any lambda (both here) let rules such as DtACI compare what other lambdas would have
given. The flagship's losses live in :mod:`conformal_control.cbf` (constraint gap) and
:mod:`conformal_control.cbf.safety_losses` (collision indicator, distance shortfall).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from .base import Loss

__all__ = ["FunctionLoss", "LossRangeError", "MiscoverageLoss", "SetRecord", "wrap_loss"]


class LossRangeError(ValueError):
    """A loss value fell outside the range its loss declared (or was not finite)."""


@runtime_checkable
class SetRecord(Protocol):
    """What a prediction-set decision family records for one interval."""

    def covers(self, truth: Any, lam: float) -> bool:
        """Whether the set the family builds with ``lam`` contains ``truth``."""
        ...


class MiscoverageLoss(Loss):
    """l = 1 - covered: 1 if the prediction set built with lambda misses the truth, else 0.

    The record must implement :class:`SetRecord` (``record.covers(truth, lam)``). With
    lambda the nominal miscoverage level (ACI's convention) the loss is non-decreasing in
    lambda, as the toolkit's sign convention requires. A ``None`` truth (nothing observed)
    gives no loss.
    """

    bounds = (0.0, 1.0)

    def __init__(self) -> None:
        pass

    def __call__(self, record: Any, truth: Any, lam: float) -> float | None:
        if truth is None:
            return None
        if not isinstance(record, SetRecord):
            raise TypeError(
                "MiscoverageLoss needs a record with covers(truth, lam); "
                f"got {type(record).__name__}"
            )
        return 0.0 if record.covers(truth, lam) else 1.0


def _example_loss(record: Any, truth: Any, lam: float) -> float:
    """Squashed lambda + record - truth (used by the contract tests)."""
    return math.atan(float(record) - float(truth) + lam) / math.pi


class FunctionLoss(Loss):
    """Wrap any function ``fn(record, truth, lam) -> float | None`` as a loss with a range.

    Every value is checked at run time: a non-finite value or one outside
    ``bounds = (lo, hi)`` raises :class:`LossRangeError` naming the function, the value
    and the declared range (the guarantees of the update rules assume the declared range,
    so silently accepting out-of-range values would void them). ``None`` passes through
    (no loss for that interval).

    Parameters
    ----------
    fn : callable
        ``fn(record, truth, lam)``.
    bounds : tuple of float
        Declared range (lo, hi), lo < hi, both finite.
    name : str or None
        Shown in error messages (default: the function's name).
    """

    def __init__(
        self,
        fn: Callable[[Any, Any, float], float | None] = _example_loss,
        bounds: tuple[float, float] = (-0.5, 0.5),
        name: str | None = None,
    ) -> None:
        self.fn = fn
        self.bounds = bounds  # type: ignore[misc]  # instance value shadows the ClassVar
        self.name = name

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{}]

    def _check_bounds(self) -> tuple[float, float]:
        try:
            lo, hi = (float(b) for b in self.bounds)
        except (TypeError, ValueError):
            raise ValueError(f"bounds must be a pair (lo, hi), got {self.bounds!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"bounds must be finite with lo < hi, got {self.bounds!r}")
        if not callable(self.fn):
            raise ValueError(f"fn must be callable, got {self.fn!r}")
        return lo, hi

    def __call__(self, record: Any, truth: Any, lam: float) -> float | None:
        lo, hi = self._check_bounds()
        value = self.fn(record, truth, lam)
        if value is None:
            return None
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise LossRangeError(f"loss {self._label()} returned {value!r}, not a number") from None
        if not (math.isfinite(v) and lo <= v <= hi):
            raise LossRangeError(
                f"loss {self._label()} returned {v!r} at lambda={lam!r}, outside its declared "
                f"range [{lo}, {hi}]; fix the function or declare wider bounds="
            )
        return v

    def _label(self) -> str:
        return repr(self.name or getattr(self.fn, "__name__", type(self.fn).__name__))


def wrap_loss(
    fn: Callable[[Any, Any, float], float | None],
    bounds: tuple[float, float],
    name: str | None = None,
) -> FunctionLoss:
    """Turn a plain function into a range-checked loss plugin.

    Examples
    --------
    >>> loss = wrap_loss(lambda rec, y, lam: float(abs(rec - y) > 1 - lam), bounds=(0, 1))
    >>> loss(0.0, 0.5, 0.0)
    0.0
    """
    out = FunctionLoss(fn, bounds=bounds, name=name)
    out._check_bounds()
    return out
