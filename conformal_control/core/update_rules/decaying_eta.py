"""The fixed-step rule with a decaying step (Angelopoulos, Barber & Bates 2024)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .base import RULE_RUN_VALUES, StepRule, check_finite, check_positive

__all__ = ["DecayingEtaRule"]


class DecayingEtaRule(
    StepRule,
    guarantee="step_identity",
    exact_step=True,
    lambda_params=("eta", "lambda_init", "lambda_min", "lambda_max"),
    run_values=RULE_RUN_VALUES,
):
    """Fixed-step rule with a decaying step: lambda <- lambda + eta_k (epsilon - l_k).

    Schedule: eta_k = eta * (offset / (offset + k - 1)) ** power, k = 1, 2, ... (so
    eta_1 = eta; ``power = 0`` is the fixed-step rule, ``power = 1/2`` the usual choice,
    ``power = 1`` a harmonic schedule).

    Guarantee (Angelopoulos, Barber & Bates 2024, "Online conformal prediction with
    decaying step sizes", ICML, Prop. 1 / Thm 1): the step identity
    sum_k eta_k (epsilon - l_k) = lambda_{K+1} - lambda_1 holds exactly (unclipped), and
    by Abel summation with non-increasing eta_k, for any data sequence,

        |mean(l) - epsilon| <= (max_k lambda_k - min_k lambda_k) / (eta_K K),

    which tends to 0 when lambda stays bounded and K eta_K -> infinity (power < 1). The
    fixed-step Theorem-2 bound is not kept (the step changes); lambda stays bounded, e.g.,
    when the family is eventually safe and large lambda drives the loss above epsilon.
    When clipping binds, each clip displacement c_k adds |c_k| / eta_k to the sum, so the
    bound reported adds (sum_k |c_k| / eta_k) / K (``clip_weighted_``): a clip that binds
    for long (e.g. below the feasibility floor) makes it vacuous, as it should. On i.i.d.
    data lambda_k also converges (the paper's second result), unlike the fixed step.

    Parameters
    ----------
    epsilon : float
        Target average loss.
    eta : float
        Initial step eta_1 (> 0), units of lambda.
    power : float
        Decay exponent in [0, 1].
    offset : float
        k_0 > 0 in the schedule (larger = slower start of the decay).
    lambda_init, lambda_min, lambda_max : float
        As for :class:`FixedEtaRule`.
    """

    def __init__(
        self,
        epsilon: float = 0.0,
        eta: float = 1.0,
        power: float = 0.5,
        offset: float = 1.0,
        lambda_init: float = 0.0,
        lambda_min: float = -math.inf,
        lambda_max: float = math.inf,
    ) -> None:
        self.epsilon = epsilon
        self.eta = eta
        self.power = power
        self.offset = offset
        self.lambda_init = lambda_init
        self.lambda_min = lambda_min
        self.lambda_max = lambda_max

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{}, {"epsilon": 0.1, "eta": 2.0, "power": 1.0, "offset": 5.0}]

    def _reset(self) -> float:
        check_finite("lambda_init", self.lambda_init)
        check_positive("eta", self.eta)
        check_positive("offset", self.offset)
        if not (0.0 <= float(self.power) <= 1.0):
            raise ValueError(f"power must be in [0, 1], got {self.power!r}")
        return self.lambda_init

    def step_size(self, k: int) -> float:
        """eta_k for update number k = 1, 2, ..."""
        return float(self.eta * (self.offset / (self.offset + k - 1)) ** self.power)

    def _step(self, loss: float) -> float:
        self.last_step_ = self.step_size(self.n_updates_ + 1)
        return self.lambda_ + self.last_step_ * (self.epsilon - loss)

    def long_run_bound(self, n: int, lambdas: Sequence[float]) -> float | None:
        if n == 0:
            return None
        lam = np.asarray(lambdas, dtype=float)
        return float((lam.max() - lam.min()) / (self.step_size(n) * n) + self.clip_weighted_ / n)
