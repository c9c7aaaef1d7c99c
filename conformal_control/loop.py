"""The generic conformal-decision loop.

It owns exactly one thing: *decide with the current lambda at the control rate; at each
sampling time observe the truth, score the interval, update lambda*. It knows nothing
about predictors, barriers, QPs or pedestrians; those live in the environment and the
decision family plugged into it (see :mod:`conformal_control.cbf` for the flagship
instantiation, and :mod:`conformal_control.domains` for other decision problems run
through the same loop). One interval, top to bottom::

    observation = env.sense()                      # sampling time k tau
    policy.begin_interval(observation)             # the family plans (e.g. predicts)
    for each control instant of I_k:
        env.apply(policy.decide(env.state(), lam)) # decide with lambda_k
    truth = env.reveal()                           # sampling time (k+1) tau
    l_k = loss(policy.interval_record(), truth, lam)
    lam = rule.update(l_k)                         # lambda_{k+1}
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .base import DecisionFamily, Environment, Loss, UpdateRule
from .monitor import GuaranteeMonitor

__all__ = ["ConformalLoop", "IntervalLog", "LoopResult"]


@dataclass
class IntervalLog:
    """What happened during one interval k."""

    k: int
    lam: float
    loss: float | None
    n_steps: int
    diagnostics: dict[str, float] = field(default_factory=dict)
    #: Running average loss after this interval (online monitor), None before any loss.
    l_avg: float | None = None


@dataclass
class LoopResult:
    """Outcome of :meth:`ConformalLoop.run`.

    Attributes
    ----------
    intervals : list of IntervalLog
        One entry per interval (including intervals without a loss).
    lambda_final : float
        lambda after the last update (lambda_{K+1}).
    monitor : GuaranteeMonitor
        Running average loss, Theorem-2 identity residual and bound.
    """

    intervals: list[IntervalLog]
    lambda_final: float
    monitor: GuaranteeMonitor

    @property
    def updates(self) -> list[IntervalLog]:
        """The intervals that produced a loss (and hence a lambda update)."""
        return [iv for iv in self.intervals if iv.loss is not None]

    @property
    def losses(self) -> np.ndarray:
        return np.array([iv.loss for iv in self.updates], dtype=float)

    @property
    def lambdas(self) -> np.ndarray:
        """lambda_k used during each updating interval."""
        return np.array([iv.lam for iv in self.updates], dtype=float)

    @property
    def n_updates(self) -> int:
        return len(self.updates)

    @property
    def l_avg(self) -> float:
        losses = self.losses
        return float(losses.mean()) if losses.size else math.nan

    @property
    def guarantee(self) -> dict[str, Any]:
        """The monitor's figures: guarantee kind, identity residual, bounds and checks."""
        return self.monitor.summary()


class ConformalLoop:
    """Run a conformal decision policy in an environment.

    Parameters
    ----------
    env : Environment
        The world: sensor, plant, ground truth.
    policy : DecisionFamily
        The decision family D^lambda (e.g. the conformal CBF controller).
    loss : Loss
        Scores an interval once its truth is revealed, with the lambda used during it.
    rule : UpdateRule
        Turns losses into the next lambda.
    learn : bool
        If False, lambda stays at its initial value (losses are still computed).
    lambda_safe : float, optional
        A lambda known (or estimated) to make the decisions safe: the monitor then reports
        the Theorem-2 bound (fixed-step rules), whether it holds and whether its premise
        was contradicted.
    lambda_safe_source : str, optional
        Where ``lambda_safe`` came from, reported with the verdict.
    lambda_safe_proven : bool
        lambda <= lambda_safe provably keeps the loss <= epsilon for this family (see
        :class:`~conformal_control.monitor.GuaranteeMonitor`).
    on_interval : callable, optional
        Called with each :class:`IntervalLog` as soon as the interval is scored.
    """

    def __init__(
        self,
        env: Environment[Any, Any, Any, Any],
        policy: DecisionFamily[Any, Any, Any, Any],
        loss: Loss[Any, Any],
        rule: UpdateRule,
        *,
        learn: bool = True,
        lambda_safe: float | None = None,
        lambda_safe_source: str | None = None,
        lambda_safe_proven: bool = False,
        on_interval: Callable[[IntervalLog], None] | None = None,
    ) -> None:
        self.env = env
        self.policy = policy
        self.loss = loss
        self.rule = rule
        self.learn = learn
        self.lambda_safe = lambda_safe
        self.lambda_safe_source = lambda_safe_source
        self.lambda_safe_proven = lambda_safe_proven
        self.on_interval = on_interval

    def run(self, max_intervals: int | None = None) -> LoopResult:
        """Run until the environment is done (or ``max_intervals`` intervals)."""
        env, policy, loss, rule = self.env, self.policy, self.loss, self.rule
        env.reset()
        policy.reset()
        monitor = GuaranteeMonitor.for_rule(
            rule,
            lambda_safe=self.lambda_safe,
            lambda_safe_source=self.lambda_safe_source,
            premise_proven=self.lambda_safe_proven,
            bounds=loss.bounds,
            learn=self.learn,
        )
        lam = monitor.lambda_1
        wants_loss_fn = self.learn and rule.uses_loss_function
        intervals: list[IntervalLog] = []
        k = 0
        while not env.done and (max_intervals is None or k < max_intervals):
            # sampling time k*tau: the family receives the observation (and plans)
            policy.begin_interval(env.sense())
            # control instants of I_k: decide with lambda_k, apply through the plant
            n_steps = 0
            for _ in range(env.control_instants()):
                env.apply(policy.decide(env.state(), lam))
                n_steps += 1
                if env.done:
                    break
            # sampling time (k+1)*tau: the truth over I_k is revealed; score, update
            truth = env.reveal()
            record = policy.interval_record()
            l_k = loss(record, truth, lam)
            diagnostics = loss.diagnostics(record, truth, lam) if l_k is not None else {}
            log = IntervalLog(k=k, lam=lam, loss=l_k, n_steps=n_steps, diagnostics=diagnostics)
            intervals.append(log)
            if l_k is not None:
                if self.learn:
                    if wants_loss_fn:
                        rule.set_loss_function(_LossAt(loss, record, truth))
                    lam = monitor.update(l_k)
                else:
                    monitor.observe(l_k, lam)
                    monitor.set_lambda_next(lam)
                log.l_avg = monitor.average
            if self.on_interval is not None:
                self.on_interval(log)
            k += 1
        return LoopResult(intervals=intervals, lambda_final=lam, monitor=monitor)


class _LossAt:
    """l_k as a function of lambda: the interval's loss re-evaluated at another lambda."""

    def __init__(self, loss: Loss, record: Any, truth: Any) -> None:
        self.loss, self.record, self.truth = loss, record, truth

    def __call__(self, lam: float) -> float | None:
        return self.loss(self.record, self.truth, lam)
