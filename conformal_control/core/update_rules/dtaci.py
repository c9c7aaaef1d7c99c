"""Dynamically-tuned adaptive conformal inference (Gibbs & Candès 2022)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np

from ..base import LossFunction
from .base import StepRule, check_finite, check_positive

__all__ = ["DtACIRule"]


class DtACIRule(
    StepRule,
    guarantee="none",
    uses_loss_function=True,
    lambda_params=("gammas", "lambda_init", "lambda_min", "lambda_max"),
    run_values={
        "epsilon": "epsilon",
        "lambda_init": "lambda_init",
        "lambda_min": "lambda_min",
        "lambda_max": "lambda_max",
    },
):
    """Dynamically-tuned ACI (Gibbs & Candès 2022): experts with several learning rates.

    Expert i runs its own fixed-step rule lambda^i <- lambda^i + gamma_i (epsilon - l(lambda^i));
    the output is the weighted mean lambda = sum_i p_i lambda^i, with exponential weights
    on the convex surrogate f(lambda) = integral of (l(u) - epsilon) du (for a
    miscoverage loss this is the paper's pinball loss, up to a constant), followed by
    the fixed-share mixing w <- (1 - sigma) w + sigma / n_experts.

    Counterfactual losses: when the loop can evaluate the interval's loss at any lambda
    (``set_loss_function``; the loop does it for every rule with ``uses_loss_function``),
    each expert receives its own loss l(lambda^i) and the surrogate is integrated
    numerically; otherwise (a bare ``update(loss)``), every expert receives the observed
    loss and the surrogate is linearised at the played lambda, (l - epsilon)(lambda^i -
    lambda), which is the standard reduction to linear losses and keeps the
    experts-regret bound for that linearisation.

    Guarantee (Gibbs & Candès 2022, "Conformal inference for online prediction with
    arbitrary distribution shifts", JMLR 2024, Thm 3.2 and Prop. 3.1): for a
    miscoverage loss whose family satisfies ACI's assumption (everything for
    lambda <= 0, empty for lambda >= 1), every expert keeps ACI's bound and the mixture
    has long-run miscoverage within a term of order (1 + 2 gamma_max)/(gamma_min K) plus
    terms that vanish with sigma and the weight rate, and a strongly-adaptive regret
    bound on the pinball loss over every time window. The monitor does not compute that
    bound (kind "none"); the property tests measure the long-run miscoverage.

    Parameters
    ----------
    epsilon : float
        Target average loss (alpha for miscoverage).
    gammas : sequence of float
        Expert learning rates (> 0), units of lambda.
    sigma : float
        Fixed-share mixing in [0, 1).
    eta_weights : float
        Exponential-weights rate (> 0), units of 1/(lambda * loss).
    lambda_init : float or None
        Common initial value of all experts (default: epsilon, ACI's choice).
    lambda_min, lambda_max : float
        Clipping of every expert and of the output.
    n_grid : int
        Quadrature points between consecutive expert values for the surrogate.
    """

    #: Documented empirical tolerance on |miscoverage - alpha| after >= 1000 steps of a
    #: miscoverage loss (i.i.d., shifting, drifting and heavy-tailed scores; checked by
    #: the property tests). Not a theorem: the paper's bound is much looser at that K.
    EMPIRICAL_TOLERANCE: ClassVar[float] = 0.03

    def __init__(
        self,
        epsilon: float = 0.1,
        gammas: Sequence[float] = (0.001, 0.002, 0.004, 0.008, 0.016, 0.032, 0.064, 0.128),
        sigma: float = 0.001,
        eta_weights: float = 2.72,
        lambda_init: float | None = None,
        lambda_min: float = -math.inf,
        lambda_max: float = math.inf,
        n_grid: int = 16,
    ) -> None:
        self.epsilon = epsilon
        self.gammas = gammas
        self.sigma = sigma
        self.eta_weights = eta_weights
        self.lambda_init = lambda_init
        self.lambda_min = lambda_min
        self.lambda_max = lambda_max
        self.n_grid = n_grid

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{}, {"epsilon": 0.0, "gammas": (0.1, 1.0), "sigma": 0.01, "eta_weights": 1.0}]

    def _reset(self) -> float:
        g = np.asarray(self.gammas, dtype=float).ravel()
        if g.size == 0 or not np.all(np.isfinite(g)) or np.any(g <= 0):
            raise ValueError(f"gammas must be a non-empty list of numbers > 0, got {self.gammas}")
        if not (0.0 <= float(self.sigma) < 1.0):
            raise ValueError(f"sigma must be in [0, 1), got {self.sigma!r}")
        check_positive("eta_weights", self.eta_weights)
        if int(self.n_grid) < 2:
            raise ValueError(f"n_grid must be >= 2, got {self.n_grid!r}")
        lam = self.epsilon if self.lambda_init is None else self.lambda_init
        lam = check_finite("lambda_init", lam)
        lam = float(np.clip(lam, self.lambda_min, self.lambda_max))
        self.gammas_ = g
        self.experts_ = np.full(g.size, lam)
        self.weights_ = np.full(g.size, 1.0 / g.size)
        self._loss_fn: LossFunction | None = None
        self.n_counterfactual_ = 0
        return lam

    def set_loss_function(self, fn: LossFunction | None) -> None:
        """Give the rule l_k(.) for the interval about to be consumed by :meth:`update`."""
        self._loss_fn = fn

    def _eval(self, fn: LossFunction, lam: float, fallback: float) -> float:
        v = fn(float(lam))
        if v is None or not math.isfinite(float(v)):
            return fallback
        return float(v)

    def _surrogate(self, fn: LossFunction, points: np.ndarray, fallback: float) -> np.ndarray:
        """f(points) - f(min point) = integral of (l(u) - eps) du, by trapezoids."""
        order = np.argsort(points)
        xs = points[order]
        grid = [xs[0]]
        for a, b in itertools.pairwise(xs):
            if b > a:
                grid.extend(np.linspace(a, b, int(self.n_grid))[1:])
        g = np.asarray(grid)
        vals = np.array([self._eval(fn, x, fallback) for x in g]) - self.epsilon
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (vals[1:] + vals[:-1]) * np.diff(g))])
        out = np.interp(xs, g, cum)
        res: np.ndarray = np.empty_like(out)
        res[order] = out
        return res

    def _step(self, loss: float) -> float:
        fn, self._loss_fn = self._loss_fn, None
        played = self.lambda_
        if fn is not None:
            self.n_counterfactual_ += 1
            expert_losses = np.array([self._eval(fn, x, loss) for x in self.experts_])
            surrogate = self._surrogate(fn, self.experts_, loss)
        else:
            expert_losses = np.full(self.experts_.size, loss)
            surrogate = (loss - self.epsilon) * (self.experts_ - played)
        # exponential weights (shifted for numerical safety) + fixed share
        logw = np.log(self.weights_) - self.eta_weights * (surrogate - surrogate.min())
        w = np.exp(logw - logw.max())
        w /= w.sum()
        w = (1.0 - self.sigma) * w + self.sigma / w.size
        self.weights_ = w / w.sum()
        experts = self.experts_ + self.gammas_ * (self.epsilon - expert_losses)
        self.experts_ = np.clip(experts, self.lambda_min, self.lambda_max)
        if np.any(self.experts_ != experts):  # experts clipped: counted like the output
            self.n_clipped_ += 1
        return float(self.weights_ @ self.experts_)
