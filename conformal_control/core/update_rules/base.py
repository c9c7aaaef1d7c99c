"""Shared machinery of the update rules: target, initial value, clipping, counters."""

from __future__ import annotations

import math

import numpy as np

from ..base import UpdateRule
from ..exceptions import InputError

__all__ = [
    "RULE_RUN_VALUES",
    "StepRule",
    "check_epsilon",
    "check_finite",
    "check_loss",
    "check_positive",
]


#: The run values a rule with the paper's parameters takes (``epsilon``, ``eta`` and
#: lambda's start and bounds, SI): declared by ``fixed_eta``, ``decaying_eta`` and ``pid``
#: as ``run_values=RULE_RUN_VALUES`` (see :class:`~conformal_control.core.spec.RunContext`).
RULE_RUN_VALUES: dict[str, str] = {
    k: k for k in ("epsilon", "eta", "lambda_init", "lambda_min", "lambda_max")
}


def check_finite(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return value


def check_positive(name: str, value: float, allow_zero: bool = False) -> float:
    value = float(value)
    ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be a finite number {bound}, got {value!r}")
    return value


def check_epsilon(epsilon: object, bounds: tuple[float, float] = (-0.5, 0.5)) -> float:
    """The target average loss, strictly inside the loss's range ``bounds``.

    A target at or beyond a bound can never be met on average (the loss never exceeds
    it), so lambda would drift without end. Raises
    :class:`~conformal_control.core.exceptions.InputError` (a ``ValueError``) otherwise; the
    command line, :func:`conformal_control.run` and
    :class:`~conformal_control.families.cbf.StepwiseCBF` all check with this function.
    """
    lo, hi = bounds
    if (
        isinstance(epsilon, bool)
        or not isinstance(epsilon, (int, float, np.integer, np.floating))
        or not lo < float(epsilon) < hi
    ):
        rng = "(-1/2, 1/2)" if (lo, hi) == (-0.5, 0.5) else f"({lo:g}, {hi:g})"
        raise InputError(f"epsilon must lie in {rng} (the loss's range), got {epsilon!r}")
    return float(epsilon)


def check_loss(loss: float) -> float:
    loss = float(loss)
    if not math.isfinite(loss):
        raise ValueError(f"update rule received a non-finite loss ({loss!r})")
    return loss


class StepRule(UpdateRule, lambda_params=("lambda_init", "lambda_min", "lambda_max")):
    """Shared machinery: target, initial value, clipping, counters.

    Subclasses implement :meth:`_reset` (returning the unclipped lambda_1) and
    :meth:`_step` (returning the unclipped lambda_{k+1}).
    """

    lambda_min: float
    lambda_max: float

    def _validate_common(self) -> None:
        check_finite("epsilon", self.epsilon)
        if math.isnan(self.lambda_min) or math.isnan(self.lambda_max):
            raise ValueError("lambda_min and lambda_max must not be NaN")
        if self.lambda_min > self.lambda_max:
            raise ValueError(
                f"lambda_min ({self.lambda_min}) must not exceed lambda_max ({self.lambda_max})"
            )

    def _clip(self, lam: float) -> float:
        clipped = min(max(lam, self.lambda_min), self.lambda_max)
        if clipped != lam:
            self.n_clipped_ += 1
            if self.capabilities.exact_step and self.last_step_ > 0:
                self.clip_weighted_ += abs(clipped - lam) / self.last_step_
        return clipped

    def _reset(self) -> float:
        raise NotImplementedError

    def _step(self, loss: float) -> float:
        raise NotImplementedError

    def reset(self) -> float:
        self._validate_common()
        self.n_clipped_ = 0
        #: sum_k |clip displacement_k| / eta_k: what clipping adds to the long-run bounds
        self.clip_weighted_ = 0.0
        self.n_updates_ = 0
        self.last_step_ = math.nan
        lam = float(self._reset())
        if not self.lambda_min <= lam <= self.lambda_max:
            # clipping lambda_1 silently would run another lambda than the one asked for
            raise ValueError(
                f"{type(self).__name__}: the initial lambda ({lam:g}) lies outside "
                f"[lambda_min, lambda_max] = [{self.lambda_min:g}, {self.lambda_max:g}]; "
                "give a lambda_init inside the bounds or widen them"
            )
        self.lambda_ = lam
        return self.lambda_

    def update(self, loss: float) -> float:
        loss = check_loss(loss)
        lam = self._step(loss)
        if math.isnan(lam):
            raise ValueError(f"{type(self).__name__} produced lambda = nan")
        self.n_updates_ += 1
        self.lambda_ = self._clip(lam)
        if not math.isfinite(self.lambda_):
            raise ValueError(
                f"{type(self).__name__} produced lambda = {self.lambda_}; "
                "set finite lambda_min / lambda_max"
            )
        return self.lambda_

    @property
    def value(self) -> float:
        return self.lambda_
