"""Generic losses: miscoverage of prediction sets, and any user function with a range.

A loss scores one interval once its truth is revealed, *with the conformal variable
lambda it is evaluated at* (``loss(record, truth, lam)``); losses that can be evaluated at
any lambda (both here) let rules such as DtACI compare what other lambdas would have
given. The flagship's losses live in :mod:`conformal_control.families.cbf` (constraint gap) and
:mod:`conformal_control.families.cbf.safety_losses` (collision indicator, distance shortfall).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from .base import Loss

__all__ = [
    "BallRecord",
    "FunctionLoss",
    "LossRangeError",
    "MiscoverageLoss",
    "SetRecord",
    "check_lambda",
    "conformal_radius",
    "wrap_loss",
]

PARAMETRISATIONS = ("level", "radius")


def check_lambda(lam: float) -> float:
    """lambda as a float; a clear ValueError for NaN (a loss needs a number)."""
    lam = float(lam)
    if math.isnan(lam):
        raise ValueError("the loss needs a lambda that is a number, got nan")
    return lam


class LossRangeError(ValueError):
    """A loss value fell outside the range its loss declared (or was not finite)."""


@runtime_checkable
class SetRecord(Protocol):
    """What a prediction-set decision family records for one interval."""

    def covers(self, truth: Any, lam: float) -> bool:
        """Whether the set the family builds with ``lam`` contains ``truth``."""
        ...


def conformal_radius(
    sorted_scores: np.ndarray, lam: float, parametrisation: str = "level"
) -> float:
    """Radius of the conformal ball built with ``lam`` (``inf`` = everything, ``-inf`` = empty).

    ``"level"`` (ACI's convention): lambda is the nominal miscoverage level; the radius is
    the conformal quantile of the scores at level 1 - lambda, i.e. the
    ceil((n + 1)(1 - lambda))-th smallest score; everything for lambda <= 0 or too few
    scores, empty for lambda >= 1. ``"radius"`` (the PID paper's quantile tracking):
    radius = -lambda, empty for lambda > 0. Both: larger lambda = smaller set.
    """
    if parametrisation == "radius":
        return -math.inf if lam > 0 else -float(lam)
    if parametrisation != "level":
        raise ValueError(
            f"parametrisation must be one of {PARAMETRISATIONS}, got {parametrisation!r}"
        )
    if lam >= 1.0:
        return -math.inf
    n = sorted_scores.size
    if lam <= 0.0 or n == 0:
        return math.inf
    k = math.ceil((n + 1) * (1.0 - lam))
    return math.inf if k > n else float(sorted_scores[max(k, 1) - 1])


@dataclass
class BallRecord:
    """A prediction set {y : |y - center| <= radius(lambda)} (interval, disc, ball).

    Attributes
    ----------
    center : ndarray
        The point forecast (any shape; the distance is the Euclidean norm).
    sorted_scores : ndarray
        Calibration scores |y - forecast| of the past, sorted ascending.
    parametrisation : str
        How lambda sets the radius, see :func:`conformal_radius`.
    """

    center: np.ndarray
    sorted_scores: np.ndarray
    parametrisation: str = "level"

    def radius(self, lam: float) -> float:
        return conformal_radius(self.sorted_scores, lam, self.parametrisation)

    def covers(self, truth: Any, lam: float) -> bool:
        diff = np.asarray(truth, dtype=float) - np.asarray(self.center, dtype=float)
        return bool(np.linalg.norm(np.atleast_1d(diff)) <= self.radius(lam))


class MiscoverageLoss(Loss[SetRecord, Any]):
    """l = 1 - covered: 1 if the prediction set built with lambda misses the truth, else 0.

    The record must implement :class:`SetRecord` (``record.covers(truth, lam)``). With
    lambda the nominal miscoverage level (ACI's convention) the loss is non-decreasing in
    lambda, as the toolkit's sign convention requires. A ``None`` truth (nothing observed)
    gives no loss.
    """

    bounds = (0.0, 1.0)

    def __init__(self) -> None:
        pass

    @classmethod
    def _unit_test_inputs(cls) -> list[tuple[Any, Any]]:
        scores = np.sort(np.random.default_rng(0).exponential(1.0, 50))
        return [
            (BallRecord(np.zeros(2), scores), np.array([0.3, -0.2])),
            (BallRecord(np.zeros(2), scores, "radius"), np.array([2.0, 1.0])),
            (BallRecord(np.zeros(1), np.zeros(0)), np.array([5.0])),  # no scores yet
            (BallRecord(np.zeros(2), scores), None),  # nothing observed
        ]

    def __call__(self, record: Any, truth: Any, lam: float) -> float | None:
        lam = check_lambda(lam)
        if truth is None:
            return None
        if not isinstance(record, SetRecord):
            raise TypeError(
                "MiscoverageLoss needs a record with covers(truth, lam); "
                f"got {type(record).__name__}"
            )
        return 0.0 if record.covers(truth, lam) else 1.0


def _squashed_difference(record: Any, truth: Any, lam: float) -> float:
    """s(lambda + record - truth) for numbers: the function the contract kit checks
    :class:`FunctionLoss` with (``_unit_test_params``); not a default."""
    return math.atan(float(record) - float(truth) + lam) / math.pi


class FunctionLoss(Loss[Any, Any]):
    """Wrap any function ``fn(record, truth, lam) -> float | None`` as a loss with a range.

    Every value is checked at run time: a non-finite value or one outside
    ``bounds = (lo, hi)`` raises :class:`LossRangeError` naming the function, the value
    and the declared range (the guarantees of the update rules assume the declared range,
    so silently accepting out-of-range values would void them). ``None`` passes through
    (no loss for that interval).

    Parameters
    ----------
    fn : callable
        ``fn(record, truth, lam)`` (required; None is refused when the loss is used).
    bounds : tuple of float
        Declared range (lo, hi), lo < hi, both finite.
    name : str or None
        Shown in error messages (default: the function's name).
    """

    def __init__(
        self,
        fn: Callable[[Any, Any, float], float | None] | None = None,
        bounds: tuple[float, float] = (-0.5, 0.5),
        name: str | None = None,
    ) -> None:
        self.fn = fn
        self.bounds = bounds  # type: ignore[misc]  # instance value shadows the ClassVar
        self.name = name

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{"fn": _squashed_difference}]

    @classmethod
    def _unit_test_inputs(cls) -> list[tuple[Any, Any]]:
        """Inputs for the checked function (``record - truth`` is a number)."""
        return [(0.0, 0.0), (1.0, -1.0), (-3.0, 2.5)]

    def check(self) -> tuple[float, float]:
        """The declared bounds, checked with the function (``ValueError`` otherwise)."""
        return self._check_bounds()

    def _check_bounds(self) -> tuple[float, float]:
        try:
            lo, hi = (float(b) for b in self.bounds)
        except (TypeError, ValueError):
            raise ValueError(f"bounds must be a pair (lo, hi), got {self.bounds!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"bounds must be finite with lo < hi, got {self.bounds!r}")
        if self.fn is None:
            raise ValueError("FunctionLoss needs fn=, a function fn(record, truth, lam)")
        if not callable(self.fn):
            raise ValueError(f"fn must be callable, got {self.fn!r}")
        return lo, hi

    def __call__(self, record: Any, truth: Any, lam: float) -> float | None:
        lo, hi = self._check_bounds()
        lam = check_lambda(lam)
        fn = self.fn
        if fn is None:  # refused by _check_bounds; narrows the type
            raise ValueError("FunctionLoss needs fn=, a function fn(record, truth, lam)")
        value = fn(record, truth, lam)
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
    out.check()
    return out
