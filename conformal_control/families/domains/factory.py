"""The CDT paper's factory example through the generic conformal loop.

A machine runs at speed lambda_k >= 0 during step k and makes ``p`` items; each item is
defective with probability q(lambda) = min(1, b * lambda), increasing in the speed. The
loss is the fraction of defective items, in [0, 1]; the target is epsilon. Faster is more
productive, slower is safer: smaller lambda = more conservative, as everywhere in the
toolkit. lambda = 0 (machine stopped) makes no defect, so the family is eventually safe
with lambda_safe = 0 and Theorem 2 bounds the average defect fraction by
epsilon + (lambda_1 + eta) / (eta K) (with lambda_1 >= -eta).

Randomness uses common random numbers: the truth of step k is the vector of ``p``
uniforms u, and the defects at speed lambda are the u_i < q(lambda). The draw does not
depend on the decision, so the loss can be evaluated at any lambda (what DtACI's experts
need) and defects are Binomial(p, q(lambda_k)) at the speed actually used.

Default parameters follow the paper's description of the example (T = 500 steps,
lambda_1 = 0.1, eta = 0.1, epsilon = 0.05, p = 10, b = 0.75, 100 seeded runs); the form
q(lambda) = min(1, b lambda) is our reading of "a defect rate increasing in the speed".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.base import DecisionFamily, Loss, SingleStepEnvironment, UpdateRule
from ...core.loop import ConformalLoop, LoopResult
from ...core.losses import check_lambda

__all__ = [
    "DefectFractionLoss",
    "FactoryEnvironment",
    "FactoryRecord",
    "MachineSpeed",
    "defect_rate",
    "run_factory",
]


def defect_rate(lam: float, b: float) -> float:
    """q(lambda) = min(1, b * max(lambda, 0))."""
    return float(min(1.0, b * max(float(lam), 0.0)))


@dataclass
class FactoryRecord:
    """The speed used during the step."""

    speed: float


class FactoryEnvironment(SingleStepEnvironment[int, float, np.ndarray]):
    """The factory: one control instant per step, ``p`` uniforms revealed per step.

    Parameters
    ----------
    T : int
        Number of steps.
    p : int
        Items made per step.
    seed : int
        Seed of the defect draws.
    """

    def __init__(self, T: int = 500, p: int = 10, seed: int = 0) -> None:
        self.T = T
        self.p = p
        self.seed = seed

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{"T": 30, "p": 5, "seed": 1}]

    @classmethod
    def _unit_test_family(cls) -> MachineSpeed:
        return MachineSpeed()

    def reset(self) -> None:
        if int(self.T) != self.T or self.T < 1 or int(self.p) != self.p or self.p < 1:
            raise ValueError(f"T and p must be integers >= 1, got T={self.T!r}, p={self.p!r}")
        self._rng = np.random.default_rng(self.seed)
        self.t = 0
        self.speeds_: list[float] = []
        self._u = np.empty(0)

    @property
    def done(self) -> bool:
        return self.t >= self.T

    def observe(self) -> int:
        return self.t

    def apply(self, decision: Any) -> None:
        if self.done:
            raise RuntimeError("apply() called on a finished factory run")
        self.speeds_.append(float(decision))
        self._u = self._rng.uniform(size=int(self.p))
        self.t += 1

    def reveal(self) -> np.ndarray:
        u: np.ndarray = self._u.copy()
        return u


class MachineSpeed(DecisionFamily[int, int, float, FactoryRecord]):
    """D^lambda = run the machine at speed max(lambda, 0)."""

    def __init__(self) -> None:
        pass

    @classmethod
    def _unit_test_environment(cls) -> FactoryEnvironment:
        return FactoryEnvironment(T=30, p=5, seed=1)

    def begin_interval(self, observation: int) -> None:
        self._speed = math.nan

    def decide(self, state: Any, lam: float) -> float:
        self._speed = max(float(lam), 0.0)
        return self._speed

    def interval_record(self) -> FactoryRecord:
        return FactoryRecord(self._speed)


class DefectFractionLoss(Loss[FactoryRecord, np.ndarray]):
    """l = fraction of the step's items that are defective at speed lambda, in [0, 1].

    ``truth`` is the step's vector of uniforms (see the module docstring); an item is
    defective when its uniform is below q(lambda) = min(1, b max(lambda, 0)).

    Parameters
    ----------
    b : float
        Defect-rate slope (> 0): q(lambda) = min(1, b lambda).
    """

    bounds = (0.0, 1.0)

    def __init__(self, b: float = 0.75) -> None:
        self.b = b

    @classmethod
    def _unit_test_inputs(cls) -> list[tuple[FactoryRecord, np.ndarray]]:
        rng = np.random.default_rng(0)
        return [
            (FactoryRecord(0.1), rng.uniform(size=10)),
            (FactoryRecord(0.0), rng.uniform(size=1)),
            (FactoryRecord(2.0), np.empty(0)),  # no item made: no loss
        ]

    def __call__(self, record: Any, truth: np.ndarray, lam: float) -> float | None:
        lam = check_lambda(lam)
        if not (math.isfinite(self.b) and self.b > 0):
            raise ValueError(f"b must be a finite number > 0, got {self.b!r}")
        u = np.asarray(truth, dtype=float)
        if u.size == 0:
            return None
        return float(np.mean(u < defect_rate(lam, self.b)))


def run_factory(
    rule: UpdateRule,
    *,
    T: int = 500,
    p: int = 10,
    b: float = 0.75,
    seed: int = 0,
    lambda_safe: float | None = 0.0,
) -> tuple[LoopResult, dict[str, Any]]:
    """Run the factory once; return the loop result and its figures.

    The figures: ``l_avg`` (average defect fraction), ``speed_avg`` (average speed,
    the productivity), ``lambda_final`` and the monitor's guarantee figures.

    Parameters
    ----------
    rule : UpdateRule
        The update rule of the machine's speed lambda.
    T : int
        Steps.
    p : int
        Items made per step.
    b : float
        Slope of the defect rate q(lambda) = min(1, b lambda).
    seed : int
        Seed of the common random numbers.
    lambda_safe : float, optional
        A speed known to make no defect (0: the stopped machine), for the monitor.
    """
    env = FactoryEnvironment(T=T, p=p, seed=seed)
    loss = DefectFractionLoss(b=b)
    # lambda <= 0 stops the machine: no item, no defect -- the premise holds by construction
    loop = ConformalLoop(
        env,
        MachineSpeed(),
        loss,
        rule,
        lambda_safe=lambda_safe,
        lambda_safe_source="stopped machine (lambda <= 0 makes no defect)",
        lambda_safe_proven=lambda_safe is not None and lambda_safe <= 0,
    )
    result = loop.run()
    figures = {
        "l_avg": result.l_avg,
        "speed_avg": float(np.mean(env.speeds_)),
        "lambda_final": result.lambda_final,
        **result.guarantee,
    }
    return result, figures
