"""The fixed-step rule of conformal decision theory."""

from __future__ import annotations

import math
from typing import Any

from .base import RULE_RUN_VALUES, StepRule, check_finite, check_positive

__all__ = ["FixedEtaRule"]


class FixedEtaRule(
    StepRule,
    guarantee="identity",
    fixed_step=True,
    exact_step=True,
    lambda_params=("eta", "lambda_init", "lambda_min", "lambda_max"),
    run_values=RULE_RUN_VALUES,
):
    """Conformal decision theory's fixed-step rule: lambda <- lambda + eta (epsilon - l).

    Guarantee (Lekeufack et al. 2024, "Conformal Decision Theory", Theorem 1; Huriot &
    Sibai, Theorem 2): for losses in (-1/2, 1/2), if the decision family is eventually
    safe with lambda_safe (lambda <= lambda_safe implies l <= eps_safe <= epsilon) and
    lambda_1 >= lambda_safe - eta, the average loss after K updates is at most
    epsilon + (lambda_1 - lambda_safe + eta) / (eta K), for any data sequence. The exact
    identity mean(l) = epsilon + (lambda_1 - lambda_{K+1}) / (eta K) holds, with no
    assumption at all, as long as lambda is not clipped.

    Parameters
    ----------
    epsilon : float
        Target average loss.
    eta : float
        Learning rate (> 0; 0 freezes lambda). Units of lambda.
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
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [
            {},
            {"epsilon": 0.1, "eta": 0.5, "lambda_min": -2.0, "lambda_max": 2.0},
            {"epsilon": 0.1, "eta": 0.5, "lambda_init": 1.0, "lambda_min": -0.5},
        ]

    @property
    def step(self) -> float:
        return float(self.eta)

    def _reset(self) -> float:
        check_finite("lambda_init", self.lambda_init)
        check_positive("eta", self.eta, allow_zero=True)
        return self.lambda_init

    def _step(self, loss: float) -> float:
        self.last_step_ = float(self.eta)
        return self.lambda_ + self.eta * (self.epsilon - loss)
