"""Update rules for the conformal variable lambda.

Sign convention (whole toolkit): a *smaller* lambda is *more conservative*. A loss above
the target epsilon therefore lowers lambda, a loss below raises it.
"""

from __future__ import annotations

import math

import numpy as np

from .base import UpdateRule

__all__ = ["FixedEtaRule"]


def _check_finite(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return value


class FixedEtaRule(UpdateRule):
    """Conformal decision theory's fixed-step rule: lambda <- lambda + eta (epsilon - l).

    Guarantee (Lekeufack et al. 2024, Theorem 1; Huriot & Sibai, Theorem 2): for losses
    in (-1/2, 1/2), if the decision family is eventually safe with lambda_safe and
    lambda_1 >= lambda_safe - eta, the average loss after K updates is at most
    epsilon + (lambda_1 - lambda_safe + eta) / (eta K), for any data sequence. The exact
    identity mean(l) = epsilon + (lambda_1 - lambda_{K+1}) / (eta K) holds as long as
    lambda is not clipped.

    Parameters
    ----------
    epsilon : float
        Target average loss.
    eta : float
        Learning rate (> 0; 0 freezes lambda).
    lambda_init : float
        lambda_1.
    lambda_min, lambda_max : float, optional
        Optional clipping of lambda against wind-up (e.g. below the feasibility floor).
        Clipping breaks the exact identity; the monitor then reports a non-zero residual.
    """

    def __init__(
        self,
        epsilon: float = 0.0,
        eta: float = 1.0,
        lambda_init: float = 0.0,
        lambda_min: float = -math.inf,
        lambda_max: float = math.inf,
    ) -> None:
        self.epsilon = epsilon
        self.eta = eta
        self.lambda_init = lambda_init
        self.lambda_min = lambda_min
        self.lambda_max = lambda_max

    @classmethod
    def _unit_test_params(cls) -> list[dict]:
        return [{}, {"epsilon": 0.1, "eta": 0.5, "lambda_init": 1.0, "lambda_min": -0.5}]

    def _validate(self) -> None:
        _check_finite("epsilon", self.epsilon)
        _check_finite("lambda_init", self.lambda_init)
        if not (math.isfinite(self.eta) and self.eta >= 0):
            raise ValueError(f"eta must be a finite number >= 0, got {self.eta!r}")
        if math.isnan(self.lambda_min) or math.isnan(self.lambda_max):
            raise ValueError("lambda_min and lambda_max must not be NaN")
        if self.lambda_min > self.lambda_max:
            raise ValueError(
                f"lambda_min ({self.lambda_min}) must not exceed lambda_max ({self.lambda_max})"
            )

    def reset(self) -> float:
        self._validate()
        self.n_clipped_ = 0
        self.lambda_ = float(np.clip(self.lambda_init, self.lambda_min, self.lambda_max))
        return self.lambda_

    def update(self, loss: float) -> float:
        loss = float(loss)
        if not math.isfinite(loss):
            raise ValueError(f"update rule received a non-finite loss ({loss!r})")
        lam = self.lambda_ + self.eta * (self.epsilon - loss)
        clipped = min(max(lam, self.lambda_min), self.lambda_max)
        if clipped != lam:
            self.n_clipped_ += 1
        self.lambda_ = clipped
        return clipped

    @property
    def value(self) -> float:
        return self.lambda_
