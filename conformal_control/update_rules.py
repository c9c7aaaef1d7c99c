"""Update rules for the conformal variable lambda.

Sign convention (whole toolkit, one for every rule)
---------------------------------------------------
A *smaller* lambda is *more conservative*: the decision family's loss is (weakly)
increasing in lambda. Every rule here therefore moves lambda **down after a loss above
the target epsilon and up after a loss below it**; in its simplest form

    lambda_{k+1} = lambda_k + eta (epsilon - l_k).

In the flagship (conformal CBF controller) lambda is the slack added to every barrier
constraint, so a larger lambda loosens the constraints (less safe, faster); in online
conformal prediction (Gibbs & Candès 2021) lambda is the nominal miscoverage level
alpha_t, so a larger lambda gives a smaller prediction set; in the CDT factory example
lambda is the machine speed. Rules written for the opposite convention (the PID paper
tracks a quantile q with q <- q + eta (err - alpha)) are stated here with lambda = -q.

Clipping
--------
Every rule accepts ``lambda_min`` / ``lambda_max`` and clips the lambda it returns into
that interval (counted in ``n_clipped_``; the total displacement in ``clip_total_``).
Clipping changes the exact identities below: the upper clip only lowers the average
loss bound, the lower clip keeps the Theorem-2 bound as long as
``lambda_min <= lambda_safe - eta`` (then it never acts under the theorem's assumption).

Guarantee kinds (``UpdateRule.guarantee``)
------------------------------------------
``"identity"``       fixed step: mean(l) = eps + (lambda_1 - lambda_{K+1}) / (eta K) exactly,
                     and the Theorem-2 bound when lambda_safe is known.
``"step_identity"``  variable step eta_k: sum_k eta_k (eps - l_k) = lambda_{K+1} - lambda_1
                     exactly, and a long-run bound on |mean(l) - eps|.
``"long_run"``       a long-run bound on |mean(l) - eps| under the stated assumptions.
``"none"``           no finite-sample statement computed by the monitor.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import numpy as np

from .base import UpdateRule

__all__ = [
    "ACIRule",
    "DecayingEtaRule",
    "DtACIRule",
    "FixedEtaRule",
    "PIDRule",
    "StepRule",
]


def _check_finite(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return value


def _check_positive(name: str, value: float, allow_zero: bool = False) -> float:
    value = float(value)
    ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be a finite number {bound}, got {value!r}")
    return value


def _check_loss(loss: float) -> float:
    loss = float(loss)
    if not math.isfinite(loss):
        raise ValueError(f"update rule received a non-finite loss ({loss!r})")
    return loss


class StepRule(UpdateRule):
    """Shared machinery: target, initial value, clipping, counters.

    Subclasses implement :meth:`_reset` (returning the unclipped lambda_1) and
    :meth:`_step` (returning the unclipped lambda_{k+1}).
    """

    guarantee: ClassVar[str] = "none"
    #: True when lambda_{k+1} = lambda_k + eta_k (eps - l_k) exactly (before clipping);
    #: the step eta_k of the last update is then in ``last_eta_``.
    exact_step: ClassVar[bool] = False
    #: Constructor parameters in the units of lambda (converted by scene-unit loaders).
    lambda_params: ClassVar[tuple[str, ...]] = ("lambda_init", "lambda_min", "lambda_max")

    lambda_min: float
    lambda_max: float

    def _validate_common(self) -> None:
        _check_finite("epsilon", self.epsilon)
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
            self.clip_total_ += clipped - lam
            if self.exact_step and self.last_eta_ > 0:
                self.clip_weighted_ += abs(clipped - lam) / self.last_eta_
        return clipped

    def _reset(self) -> float:
        raise NotImplementedError

    def _step(self, loss: float) -> float:
        raise NotImplementedError

    def reset(self) -> float:
        self._validate_common()
        self.n_clipped_ = 0
        self.clip_total_ = 0.0
        #: sum_k |clip displacement_k| / eta_k: what clipping adds to the long-run bounds
        self.clip_weighted_ = 0.0
        self.n_updates_ = 0
        self.last_eta_ = math.nan
        lam = float(self._reset())
        self.lambda_ = float(np.clip(lam, self.lambda_min, self.lambda_max))
        return self.lambda_

    def update(self, loss: float) -> float:
        loss = _check_loss(loss)
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

    def long_run_bound(self, n: int, lambdas: Sequence[float]) -> float | None:
        """Bound on |mean(l_1..l_n) - epsilon| after n updates, or None.

        ``lambdas`` are lambda_1 .. lambda_{n+1}.
        """
        return None

    def guarantee_assumptions(self) -> str:
        """One line: under what the rule's guarantee holds (for reports)."""
        return ""


# --------------------------------------------------------------------------------------
class FixedEtaRule(StepRule):
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

    guarantee = "identity"
    exact_step = True
    lambda_params = ("eta", "lambda_init", "lambda_min", "lambda_max")

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

    def _reset(self) -> float:
        _check_finite("lambda_init", self.lambda_init)
        _check_positive("eta", self.eta, allow_zero=True)
        return self.lambda_init

    def _step(self, loss: float) -> float:
        self.last_eta_ = float(self.eta)
        return self.lambda_ + self.eta * (self.epsilon - loss)

    def guarantee_assumptions(self) -> str:
        return (
            "identity: always (unclipped); bound: losses in (-1/2, 1/2), eventually safe "
            "with lambda_safe, lambda_1 >= lambda_safe - eta (Lekeufack et al. 2024 Thm 1; "
            "Huriot & Sibai Thm 2)"
        )


# --------------------------------------------------------------------------------------
class DecayingEtaRule(StepRule):
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

    guarantee = "step_identity"
    exact_step = True
    lambda_params = ("eta", "lambda_init", "lambda_min", "lambda_max")

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
        _check_finite("lambda_init", self.lambda_init)
        _check_positive("eta", self.eta)
        _check_positive("offset", self.offset)
        if not (0.0 <= float(self.power) <= 1.0):
            raise ValueError(f"power must be in [0, 1], got {self.power!r}")
        return self.lambda_init

    def step_size(self, k: int) -> float:
        """eta_k for update number k = 1, 2, ..."""
        return float(self.eta * (self.offset / (self.offset + k - 1)) ** self.power)

    def _step(self, loss: float) -> float:
        self.last_eta_ = self.step_size(self.n_updates_ + 1)
        return self.lambda_ + self.last_eta_ * (self.epsilon - loss)

    def long_run_bound(self, n: int, lambdas: Sequence[float]) -> float | None:
        if n == 0:
            return None
        lam = np.asarray(lambdas, dtype=float)
        return float((lam.max() - lam.min()) / (self.step_size(n) * n) + self.clip_weighted_ / n)

    def guarantee_assumptions(self) -> str:
        return (
            "step identity: always (unclipped); long-run bound (range of lambda)/(eta_K K): "
            "always, -> 0 when lambda stays bounded (Angelopoulos, Barber & Bates 2024)"
        )


# --------------------------------------------------------------------------------------
class ACIRule(StepRule):
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

    guarantee = "identity"
    exact_step = True
    lambda_params = ()

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
    def eta(self) -> float:
        """The fixed step (gamma), under the name the monitor uses."""
        return self.gamma

    def _reset(self) -> float:
        if not (0.0 < float(self.alpha) < 1.0):
            raise ValueError(f"alpha must be in (0, 1), got {self.alpha!r}")
        _check_positive("gamma", self.gamma)
        lam = self.alpha if self.lambda_init is None else self.lambda_init
        return _check_finite("lambda_init", lam)

    def _step(self, loss: float) -> float:
        self.last_eta_ = float(self.gamma)
        return self.lambda_ + self.gamma * (self.alpha - loss)

    def long_run_bound(self, n: int, lambdas: Sequence[float]) -> float | None:
        if n == 0:
            return None
        lam1 = float(lambdas[0])
        return (max(lam1, 1.0 - lam1) + self.gamma) / (self.gamma * n) + self.clip_weighted_ / n

    def guarantee_assumptions(self) -> str:
        return (
            "loss = miscoverage in {0,1}; set = everything for lambda <= 0, empty for "
            "lambda >= 1 (Gibbs & Candès 2021, Prop. 4.1)"
        )


# --------------------------------------------------------------------------------------
LossFunction = Callable[[float], "float | None"]


class DtACIRule(StepRule):
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

    guarantee = "none"
    uses_loss_function = True
    #: Documented empirical tolerance on |miscoverage - alpha| after >= 1000 steps of a
    #: miscoverage loss (i.i.d., shifting, drifting and heavy-tailed scores; checked by
    #: the property tests). Not a theorem: the paper's bound is much looser at that K.
    EMPIRICAL_TOLERANCE: ClassVar[float] = 0.03
    lambda_params = ("gammas", "lambda_init", "lambda_min", "lambda_max")

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
        _check_positive("eta_weights", self.eta_weights)
        if int(self.n_grid) < 2:
            raise ValueError(f"n_grid must be >= 2, got {self.n_grid!r}")
        lam = self.epsilon if self.lambda_init is None else self.lambda_init
        lam = _check_finite("lambda_init", lam)
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
        res = np.empty_like(out)
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
            self.clip_total_ += float(self.weights_ @ (self.experts_ - experts))
        return float(self.weights_ @ self.experts_)

    def guarantee_assumptions(self) -> str:
        return (
            "miscoverage loss with ACI's set assumption; long-run and strongly-adaptive "
            "regret bounds of Gibbs & Candès 2022 (not computed online)"
        )


# --------------------------------------------------------------------------------------
class PIDRule(StepRule):
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

    guarantee = "long_run"
    lambda_params = ("eta", "K_I", "lambda_init", "lambda_min", "lambda_max")

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
        _check_finite("lambda_init", self.lambda_init)
        _check_positive("eta", self.eta, allow_zero=True)
        _check_positive("K_I", self.K_I, allow_zero=True)
        _check_positive("C_sat", self.C_sat)
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

    def guarantee_assumptions(self) -> str:
        return (
            "loss beyond epsilon at the saturated lambda on either side; then for any "
            "scorecaster (Angelopoulos, Candès & Tibshirani 2023, Thm 1)"
        )
