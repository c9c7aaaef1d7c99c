"""The generic conformal-decision loop.

It owns exactly one thing: *decide with the current lambda at the control rate; at each
sampling time observe the truth, score the interval, update lambda*. It knows nothing
about predictors, barriers, QPs or pedestrians; those live in the environment and the
decision family plugged into it (see :mod:`conformal_control.families.cbf` for the flagship
instantiation, and :mod:`conformal_control.families.domains` for other decision problems run
through the same loop). One interval, top to bottom::

    observation = env.sense()                      # sampling time k tau
    family.begin_interval(observation)             # the family plans (e.g. predicts)
    for each control instant of I_k:
        env.apply(family.decide(env.state(), lam)) # decide with lambda_k
    truth = env.reveal()                           # sampling time (k+1) tau
    l_k = loss(family.interval_record(), truth, lam)
    lam = rule.update(l_k)                         # lambda_{k+1}

With ``lambda_per="agent"`` lambda is a vector indexed by agent: after ``begin_interval``
the family names the interval's agents (``family.lambda_keys()``), each gets its entry
(a new one at the prior, see :class:`~conformal_control.core.monitor.AgentMonitor`), the
family decides with the vector, the loss is split by agent (``loss.components``) and
each entry is updated by its own copy of the rule from its own loss. With one agent this
is the scalar loop, bit for bit.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ParamSpec, TypeVar

import numpy as np

from .base import LAMBDA_PER, DecisionFamily, Environment, KeyedLosses, Loss, UpdateRule
from .exceptions import ConformalControlDeprecationWarning
from .monitor import AgentMonitor, GuaranteeMonitor

__all__ = [
    "ConformalLoop",
    "ConformalStepper",
    "IntervalLog",
    "IntervalScore",
    "LoopResult",
    "LossAt",
    "check_per_agent",
    "close_agent_interval",
    "close_interval",
]


@dataclass
class IntervalLog:
    """What happened during one interval k.

    With lambda run per agent, ``lam`` is the smallest (most conservative) entry the
    interval decided with (the prior of a new agent when no agent was sensed), ``loss``
    the largest of the agents' losses (the paper's loss at the vector lambda), ``l_avg``
    the pooled average of the agents' losses, and ``keys``, ``lams`` and
    ``agent_losses`` give every agent's entry and loss (NaN: not scored).
    """

    k: int
    lam: float
    loss: float | None
    n_steps: int
    diagnostics: dict[str, float] = field(default_factory=dict)
    #: Running average loss after this interval's update (online monitor), None without a loss.
    l_avg: float | None = None
    #: Per agent (lambda run per agent; None otherwise): the agents' keys, ...
    keys: np.ndarray | None = None
    #: ... the lambda each decided with, ...
    lams: np.ndarray | None = None
    #: ... and each one's loss (NaN where it was not scored).
    agent_losses: np.ndarray | None = None


@dataclass
class LoopResult:
    """Outcome of :meth:`ConformalLoop.run`.

    Attributes
    ----------
    intervals : list of IntervalLog
        One entry per interval (including intervals without a loss).
    lambda_final : float
        lambda after the last update (lambda_{K+1}); per agent, the lambda a new agent
        would start at (:meth:`AgentMonitor.prior_value`).
    monitor : GuaranteeMonitor or AgentMonitor
        Running average loss, Theorem-2 identity residual and bound (per agent and pooled
        when lambda is run per agent).
    """

    intervals: list[IntervalLog]
    lambda_final: float
    monitor: GuaranteeMonitor | AgentMonitor

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


@dataclass
class IntervalScore:
    """An interval's score: its loss l_k, the loss's diagnostics, and l_k as a function of
    lambda (for rules that re-evaluate it, ``uses_loss_function``)."""

    loss: float | None
    diagnostics: dict[str, float] = field(default_factory=dict)
    loss_at: Callable[[float], float | None] | None = None


def close_interval(
    k: int,
    lam: float,
    n_steps: int,
    *,
    rule: UpdateRule,
    monitor: GuaranteeMonitor,
    learn: bool = True,
    loss: Loss[Any, Any] | None = None,
    record: Any = None,
    truth: Any = None,
    score: IntervalScore | None = None,
) -> tuple[IntervalLog, float]:
    """Score interval ``k`` and update lambda: the end of every interval, in every engine.

    The interval is scored by ``loss`` on its ``record`` and ``truth`` with the lambda it
    ran with, unless ``score`` is given (an engine that computed l_k itself, the same
    arithmetic). A scored interval updates lambda through the ``monitor`` (which steps the
    ``rule``; without ``learn`` lambda stays and the loss is only observed).

    Parameters
    ----------
    k : int
        The interval's index (from 0).
    lam : float
        lambda_k, the lambda the interval's decisions were taken with.
    n_steps : int
        Control instants the interval ran.
    rule : UpdateRule
        Turns losses into the next lambda; a rule with ``uses_loss_function`` first
        receives l_k as a function of lambda.
    monitor : GuaranteeMonitor
        The running average loss and the guarantee's bookkeeping (steps ``rule``).
    learn : bool
        False keeps lambda at its value.
    loss, record, truth
        The loss and what it scores (when ``score`` is None).
    score : IntervalScore, optional
        The interval's score, computed by the caller.

    Returns
    -------
    (IntervalLog, float)
        The interval's log and lambda_{k+1}.
    """
    if score is None:
        if loss is None:
            raise ValueError("close_interval needs a loss (with record and truth) or a score")
        l_k = loss(record, truth, lam)
        score = IntervalScore(
            l_k,
            loss.diagnostics(record, truth, lam) if l_k is not None else {},
            LossAt(loss, record, truth),
        )
    log = IntervalLog(k=k, lam=lam, loss=score.loss, n_steps=n_steps, diagnostics=score.diagnostics)
    if score.loss is not None:
        if learn:
            if rule.capabilities.uses_loss_function:
                rule.set_loss_function(score.loss_at)
            lam = monitor.update(score.loss)
        else:
            monitor.observe(score.loss, lam)
            monitor.set_lambda_next(lam)
        log.l_avg = monitor.average
    return log, lam


def close_agent_interval(
    k: int,
    keys: np.ndarray,
    lams: np.ndarray,
    n_steps: int,
    *,
    monitor: AgentMonitor,
    loss: Loss[Any, Any] | None = None,
    record: Any = None,
    truth: Any = None,
    components: KeyedLosses | None = None,
    diagnostics: dict[str, float] | None = None,
    floors: np.ndarray | None = None,
) -> tuple[IntervalLog, float]:
    """:func:`close_interval` with lambda run per agent: score interval ``k`` agent by
    agent and update each scored agent's entry from its own loss.

    Parameters
    ----------
    k : int
        The interval's index (from 0).
    keys : ndarray of shape (n,)
        The interval's agents (the family's ``lambda_keys()``).
    lams : ndarray of shape (n,)
        Their lambdas, which the interval's decisions were taken with.
    n_steps : int
        Control instants the interval ran.
    monitor : AgentMonitor
        The agents' entries, rules and guarantees (updated here).
    loss, record, truth
        The loss and what it scores (when ``components`` is None).
    components : KeyedLosses, optional
        The interval's losses per agent, computed by the caller.
    diagnostics : dict, optional
        The loss's diagnostics, computed by the caller.
    floors : ndarray of shape (n,), optional
        The agents' own feasibility floors of the interval, in ``keys``' order (the
        family's ``lambda_floors()``; read by a monitor with ``row_floor``).

    Returns
    -------
    (IntervalLog, float)
        The interval's log and the lambda a new agent would start at now.
    """
    if components is None:
        if loss is None:
            raise ValueError(
                "close_agent_interval needs a loss (with record and truth) or components"
            )
        components = loss.components(record, truth, lams)
        if components is None:
            raise ValueError(
                f"the loss {type(loss).__name__} does not split by agent (components() gave "
                "None): lambda cannot be run per agent with it"
            )
        if diagnostics is None and np.isfinite(components.values).any():
            diagnostics = loss.diagnostics(record, truth, lams)
    values = np.asarray(components.values, dtype=float)
    scored = np.isfinite(values)
    l_k = float(values[scored].max()) if scored.any() else None
    per = np.full(len(keys), np.nan)
    where = {int(key): i for i, key in enumerate(np.asarray(keys).tolist())}
    for key, v in zip(np.asarray(components.keys).tolist(), values.tolist(), strict=True):
        i = where.get(int(key))
        if i is None:
            raise ValueError(f"the loss scored agent {key}, which the family gave no lambda")
        per[i] = v
    log = IntervalLog(
        k=k,
        lam=float(lams.min()) if lams.size else monitor.prior_value(),
        loss=l_k,
        n_steps=n_steps,
        diagnostics=dict(diagnostics or {}) if l_k is not None else {},
        keys=np.array(keys, dtype=np.int64),
        lams=np.array(lams, dtype=float),
        agent_losses=per,
    )
    own = None
    if floors is not None:  # the scored keys' floors (components may leave keys out)
        fl = np.asarray(floors, dtype=float).ravel()
        if fl.shape != (len(keys),):
            raise ValueError(f"{fl.size} floors for the interval's {len(keys)} agents")
        own = np.array([fl[where[int(key)]] for key in np.asarray(components.keys).tolist()])
    monitor.update(components.keys, values, components.at, floors=own)
    if l_k is not None:
        log.l_avg = monitor.average
    return log, monitor.prior_value()


_P = ParamSpec("_P")
_R = TypeVar("_R")


def _policy_is_family(init: Callable[_P, _R]) -> Callable[_P, _R]:
    """Accept 0.2's keyword ``policy=`` for the family, with a ``DeprecationWarning``."""

    @functools.wraps(init)
    def wrapper(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        if "policy" in kwargs:
            warnings.warn(
                "the loop's keyword policy= is now family= (removed in 0.4, not before 2027-06-30)",
                ConformalControlDeprecationWarning,
                stacklevel=2,
            )
            kwargs["family"] = kwargs.pop("policy")
        return init(*args, **kwargs)

    return wrapper


class ConformalStepper:
    """The loop's body, one call at a time: for a world that is not an :class:`Environment`.

    :class:`ConformalLoop` drives a stepper from an environment; a user with their own
    simulator or robot drives it directly::

        stepper = ConformalStepper(family, loss, rule)
        stepper.start()
        while running:
            stepper.begin_interval(observation)        # at a sampling time
            for each control instant:
                apply(stepper.decide(state))            # decided with stepper.lam
            stepper.end_interval(truth)                 # at the next sampling time
        result = stepper.result()

    Parameters
    ----------
    family : DecisionFamily
        The decision family D^lambda (e.g. the conformal CBF controller). The keyword
        ``policy=`` of 0.2 is still accepted, with a ``DeprecationWarning``.
    loss : Loss
        Scores an interval once its truth is revealed, with the lambda used during it.
    rule : UpdateRule
        Turns losses into the next lambda.
    learn : bool
        If False, lambda stays at its initial value (losses are still computed).
    lambda_safe : float, optional
        A lambda known (or estimated) to make the decisions safe (see
        :class:`ConformalLoop`).
    lambda_safe_source : str, optional
        Where ``lambda_safe`` came from, reported with the verdict.
    lambda_safe_proven : bool
        lambda <= lambda_safe provably keeps the loss <= epsilon for this family.
    on_interval : callable, optional
        Called with each :class:`IntervalLog` as soon as the interval is scored.
    lambda_per : {"run", "agent"}
        One lambda for the run (the paper's), or one per agent: the family then decides
        with a vector indexed by its ``lambda_keys()`` and each entry learns from its
        agent's own loss (``loss.components``), see
        :class:`~conformal_control.core.monitor.AgentMonitor`.
    lambda_prior : float
        Per agent: the quantile in [0, 1] of the current lambdas a new agent starts at.
    lambda_floor_row : float
        Per agent: the share in [0, 1] of each agent's own feasibility floor (the
        family's ``lambda_floors()``) that may replace the rule's ``lambda_min`` for it
        (:class:`~conformal_control.core.monitor.AgentMonitor`'s ``row_floor``); 0: off.
    lambda_floor_step : float
        Per agent: how far an agent's own floor steps down at an update whose lambda_j
        sat at it while its loss exceeded epsilon (1/s;
        :class:`~conformal_control.core.monitor.AgentMonitor`'s ``floor_step``); 0: off.
    lambda_floor_limit : float
        Per agent: the lowest floor ``lambda_floor_step`` reaches (1/s; -inf: none).
    """

    @_policy_is_family
    def __init__(
        self,
        family: DecisionFamily[Any, Any, Any, Any],
        loss: Loss[Any, Any],
        rule: UpdateRule,
        *,
        learn: bool = True,
        lambda_safe: float | None = None,
        lambda_safe_source: str | None = None,
        lambda_safe_proven: bool = False,
        on_interval: Callable[[IntervalLog], None] | None = None,
        lambda_per: str = "run",
        lambda_prior: float = 0.5,
        lambda_floor_row: float = 0.0,
        lambda_floor_step: float = 0.0,
        lambda_floor_limit: float = -math.inf,
    ) -> None:
        self.family = family
        self.loss = loss
        self.rule = rule
        self.learn = learn
        self.lambda_safe = lambda_safe
        self.lambda_safe_source = lambda_safe_source
        self.lambda_safe_proven = lambda_safe_proven
        self.on_interval = on_interval
        self.lambda_per = lambda_per
        self.lambda_prior = lambda_prior
        self.lambda_floor_row = lambda_floor_row
        self.lambda_floor_step = lambda_floor_step
        self.lambda_floor_limit = lambda_floor_limit

    @property
    def policy(self) -> DecisionFamily[Any, Any, Any, Any]:
        """Deprecated name of :attr:`family` (removed in 0.4, not before 2027-06-30)."""
        warnings.warn(
            "the loop's attribute policy is now family (removed in 0.4, not before 2027-06-30)",
            ConformalControlDeprecationWarning,
            stacklevel=2,
        )
        return self.family

    def start(self) -> float:
        """Reset the family and the rule; return lambda_1."""
        if self.lambda_per not in LAMBDA_PER:
            raise ValueError(
                f"lambda_per must be one of {', '.join(LAMBDA_PER)}, got {self.lambda_per!r}"
            )
        self._vector = self.lambda_per == "agent"
        if self._vector:
            check_per_agent(self.family, self.loss)
        self.family.reset()
        self.monitor_: GuaranteeMonitor | AgentMonitor
        self.monitor_ = (AgentMonitor if self._vector else GuaranteeMonitor).for_rule(
            self.rule,
            lambda_safe=self.lambda_safe,
            lambda_safe_source=self.lambda_safe_source,
            premise_proven=self.lambda_safe_proven,
            bounds=self.loss.bounds,
            learn=self.learn,
            **(
                {
                    "prior": self.lambda_prior,
                    "row_floor": self.lambda_floor_row,
                    "floor_step": self.lambda_floor_step,
                    "floor_limit": self.lambda_floor_limit,
                }
                if self._vector
                else {}
            ),
        )
        self.lam_ = self.monitor_.lambda_1
        self._keys = np.zeros(0, dtype=np.int64)
        self._lams = np.zeros(0)
        self.intervals_: list[IntervalLog] = []
        #: The last closed interval's record (what the loss scored; None before the first).
        self.record_: Any = None
        self._n_steps = 0
        self._open = False
        return self.lam_

    @property
    def lam(self) -> float:
        """The lambda decisions are taken with now (lambda_k); per agent, the lambda a new
        agent would start at."""
        return self.lam_

    @property
    def lams(self) -> np.ndarray | None:
        """Per agent: the current interval's lambdas, one per key of the family's
        ``lambda_keys()`` (None with one lambda for the run)."""
        return self._lams if self._vector else None

    @property
    def lam_extreme(self) -> float:
        """The entry of lambda farthest from 0 (lambda itself with one lambda): what an
        overflow check looks at."""
        if not self._vector:
            return self.lam_
        assert isinstance(self.monitor_, AgentMonitor)
        cur = np.append(self.monitor_.current(), self.lam_)
        return float(cur[int(np.argmax(np.abs(cur)))])

    def begin_interval(self, observation: Any) -> None:
        """Sampling time k tau: hand the observation to the family."""
        if self._open:
            raise RuntimeError("begin_interval() called twice without end_interval()")
        self.family.begin_interval(observation)
        if self._vector:
            assert isinstance(self.monitor_, AgentMonitor)
            keys = self.family.lambda_keys()
            if keys is None:
                raise ValueError(
                    f"{type(self.family).__name__}.lambda_keys() gave None after "
                    "begin_interval: lambda cannot be run per agent with this family"
                )
            self._keys = np.asarray(keys, dtype=np.int64).ravel()
            self._lams = self.monitor_.values(self._keys)
        self._n_steps = 0
        self._open = True

    def decide(self, state: Any) -> Any:
        """Decision D^{lambda_k}(state) at a control instant of the open interval."""
        if not self._open:
            raise RuntimeError("decide() called outside an interval (call begin_interval())")
        self._n_steps += 1
        if self._vector:
            # the family takes an array per agent (it declares lambda_keys), see
            # DecisionFamily.decide: the base signature keeps the scalar for every family
            decide: Callable[[Any, np.ndarray], Any] = self.family.decide  # type: ignore[assignment]
            return decide(state, self._lams)
        return self.family.decide(state, self.lam_)

    def add_decisions(self, n: int) -> None:
        """Count ``n`` decisions of the open interval made for this stepper by a lockstep
        engine (its family's compiled step called directly, at this stepper's ``lam_``),
        as :meth:`decide` counts its own.

        Parameters
        ----------
        n : int
            Decisions made.
        """
        if not self._open:
            raise RuntimeError("add_decisions() called outside an interval")
        self._n_steps += int(n)

    def end_interval(self, truth: Any) -> IntervalLog:
        """Sampling time (k+1) tau: score the interval on its truth, update lambda."""
        if not self._open:
            raise RuntimeError("end_interval() called without begin_interval()")
        self._open = False
        self.record_ = record = self.family.interval_record()
        if isinstance(self.monitor_, AgentMonitor):
            log, self.lam_ = close_agent_interval(
                len(self.intervals_),
                self._keys,
                self._lams,
                self._n_steps,
                monitor=self.monitor_,
                loss=self.loss,
                record=record,
                truth=truth,
                floors=self.family.lambda_floors() if self.monitor_.row_floor > 0 else None,
            )
        else:
            log, self.lam_ = close_interval(
                len(self.intervals_),
                self.lam_,
                self._n_steps,
                rule=self.rule,
                monitor=self.monitor_,
                learn=self.learn,
                loss=self.loss,
                record=record,
                truth=truth,
            )
        self.intervals_.append(log)
        if self.on_interval is not None:
            self.on_interval(log)
        return log

    def result(self) -> LoopResult:
        """Everything so far as a :class:`LoopResult`."""
        return LoopResult(
            intervals=list(self.intervals_), lambda_final=self.lam_, monitor=self.monitor_
        )


class ConformalLoop(ConformalStepper):
    """Run a conformal decision family in an environment.

    Parameters
    ----------
    env : Environment
        The world: sensor, plant, ground truth.
    family : DecisionFamily
        The decision family D^lambda (e.g. the conformal CBF controller). The keyword
        ``policy=`` of 0.2 is still accepted, with a ``DeprecationWarning``.
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
        :class:`~conformal_control.core.monitor.GuaranteeMonitor`).
    on_interval : callable, optional
        Called with each :class:`IntervalLog` as soon as the interval is scored.
    lambda_per : {"run", "agent"}
        One lambda for the run, or one per agent (see :class:`ConformalStepper`).
    lambda_prior : float
        Per agent: the quantile of the current lambdas a new agent starts at.
    lambda_floor_row : float
        Per agent: the share of each agent's own feasibility floor that may replace
        ``lambda_min`` for it (see :class:`ConformalStepper`).
    lambda_floor_step, lambda_floor_limit : float
        Per agent: each agent's own floor stepping down while it binds and the agent is
        missed, and its limit (1/s; see :class:`ConformalStepper`).
    """

    @_policy_is_family
    def __init__(
        self,
        env: Environment[Any, Any, Any, Any],
        family: DecisionFamily[Any, Any, Any, Any],
        loss: Loss[Any, Any],
        rule: UpdateRule,
        *,
        learn: bool = True,
        lambda_safe: float | None = None,
        lambda_safe_source: str | None = None,
        lambda_safe_proven: bool = False,
        on_interval: Callable[[IntervalLog], None] | None = None,
        lambda_per: str = "run",
        lambda_prior: float = 0.5,
        lambda_floor_row: float = 0.0,
        lambda_floor_step: float = 0.0,
        lambda_floor_limit: float = -math.inf,
    ) -> None:
        super().__init__(
            family,
            loss,
            rule,
            learn=learn,
            lambda_safe=lambda_safe,
            lambda_safe_source=lambda_safe_source,
            lambda_safe_proven=lambda_safe_proven,
            on_interval=on_interval,
            lambda_per=lambda_per,
            lambda_prior=lambda_prior,
            lambda_floor_row=lambda_floor_row,
            lambda_floor_step=lambda_floor_step,
            lambda_floor_limit=lambda_floor_limit,
        )
        self.env = env

    def run(self, max_intervals: int | None = None) -> LoopResult:
        """Run until the environment is done (or ``max_intervals`` intervals)."""
        env = self.env
        env.reset()
        self.start()
        while not env.done and (max_intervals is None or len(self.intervals_) < max_intervals):
            # sampling time k*tau: the family receives the observation (and plans)
            self.begin_interval(env.sense())
            # control instants of I_k: decide with lambda_k, apply through the plant
            for _ in range(env.control_instants()):
                env.apply(self.decide(env.state()))
                if env.done:
                    break
            # sampling time (k+1)*tau: the truth over I_k is revealed; score, update
            self.end_interval(env.reveal())
        return self.result()


def check_per_agent(family: DecisionFamily[Any, Any, Any, Any], loss: Loss[Any, Any]) -> None:
    """Raise ``ValueError`` (one line) unless ``family`` and ``loss`` can run lambda per
    agent: the family names its agents (``lambda_keys``) and the loss splits by agent
    (``components``)."""
    if type(family).lambda_keys is DecisionFamily.lambda_keys:
        raise ValueError(
            f"the family {type(family).__name__} takes one lambda (it has no lambda_keys()): "
            "lambda cannot be run per agent with it"
        )
    if type(loss).components is Loss.components:
        raise ValueError(
            f"the loss {type(loss).__name__} does not split by agent (no components()): "
            "lambda cannot be run per agent with it"
        )


class LossAt:
    """l_k as a function of lambda: the interval's loss re-evaluated at another lambda."""

    def __init__(self, loss: Loss[Any, Any], record: Any, truth: Any) -> None:
        self.loss, self.record, self.truth = loss, record, truth

    def __call__(self, lam: float) -> float | None:
        return self.loss(self.record, self.truth, lam)
