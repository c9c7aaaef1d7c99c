"""Conformal PID control (Angelopoulos, Candès & Tibshirani 2023)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .base import RULE_RUN_VALUES, StepRule, check_finite, check_positive

__all__ = ["PIDRule"]


class PIDRule(
    StepRule,
    guarantee="long_run",
    lambda_params=("eta", "K_I", "lambda_init", "lambda_min", "lambda_max"),
    run_values=RULE_RUN_VALUES,
):
    """Conformal PID control (Angelopoulos, Candès & Tibshirani 2023), in lambda's convention.

    lambda_{k+1} = P_{k+1} + I_{k+1} + D_{k+1} with

    * P (the paper's "quantile tracking"): P_{k+1} = P_k + eta (epsilon - l_k), P_1 =
      lambda_init: exactly the fixed-step rule;
    * I (error integrator with saturation): I_{k+1} = r_k(S_k),
      S_k = sum_{i <= k} (epsilon - l_i), r_k(x) = K_I tan(x log(k+1) / (C_sat (k+1)))
      with the tangent's argument capped at +-``max_arg`` (< pi/2) so lambda stays
      finite (the paper lets tan reach +-infinity; clip with lambda_min / lambda_max);
    * D (optional scorecaster): D_{k+1} = scorecaster(losses, lambdas), any callable
      returning a finite offset in lambda's units forecasting the needed correction
      (the paper forecasts the next score with a time-series model).

    The paper tracks a quantile q with q <- q + eta (err - alpha) (larger q = more
    conservative); here lambda = -q, i.e. the same controller with our sign convention.

    Guarantee (Angelopoulos, Candès & Tibshirani 2023, "Conformal PID control for time
    series prediction", NeurIPS, Thm 1 / Prop. 2): if the loss reaches its extremes at
    the saturated lambda (K_I tan(max_arg) large enough that lambda at the cap gives a
    loss above epsilon, and the opposite cap a loss below), then for every data sequence
    |sum_{i<=K}(epsilon - l_i)| <= C_sat h(K) + M with h(K) = (pi/2) (K+1)/log(K+1)
    and M = max |l - epsilon|, i.e. |mean(l) - epsilon| <= C_sat (pi/2)(K+1)/(K log(K+1))
    + M/K, whatever the scorecaster does (the integrator overrides it). With
    ``K_I = 0`` it is the fixed-step rule (P only) with that rule's guarantees. With
    clipping, the saturation assumption must hold at lambda_min / lambda_max.

    Parameters
    ----------
    epsilon : float
        Target average loss.
    eta : float
        Proportional (quantile-tracking) step, units of lambda.
    K_I : float
        Integrator gain (>= 0), units of lambda.
    C_sat : float
        Saturation constant (> 0).
    lambda_init : float
        P_1.
    scorecaster : callable or None
        ``scorecaster(losses, lambdas) -> float`` called before each new lambda with the
        losses l_1..l_k and lambdas lambda_1..lambda_k so far.
    max_arg : float
        Cap of the tangent's argument, in (0, pi/2).
    lambda_min, lambda_max : float
        Clipping of the output.
    """

    def __init__(
        self,
        epsilon: float = 0.0,
        eta: float = 1.0,
        K_I: float = 1.0,
        C_sat: float = 5.0,
        lambda_init: float = 0.0,
        scorecaster: Callable[[np.ndarray, np.ndarray], float] | None = None,
        max_arg: float = 1.5,
        lambda_min: float = -math.inf,
        lambda_max: float = math.inf,
    ) -> None:
        self.epsilon = epsilon
        self.eta = eta
        self.K_I = K_I
        self.C_sat = C_sat
        self.lambda_init = lambda_init
        self.scorecaster = scorecaster
        self.max_arg = max_arg
        self.lambda_min = lambda_min
        self.lambda_max = lambda_max

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{}, {"epsilon": 0.1, "eta": 0.5, "K_I": 0.0}, {"K_I": 2.0, "C_sat": 1.0}]

    def _reset(self) -> float:
        check_finite("lambda_init", self.lambda_init)
        check_positive("eta", self.eta, allow_zero=True)
        check_positive("K_I", self.K_I, allow_zero=True)
        check_positive("C_sat", self.C_sat)
        if not (0.0 < float(self.max_arg) < math.pi / 2):
            raise ValueError(f"max_arg must be in (0, pi/2), got {self.max_arg!r}")
        if self.scorecaster is not None and not callable(self.scorecaster):
            raise ValueError("scorecaster must be callable or None")
        self.p_ = float(self.lambda_init)
        self.integral_ = 0.0
        self.i_term_ = 0.0
        self.d_term_ = 0.0
        self.n_saturated_ = 0
        self.losses_: list[float] = []
        self.lambdas_: list[float] = [float(self.lambda_init)]
        return self.lambda_init

    def saturation(self, x: float, k: int) -> float:
        """r_k(x) = K_I tan(x log(k+1) / (C_sat (k+1))), argument capped at +-max_arg."""
        if self.K_I == 0:
            return 0.0
        arg = x * math.log(k + 1) / (self.C_sat * (k + 1))
        if abs(arg) >= self.max_arg:
            self.n_saturated_ += 1
            arg = math.copysign(self.max_arg, arg)
        return float(self.K_I * math.tan(arg))

    def _step(self, loss: float) -> float:
        k = self.n_updates_ + 1
        self.p_ += self.eta * (self.epsilon - loss)
        self.integral_ += self.epsilon - loss
        self.i_term_ = self.saturation(self.integral_, k)
        self.losses_.append(loss)
        if self.scorecaster is not None:
            d = float(self.scorecaster(np.asarray(self.losses_), np.asarray(self.lambdas_)))
            if not math.isfinite(d):
                raise ValueError(f"scorecaster returned a non-finite offset ({d!r})")
            self.d_term_ = d
        lam = self.p_ + self.i_term_ + self.d_term_
        self.lambdas_.append(float(min(max(lam, self.lambda_min), self.lambda_max)))
        return lam

    def long_run_bound(self, n: int, lambdas: Sequence[float]) -> float | None:
        if n == 0 or self.K_I == 0:
            return None
        m = max(abs(b - self.epsilon) for b in self._loss_range())
        h = (math.pi / 2) * (n + 1) / math.log(n + 1)
        return float((self.C_sat * h + m) / n)

    def _loss_range(self) -> tuple[float, float]:
        if self.losses_:
            return (min(self.losses_), max(self.losses_))
        return (self.epsilon, self.epsilon)
