"""Adaptive conformal inference (Gibbs & Candès 2021)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from .base import StepRule, check_finite, check_positive

__all__ = ["ACIRule"]


class ACIRule(
    StepRule,
    guarantee="identity",
    fixed_step=True,
    exact_step=True,
    lambda_params=(),
    run_values={
        "lambda_init": "lambda_init",
        "lambda_min": "lambda_min",
        "lambda_max": "lambda_max",
    },
):
    """Adaptive conformal inference (Gibbs & Candès 2021): lambda <- lambda + gamma (alpha - err).

    lambda is the nominal miscoverage level alpha_t of the prediction set (larger =
    smaller set, less conservative), the loss is the miscoverage indicator
    err_k = 1 - covered in {0, 1} and the target is ``alpha`` (``epsilon = alpha``). It
    is the fixed-step rule on that loss, so the fixed-step identity is exact.

    Guarantee (Gibbs & Candès 2021, "Adaptive conformal inference under distribution
    shift", NeurIPS, Prop. 4.1): if the set is the whole space for lambda <= 0 and empty
    for lambda >= 1 (true for sets built from a quantile at level 1 - lambda), then
    lambda_k stays in [-gamma, 1 + gamma] and, for every data sequence,

        |mean(err) - alpha| <= (max(lambda_1, 1 - lambda_1) + gamma) / (gamma K)

    (plus (sum_k |c_k|) / (gamma K) for clip displacements c_k when clipping binds).

    Parameters
    ----------
    alpha : float
        Target miscoverage in (0, 1).
    gamma : float
        Step size (> 0).
    lambda_init : float or None
        alpha_1 (default: alpha).
    lambda_min, lambda_max : float
        Optional clipping (not needed for the guarantee).
    """

    def __init__(
        self,
        alpha: float = 0.1,
        gamma: float = 0.005,
        lambda_init: float | None = None,
        lambda_min: float = -math.inf,
        lambda_max: float = math.inf,
    ) -> None:
        self.alpha = alpha
        self.gamma = gamma
        self.lambda_init = lambda_init
        self.lambda_min = lambda_min
        self.lambda_max = lambda_max

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{}, {"alpha": 0.2, "gamma": 0.05, "lambda_init": 0.5}]

    @property
    def epsilon(self) -> float:  # type: ignore[override]
        return self.alpha

    @property
    def step(self) -> float:
        """The fixed step (gamma)."""
        return float(self.gamma)

    def _reset(self) -> float:
        if not (0.0 < float(self.alpha) < 1.0):
            raise ValueError(f"alpha must be in (0, 1), got {self.alpha!r}")
        check_positive("gamma", self.gamma)
        lam = self.alpha if self.lambda_init is None else self.lambda_init
        return check_finite("lambda_init", lam)

    def _step(self, loss: float) -> float:
        self.last_step_ = float(self.gamma)
        return self.lambda_ + self.gamma * (self.alpha - loss)

    def long_run_bound(self, n: int, lambdas: Sequence[float]) -> float | None:
        if n == 0:
            return None
        lam1 = float(lambdas[0])
        return (max(lam1, 1.0 - lam1) + self.gamma) / (self.gamma * n) + self.clip_weighted_ / n
