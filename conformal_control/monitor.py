"""Online guarantee monitor for the conformal loop.

For the fixed-step rule lambda_{k+1} = lambda_k + eta (epsilon - l_k), unrolling gives
the exact identity (SPEC section 1)::

    (1/K) sum_k l_k = epsilon + (lambda_1 - lambda_{K+1}) / (eta K)

and, for an eventually-safe controller with lambda_1 >= lambda_safe - eta, the bound
(1/K) sum_k l_k <= epsilon + (lambda_1 - lambda_safe + eta) / (eta K) (paper Theorem 2).
The monitor tracks the running average loss, the residual of the identity (a numerical
check of the implementation: it is ~1e-15 unless lambda was clipped) and, when
``lambda_safe`` is known, the bound and whether it holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class GuaranteeMonitor:
    """Running statistics of a conformal loop.

    Parameters
    ----------
    epsilon : float
        Target average loss.
    lambda_1 : float
        Initial conformal variable.
    eta : float or None
        Fixed learning rate (None when the rule has none or lambda is not learned).
    lambda_safe : float or None
        A lambda known (or estimated) to make the controller safe, for the Theorem-2 bound.
    bounds : tuple of float
        The declared range of the loss.
    """

    epsilon: float
    lambda_1: float
    eta: float | None = None
    lambda_safe: float | None = None
    bounds: tuple[float, float] = (-0.5, 0.5)
    losses: list[float] = field(default_factory=list)
    lambdas: list[float] = field(default_factory=list)
    lambda_next: float = math.nan

    def observe(self, loss: float, lam: float) -> None:
        """Record l_k and the lambda_k it was computed with."""
        self.losses.append(float(loss))
        self.lambdas.append(float(lam))

    def set_lambda_next(self, lam: float) -> None:
        """Record lambda_{k+1} after the update."""
        self.lambda_next = float(lam)

    @property
    def n(self) -> int:
        return len(self.losses)

    @property
    def average(self) -> float:
        """Running average loss (nan before the first loss)."""
        return math.fsum(self.losses) / self.n if self.n else math.nan

    @property
    def identity_residual(self) -> float | None:
        """|mean loss - epsilon - (lambda_1 - lambda_{K+1})/(eta K)|, or None if undefined."""
        if self.eta is None or self.eta <= 0 or self.n == 0:
            return None
        rhs = self.epsilon + (self.lambda_1 - self.lambda_next) / (self.eta * self.n)
        return abs(self.average - rhs)

    @property
    def bound(self) -> float | None:
        """Theorem-2 bound epsilon + (lambda_1 - lambda_safe + eta)/(eta K), if defined."""
        if self.eta is None or self.eta <= 0 or self.lambda_safe is None or self.n == 0:
            return None
        return self.epsilon + (self.lambda_1 - self.lambda_safe + self.eta) / (self.eta * self.n)

    @property
    def bound_holds(self) -> bool | None:
        b = self.bound
        return None if b is None else bool(self.average <= b + 1e-12)

    def summary(self) -> dict[str, float | bool | int | None]:
        """Figures for metrics.json."""
        return {
            "n_losses": self.n,
            "l_avg": self.average if self.n else None,
            "identity_residual": self.identity_residual,
            "theorem2_bound": self.bound,
            "theorem2_holds": self.bound_holds,
        }
