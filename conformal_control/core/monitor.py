"""Online guarantee monitor for the conformal loop (rule-aware).

For the fixed-step rule lambda_{k+1} = lambda_k + eta (epsilon - l_k), unrolling gives
the exact identity (sum the K updates: the lambdas telescope)::

    (1/K) sum_k l_k = epsilon + (lambda_1 - lambda_{K+1}) / (eta K)

and, for an eventually-safe controller with lambda_1 >= lambda_safe - eta, the bound
(1/K) sum_k l_k <= epsilon + (lambda_1 - lambda_safe + eta) / (eta K) (paper Theorem 2).

For any rule of the form lambda_{k+1} = lambda_k + eta_k (epsilon - l_k) (fixed, decaying,
ACI) the monitor checks the weighted identity sum_k eta_k (epsilon - l_k) = lambda_{K+1} -
lambda_1 and reports its residual normalised by sum_k eta_k (for a fixed step this is
exactly |mean(l) - epsilon - (lambda_1 - lambda_{K+1})/(eta K)|): ~1e-15 unless lambda was
clipped. Rules that declare a long-run bound (decaying step, ACI, PID) get
|mean(l) - epsilon| <= bound checked as well. Which figures apply is read from the rule's
``guarantee`` kind (see :mod:`conformal_control.core.update_rules`).

Theorem 2 rests on a premise about the decision family, "lambda <= lambda_safe keeps the
loss <= epsilon", which no arithmetic on the losses can prove. The monitor checks it on
what it sees: every update whose lambda_k <= lambda_safe and whose loss exceeds epsilon
contradicts the premise (``premise_violations``). The verdict (``theorem2_verdict``) is
``"holds"`` only when the bound is met, its lambda_1 assumption holds and the premise was
tested on at least one such update without a contradiction (or is proven for the family,
``premise_proven``, as for the factory's stopped machine); otherwise it says which part
is missing. Where lambda_safe came from is recorded (``lambda_safe_source``).

Used on its own, the monitor drives a rule in a few lines (river style)::

    rule = FixedEtaRule(epsilon=0.1, eta=0.05)
    monitor = GuaranteeMonitor.for_rule(rule)      # resets the rule
    for x, y in stream:
        decision = family(x, monitor.lam)          # decide with the current lambda
        monitor.update(loss(decision, y, monitor.lam))
    monitor.summary()
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from .base import UpdateRule
from .capabilities import GuaranteeKind

__all__ = ["AgentMonitor", "GuaranteeMonitor", "Theorem2Verdict"]

#: The monitor's reading of Theorem 2: ``"holds"`` (bound met, lambda_1 assumption met,
#: premise tested without contradiction), ``"violated"`` (average above the bound),
#: ``"premise_fails"`` (an update with lambda_k <= lambda_safe had loss > epsilon: the
#: given lambda_safe is not safe), ``"premise_untested"`` (lambda never went down to
#: lambda_safe: the bound is met but says nothing), ``"assumption_fails"`` (lambda_1 <
#: lambda_safe - eta or a clip below lambda_safe - eta), ``"not_applicable"`` (no
#: lambda_safe, not a fixed-step rule, no loss yet).
Theorem2Verdict = Literal[
    "holds", "violated", "premise_fails", "premise_untested", "assumption_fails", "not_applicable"
]

_TOL = 1e-12


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
    kind : str or None
        The rule's guarantee kind; default: ``"identity"`` when ``eta`` is given, else
        ``"none"``.
    rule : UpdateRule or None
        The rule (for its long-run bound and clipping settings).
    lambda_safe_source : str or None
        Where ``lambda_safe`` came from (``"given"``, ``"feasibility floor"``, ...);
        reported beside the verdict.
    premise_proven : bool
        The premise "lambda <= lambda_safe keeps the loss <= epsilon" holds by
        construction of the family (a proof, not an estimate); the verdict then does not
        need an update at or below lambda_safe to say "holds".
    """

    epsilon: float
    lambda_1: float
    eta: float | None = None
    lambda_safe: float | None = None
    bounds: tuple[float, float] = (-0.5, 0.5)
    kind: GuaranteeKind | None = None
    rule: UpdateRule | None = None
    lambda_safe_source: str | None = None
    premise_proven: bool = False
    losses: list[float] = field(default_factory=list)
    lambdas: list[float] = field(default_factory=list)
    etas: list[float] = field(default_factory=list)
    lambda_next: float = math.nan

    def __post_init__(self) -> None:
        if self.kind is None:
            self.kind = "identity" if self.eta is not None else "none"
        if self.lambda_safe is not None:
            if not math.isfinite(self.lambda_safe):
                raise ValueError(f"lambda_safe must be a finite number, got {self.lambda_safe!r}")
            if self.lambda_safe_source is None:
                self.lambda_safe_source = "given"

    @classmethod
    def for_rule(
        cls,
        rule: UpdateRule,
        *,
        lambda_safe: float | None = None,
        lambda_safe_source: str | None = None,
        premise_proven: bool = False,
        bounds: tuple[float, float] = (-0.5, 0.5),
        learn: bool = True,
    ) -> GuaranteeMonitor:
        """A monitor for ``rule``, which it resets (lambda_1 = ``rule.reset()``).

        With ``learn=False`` lambda stays at lambda_1 and no guarantee is computed (the
        losses are still averaged).

        Parameters
        ----------
        rule : UpdateRule
            The rule (reset here); its ``epsilon``, step and guarantee kind.
        lambda_safe : float, optional
            A lambda known or estimated to be safe (the Theorem-2 bound).
        lambda_safe_source : str, optional
            Where ``lambda_safe`` came from.
        premise_proven : bool
            lambda <= ``lambda_safe`` provably keeps the loss <= epsilon.
        bounds : (float, float)
            The loss's range.
        learn : bool
            False keeps lambda at lambda_1.
        """
        lam = rule.reset()
        return cls(
            epsilon=rule.epsilon,
            lambda_1=lam,
            eta=rule.step if learn else None,
            lambda_safe=lambda_safe,
            bounds=bounds,
            kind=rule.capabilities.guarantee if learn else "none",
            rule=rule if learn else None,
            lambda_safe_source=lambda_safe_source,
            premise_proven=premise_proven,
        )

    @property
    def lam(self) -> float:
        """The lambda to decide with now (lambda_1 before any update)."""
        return self.lambda_next if self.losses else self.lambda_1

    def update(self, loss: float) -> float:
        """Record l_k (decided with :attr:`lam`), update the rule, return lambda_{k+1}.

        Needs a monitor made by :meth:`for_rule` with ``learn=True``.
        """
        if self.rule is None:
            raise RuntimeError("update() needs a monitor made by GuaranteeMonitor.for_rule(rule)")
        self.observe(loss, self.lam)
        lam = self.rule.update(loss)
        self.set_lambda_next(lam, self.rule.last_step_)
        return lam

    # -- feeding ------------------------------------------------------------------------
    def observe(self, loss: float, lam: float) -> None:
        """Record l_k and the lambda_k it was computed with."""
        self.losses.append(float(loss))
        self.lambdas.append(float(lam))

    def set_lambda_next(self, lam: float, eta: float | None = None) -> None:
        """Record lambda_{k+1} after the update (and the step eta_k it used, if any)."""
        self.lambda_next = float(lam)
        if eta is None or not math.isfinite(eta):
            eta = self.eta if self.eta is not None else math.nan
        self.etas.append(float(eta))

    # -- figures ------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return len(self.losses)

    @property
    def average(self) -> float:
        """Running average loss (nan before the first loss)."""
        return math.fsum(self.losses) / self.n if self.n else math.nan

    @property
    def _has_identity(self) -> bool:
        return self.kind in ("identity", "step_identity")

    @property
    def identity_residual(self) -> float | None:
        """|sum eta_k (eps - l_k) - (lambda_{K+1} - lambda_1)| / sum eta_k, or None.

        For a fixed step: |mean loss - epsilon - (lambda_1 - lambda_{K+1})/(eta K)|.
        """
        if not self._has_identity or self.n == 0 or len(self.etas) != self.n:
            return None
        etas = np.asarray(self.etas)
        if not np.all(np.isfinite(etas)) or etas.sum() <= 0:
            return None
        if self.kind == "identity" and self.eta is not None and self.eta > 0:
            rhs = self.epsilon + (self.lambda_1 - self.lambda_next) / (self.eta * self.n)
            return abs(self.average - rhs)
        lhs = math.fsum(e * (self.epsilon - x) for e, x in zip(etas, self.losses, strict=True))
        return abs(lhs - (self.lambda_next - self.lambda_1)) / float(etas.sum())

    @property
    def bound(self) -> float | None:
        """Theorem-2 bound epsilon + (lambda_1 - lambda_safe + eta)/(eta K), if defined."""
        if (
            self.kind != "identity"
            or self.eta is None
            or self.eta <= 0
            or self.lambda_safe is None
            or self.n == 0
        ):
            return None
        return self.epsilon + (self.lambda_1 - self.lambda_safe + self.eta) / (self.eta * self.n)

    @property
    def bound_holds(self) -> bool | None:
        b = self.bound
        return None if b is None else bool(self.average <= b + _TOL)

    @property
    def bound_assumption(self) -> bool | None:
        """Whether Theorem 2's lambda_1 >= lambda_safe - eta (and, with clipping,
        lambda_min <= lambda_safe - eta) holds; None when no bound applies."""
        if self.bound is None:
            return None
        assert self.eta is not None and self.lambda_safe is not None
        ok = self.lambda_1 >= self.lambda_safe - self.eta - _TOL
        lam_min = self.rule.lambda_min if self.rule is not None else -math.inf
        return bool(ok and lam_min <= self.lambda_safe - self.eta + _TOL)

    @property
    def premise_tested(self) -> int:
        """Updates whose lambda_k <= lambda_safe (where the premise can be contradicted)."""
        if self.lambda_safe is None:
            return 0
        return int(sum(lam <= self.lambda_safe for lam in self.lambdas))

    @property
    def premise_violations(self) -> int:
        """Updates with lambda_k <= lambda_safe whose loss exceeded epsilon."""
        if self.lambda_safe is None:
            return 0
        ls = self.lambda_safe
        return int(
            sum(
                lam <= ls and x > self.epsilon + _TOL
                for lam, x in zip(self.lambdas, self.losses, strict=True)
            )
        )

    @property
    def verdict(self) -> Theorem2Verdict:
        """The monitor's reading of Theorem 2 (see :data:`Theorem2Verdict`)."""
        if self.bound is None:
            return "not_applicable"
        if not self.bound_holds:
            return "violated"
        if self.premise_violations:
            return "premise_fails"
        if not self.bound_assumption:
            return "assumption_fails"
        if not (self.premise_tested or self.premise_proven):
            return "premise_untested"
        return "holds"

    @property
    def long_run_bound(self) -> float | None:
        """The rule's bound on |mean loss - epsilon| after n updates, if it declares one."""
        if self.rule is None or self.n == 0 or self.kind == "none":
            return None
        return self.rule.long_run_bound(self.n, [*self.lambdas, self.lambda_next])

    @property
    def long_run_holds(self) -> bool | None:
        b = self.long_run_bound
        return None if b is None else bool(abs(self.average - self.epsilon) <= b + _TOL)

    def running_average(self) -> np.ndarray:
        """Average loss after each update, shape (n,)."""
        x = np.asarray(self.losses, dtype=float)
        return np.cumsum(x) / np.arange(1, x.size + 1) if x.size else x

    def bound_trace(self) -> np.ndarray | None:
        """Theorem-2 bound after each update (nan-free), or None when it does not apply."""
        if self.bound is None:
            return None
        assert self.eta is not None and self.lambda_safe is not None
        k = np.arange(1, self.n + 1)
        return self.epsilon + (self.lambda_1 - self.lambda_safe + self.eta) / (self.eta * k)

    def long_run_trace(self) -> np.ndarray | None:
        """The rule's long-run bound after each update, or None.

        With clipping, the clip term uses the whole run's total (a valid, looser bound at
        earlier updates).
        """
        if self.long_run_bound is None:
            return None
        assert self.rule is not None
        lam = [*self.lambdas, self.lambda_next]
        fn = self.rule.long_run_bound
        out = [fn(k, lam[: k + 1]) for k in range(1, self.n + 1)]
        return np.array([math.nan if b is None else b for b in out], dtype=float)

    def summary(self) -> dict[str, float | bool | int | str | None]:
        """Figures for metrics.json.

        ``theorem2_holds`` is True only when the verdict is ``"holds"`` (the bound met
        AND its premise tested without contradiction); ``theorem2_bound_met`` is the bare
        arithmetic comparison.
        """
        lr = self.long_run_bound
        verdict = self.verdict
        return {
            "guarantee": self.kind,
            "n_losses": self.n,
            "l_avg": self.average if self.n else None,
            "identity_residual": self.identity_residual,
            "lambda_safe": self.lambda_safe,
            "lambda_safe_source": self.lambda_safe_source,
            "theorem2_bound": self.bound,
            "theorem2_bound_met": self.bound_holds,
            "theorem2_assumption": self.bound_assumption,
            "theorem2_premise_tested": self.premise_tested if self.bound is not None else None,
            "theorem2_premise_violations": (
                self.premise_violations if self.bound is not None else None
            ),
            "theorem2_verdict": verdict,
            "theorem2_holds": None if self.bound is None else verdict == "holds",
            "long_run_bound": lr,
            "long_run_holds": self.long_run_holds,
            "n_lambda_clipped": int(self.rule.n_clipped_) if self.rule is not None else 0,
        }

    @property
    def n_clipped(self) -> int:
        """Updates whose lambda was clipped (0 without a rule)."""
        return int(self.rule.n_clipped_) if self.rule is not None else 0


#: Figures of :meth:`AgentMonitor.summary` per agent (lists, one entry per agent with at
#: least ``min_intervals`` losses): its number of losses, its average loss, its bound.
AGENT_FIGURES = ("agent_n", "agent_l_avg", "agent_bound")
#: Figures of :meth:`AgentMonitor.premise_figures` (counts; None without lambda_safe).
_PREMISE_FIGURES = (
    "n_agents_premise_tested",
    "n_agents_premise_failed",
    "n_premise_checks",
    "n_premise_exceeded",
    "n_agents_premise_exceeded",
)


@dataclass
class AgentMonitor:
    """lambda run per agent: one update rule and one :class:`GuaranteeMonitor` per key.

    The vector form of conformal decisions (``lambda_per="agent"``): agent j has its own
    entry lambda_j, which enters only agent j's part of the decision (its constraint row,
    its safe distance), and its own loss l_j,k (its term of the interval's loss, e.g.
    ``s(max_t gap_j(t) + lambda_j)``). Entry j is updated by its own copy of the run's
    rule from its own losses only, at the intervals where j was scored: each entry is the
    scalar rule on its own loss sequence, so every scalar statement holds per agent, with
    K_j (agent j's scored intervals) in place of K:

    * fixed step: mean_j(l) = epsilon + (lambda_j,1 - lambda_j,K_j+1) / (eta K_j) exactly,
      and, if lambda <= lambda_safe keeps agent j's loss <= epsilon (the gap loss: the
      paper's Theorem 3 bounds each agent's gap separately) and lambda_j,1 >=
      lambda_safe - eta, mean_j(l) <= epsilon + (lambda_j,1 - lambda_safe + eta) /
      (eta K_j) (Theorem 2, per agent);
    * pooled over the agents (every (agent, interval) loss, K = sum_j K_j): the average
      is the K_j-weighted mean of the agents' averages, so it is at most epsilon +
      sum_j (lambda_j,1 - lambda_safe + eta) / (eta K): the constant grows with the
      number of agents, the bound is loose when agents are seen for few intervals.

    Limits: an agent seen for K_j intervals has a bound of order 1/K_j (vacuous for a
    pedestrian passing in two intervals: the per-agent check counts only agents with at
    least ``min_intervals`` losses); the guarantee is about each agent's own average, not
    about the interval's largest term (the paper's loss), which can stay above epsilon
    while every agent's average meets it.

    A new agent starts at ``prior``, the quantile of the current lambda of the agents
    seen so far (lambda_1 of the rule while there is none): every entry stays >=
    lambda_safe - eta under Theorem 2's premise, so the prior keeps the per-agent
    assumption lambda_j,1 >= lambda_safe - eta. An agent that leaves keeps its entry
    (frozen: no loss, no update) and resumes with it if it is sensed again; its loss
    sequence simply continues.

    Parameters
    ----------
    rule : UpdateRule
        The run's rule: each agent gets a copy (same parameters, ``lambda_init`` = the
        prior); the rule itself is only reset (lambda_1, parameter validation).
    prior : float
        Quantile in [0, 1] of the current lambdas a new agent starts at (0: the most
        conservative entry, 0.5: the median).
    lambda_safe : float, optional
        A lambda known (or estimated) to be safe for every agent (Theorem 2 per agent).
    lambda_safe_source : str, optional
        Where ``lambda_safe`` came from.
    premise_proven : bool
        lambda <= ``lambda_safe`` provably keeps each agent's loss <= epsilon.
    bounds : tuple of float
        The loss's range.
    learn : bool
        False keeps every entry at its start (losses are still recorded).
    min_intervals : int
        Agents with at least this many losses are checked one by one (``summary``).
    row_floor : float
        Share in [0, 1] of each agent's own feasibility floor (the ``floors`` given to
        :meth:`update`) that may replace the rule's ``lambda_min`` for that agent: agent
        j's floor at an update is ``min(lambda_min, row_floor * floor_j)``, so lambda_j
        may go below the run's floor down to where its own row stops being satisfiable,
        and the run's floor binds only where a lower lambda_j would make that row
        infeasible. 0 (the default): the rule's ``lambda_min`` for every agent.
    floor_step : float
        Each agent's own floor that steps down while it binds (1/s, >= 0; 0, the default:
        off). Agent j's floor starts at the rule's ``lambda_min``; at an update whose
        lambda_j was decided at its floor (every expert of DtACI at it; within a relative
        1e-9) and whose loss exceeds
        epsilon -- the floor held lambda_j back and the agent was still missed -- the
        floor moves ``floor_step`` lower (not below ``floor_limit``) before the rule's
        update, so lambda_j can follow. A floor never rises again (an agent is seen for
        a few seconds). Applied before ``row_floor`` (which may lower it further).
    floor_limit : float
        The lowest floor ``floor_step`` reaches (1/s; default -inf: no limit); must not
        exceed the rule's ``lambda_min`` when ``floor_step`` is on.
    """

    rule: UpdateRule
    prior: float = 0.5
    lambda_safe: float | None = None
    lambda_safe_source: str | None = None
    premise_proven: bool = False
    bounds: tuple[float, float] = (-0.5, 0.5)
    learn: bool = True
    min_intervals: int = 10
    row_floor: float = 0.0
    floor_step: float = 0.0
    floor_limit: float = -math.inf
    entries: dict[int, GuaranteeMonitor] = field(default_factory=dict)
    #: (interval, key, loss) of every update, in order (the pooled running average);
    #: the interval counts the calls of :meth:`update` from 0.
    sequence: list[tuple[int, int, float]] = field(default_factory=list)
    #: Calls of :meth:`update` so far (intervals closed).
    n_intervals: int = 0
    #: With ``lambda_safe`` and a loss that re-evaluates an agent's loss at another lambda
    #: (``at``): per key, [losses re-evaluated at ``lambda_safe``, of those above epsilon]
    #: -- Theorem 2's premise checked at every interval, whatever lambda the agent had.
    safe_checks: dict[int, list[int]] = field(default_factory=dict)
    #: With ``row_floor``: updates whose agent's floor went below the rule's lambda_min
    #: (its own row allowed it), and of those, updates that ended at that lower floor.
    n_floor_lowered: int = 0
    n_floor_bound: int = 0
    #: With ``floor_step``: each agent's own floor (only agents whose floor moved), and
    #: the updates at which a floor stepped down.
    agent_floors: dict[int, float] = field(default_factory=dict)
    n_floor_stepped: int = 0

    def __post_init__(self) -> None:
        q = self.prior
        if isinstance(q, bool) or not isinstance(q, (int, float)) or not 0.0 <= q <= 1.0:
            raise ValueError(f"lambda_prior must be a quantile in [0, 1], got {q!r}")
        r = self.row_floor
        if (
            isinstance(r, bool)
            or not isinstance(r, (int, float))
            or not math.isfinite(r)
            or not 0.0 <= r <= 1.0
        ):
            raise ValueError(f"lambda_floor_row must be a share in [0, 1], got {r!r}")
        step, limit = self.floor_step, self.floor_limit
        if (
            isinstance(step, bool)
            or not isinstance(step, (int, float))
            or not math.isfinite(step)
            or step < 0.0
        ):
            raise ValueError(f"lambda_floor_step must be a finite rate >= 0, got {step!r}")
        if isinstance(limit, bool) or not isinstance(limit, (int, float)) or math.isnan(limit):
            raise ValueError(f"lambda_floor_limit must be a number or -inf, got {limit!r}")
        if int(self.min_intervals) != self.min_intervals or self.min_intervals < 1:
            raise ValueError(f"min_intervals must be an integer >= 1, got {self.min_intervals!r}")
        if "lambda_init" not in self.rule.get_params():
            raise ValueError(
                f"{type(self.rule).__name__} has no lambda_init: it cannot start an agent's "
                "entry at the prior, so lambda cannot be run per agent with it"
            )
        if self.lambda_safe is not None and self.lambda_safe_source is None:
            self.lambda_safe_source = "given"
        self.lambda_1 = float(self.rule.reset())  # validates the rule's parameters
        self.epsilon = float(self.rule.epsilon)
        #: the rule's own floor (each agent's, unless its row allows a lower one)
        self.lambda_min = float(self.rule.lambda_min)
        if step > 0.0 and limit > self.lambda_min:
            raise ValueError(
                f"lambda_floor_limit ({limit!r}) must not exceed lambda_min ({self.lambda_min!r}): "
                "the floor only steps down from lambda_min"
            )
        self.kind: GuaranteeKind = self.rule.capabilities.guarantee if self.learn else "none"
        self.eta = self.rule.step if self.learn else None

    @classmethod
    def for_rule(
        cls,
        rule: UpdateRule,
        *,
        prior: float = 0.5,
        lambda_safe: float | None = None,
        lambda_safe_source: str | None = None,
        premise_proven: bool = False,
        bounds: tuple[float, float] = (-0.5, 0.5),
        learn: bool = True,
        row_floor: float = 0.0,
        floor_step: float = 0.0,
        floor_limit: float = -math.inf,
    ) -> AgentMonitor:
        """A per-agent monitor for ``rule`` (which it resets); the arguments of
        :meth:`GuaranteeMonitor.for_rule`, and the ``prior`` of a new agent.

        Parameters
        ----------
        rule : UpdateRule
            The rule every agent gets a copy of.
        prior : float
            Quantile of the current lambdas a new agent starts at.
        lambda_safe : float, optional
            A lambda known or estimated to be safe (Theorem 2 per agent).
        lambda_safe_source : str, optional
            Where ``lambda_safe`` came from.
        premise_proven : bool
            lambda <= ``lambda_safe`` provably keeps each agent's loss <= epsilon.
        bounds : (float, float)
            The loss's range.
        learn : bool
            False keeps every entry at its start.
        row_floor : float
            Share of each agent's own feasibility floor that may replace ``lambda_min``.
        floor_step : float
            How far an agent's own floor steps down while it binds and the agent is missed
            (1/s; 0: off).
        floor_limit : float
            The lowest such floor (1/s).
        """
        return cls(
            rule,
            prior=prior,
            lambda_safe=lambda_safe,
            lambda_safe_source=lambda_safe_source,
            premise_proven=premise_proven,
            bounds=bounds,
            learn=learn,
            row_floor=row_floor,
            floor_step=floor_step,
            floor_limit=floor_limit,
        )

    # -- entries ------------------------------------------------------------------------
    def current(self) -> np.ndarray:
        """The current lambda of every agent seen, in the order they were first seen."""
        return np.array([m.lam for m in self.entries.values()], dtype=float)

    def prior_value(self) -> float:
        """The lambda a new agent starts at now: the ``prior`` quantile of :meth:`current`
        (lambda_1 while no agent has been seen), at least the rule's ``lambda_min`` (with
        ``row_floor`` other agents' entries can be below it; a new agent's own row is not
        known yet)."""
        lams = self.current()
        if not lams.size:
            return self.lambda_1
        return max(float(np.quantile(lams, self.prior)), self.lambda_min)

    @property
    def lam(self) -> float:
        """One number for "lambda now": :meth:`prior_value` (what a new agent gets)."""
        return self.prior_value()

    def _entry(self, key: int, start: float | None) -> GuaranteeMonitor:
        params = self.rule.get_params()
        if start is not None:  # None: the rule's own lambda_init (the first agents)
            params["lambda_init"] = start
        rule = type(self.rule)(**params)
        return GuaranteeMonitor.for_rule(
            rule,
            lambda_safe=self.lambda_safe,
            lambda_safe_source=self.lambda_safe_source,
            premise_proven=self.premise_proven,
            bounds=self.bounds,
            learn=self.learn,
        )

    def values(self, keys: Sequence[int] | np.ndarray) -> np.ndarray:
        """lambda of each key (an agent seen for the first time gets an entry at the
        prior; every new agent of one call gets the same prior), shape (len(keys),)."""
        keys = [int(k) for k in np.asarray(keys).ravel().tolist()]
        new = [k for k in dict.fromkeys(keys) if k not in self.entries]
        if new:
            start = self.prior_value() if self.entries else None
            for k in new:
                self.entries[k] = self._entry(k, start)
        return np.array([self.entries[k].lam for k in keys], dtype=float)

    def update(
        self,
        keys: Sequence[int] | np.ndarray,
        losses: Sequence[float] | np.ndarray,
        at: Callable[[int, float], float | None] | None = None,
        floors: Sequence[float] | np.ndarray | None = None,
    ) -> None:
        """Feed each key its loss (NaN: none this interval, no update) and update its entry.

        ``at(i, lam)`` re-evaluates key ``i``'s loss at another lambda (rules with
        ``uses_loss_function``; and, with ``lambda_safe``, the premise's check at every
        interval, :attr:`safe_checks`). ``floors`` (one per key, NaN: none) are the keys'
        own feasibility floors of the interval (the family's ``lambda_floors``), read
        with ``row_floor`` > 0: key i's update is clipped at ``min(lambda_min, row_floor
        * floors[i])``. A key must have been given an entry by :meth:`values`.

        Parameters
        ----------
        keys : sequence of int
            The agents scored this interval.
        losses : sequence of float
            Their losses (NaN: none).
        at : callable, optional
            ``at(i, lam)``: key i's loss at another lambda.
        floors : sequence of float, optional
            The keys' own feasibility floors of the interval (1/s; NaN: none).
        """
        keys = np.asarray(keys).ravel()
        losses = np.asarray(losses, dtype=float).ravel()
        if keys.shape != losses.shape:
            raise ValueError(f"{keys.size} keys but {losses.size} losses")
        own: np.ndarray | None = None
        if floors is not None and self.row_floor > 0.0:
            own = np.asarray(floors, dtype=float).ravel()
            if own.shape != keys.shape:
                raise ValueError(f"{keys.size} keys but {own.size} floors")
        for i, (key, loss) in enumerate(zip(keys.tolist(), losses.tolist(), strict=True)):
            if not math.isfinite(loss):
                continue
            mon = self.entries.get(int(key))
            if mon is None:
                raise KeyError(f"agent {key} was scored but has no lambda entry (see values())")
            lowered = math.nan
            if (self.row_floor > 0.0 or self.floor_step > 0.0) and mon.rule is not None:
                floor = self._own_floor(int(key), mon.lam, loss)
                if own is not None and math.isfinite(own[i]) and self.row_floor * own[i] < floor:
                    floor = lowered = float(self.row_floor * own[i])
                    self.n_floor_lowered += 1
                mon.rule.lambda_min = floor  # this agent's floor for this update only
            if self.lambda_safe is not None and at is not None:
                at_safe = at(i, self.lambda_safe)
                if at_safe is not None and math.isfinite(at_safe):
                    counts = self.safe_checks.setdefault(int(key), [0, 0])
                    counts[0] += 1
                    counts[1] += int(at_safe > self.epsilon + _TOL)
            if self.learn:
                if mon.rule is not None and mon.rule.capabilities.uses_loss_function:
                    mon.rule.set_loss_function(None if at is None else functools.partial(at, i))
                mon.update(loss)
                if mon.lam == lowered:
                    self.n_floor_bound += 1
            else:
                mon.observe(loss, mon.lam)
                mon.set_lambda_next(mon.lam)
            self.sequence.append((self.n_intervals, int(key), float(loss)))
        self.n_intervals += 1

    def _own_floor(self, key: int, lam: float, loss: float) -> float:
        """Agent ``key``'s floor for this update: the rule's ``lambda_min``, or with
        ``floor_step`` its own floor, stepped down first when lambda_j (``lam``, the value
        the interval was decided with) sat at it -- for a rule mixing experts (DtACI):
        every expert at it -- and ``loss`` exceeded epsilon."""
        floor = self.agent_floors.get(key, self.lambda_min)
        if self.floor_step > 0.0 and self.learn:
            at_floor = lam <= floor + 1e-9 * max(1.0, abs(floor))
            if at_floor and loss > self.epsilon and floor > self.floor_limit:
                floor = max(floor - self.floor_step, self.floor_limit)
                self.agent_floors[key] = floor
                self.n_floor_stepped += 1
        return floor

    # -- figures ------------------------------------------------------------------------
    @property
    def n(self) -> int:
        """Losses recorded, over every agent."""
        return len(self.sequence)

    @property
    def average(self) -> float:
        """Pooled average loss over every (agent, interval) loss (nan before any)."""
        return math.fsum(x for _, _, x in self.sequence) / self.n if self.n else math.nan

    @property
    def n_agents(self) -> int:
        """Agents with at least one loss."""
        return sum(1 for m in self.entries.values() if m.n)

    @property
    def n_clipped(self) -> int:
        """Updates clipped, over every agent."""
        return sum(m.n_clipped for m in self.entries.values())

    def _scored(self) -> list[GuaranteeMonitor]:
        return [m for m in self.entries.values() if m.n]

    def premise_figures(self) -> dict[str, int | None]:
        """Theorem 2's premise ("lambda <= lambda_safe keeps the loss <= epsilon") per agent,
        None without ``lambda_safe``:

        * ``n_agents_premise_tested``: agents with an update at lambda_j <= lambda_safe;
        * ``n_agents_premise_failed``: of those, agents with a loss > epsilon there;
        * ``n_premise_checks``: (agent, interval) losses re-evaluated at lambda_safe (the
          loss's ``at``; 0 when the loss cannot), and ``n_premise_exceeded`` of them above
          epsilon, in ``n_agents_premise_exceeded`` agents: the premise checked at every
          interval, with the decision the robot took.
        """
        if self.lambda_safe is None:
            return dict.fromkeys(_PREMISE_FIGURES)
        scored = self._scored()
        checks = list(self.safe_checks.values())
        return {
            "n_agents_premise_tested": sum(1 for m in scored if m.premise_tested),
            "n_agents_premise_failed": sum(1 for m in scored if m.premise_violations),
            "n_premise_checks": sum(c[0] for c in checks),
            "n_premise_exceeded": sum(c[1] for c in checks),
            "n_agents_premise_exceeded": sum(1 for c in checks if c[1]),
        }

    def agent_bound(self, mon: GuaranteeMonitor) -> float | None:
        """Agent ``mon``'s bound on its average loss: Theorem 2's with ``lambda_safe``, else
        epsilon + the rule's long-run bound, else None."""
        b = mon.bound
        if b is not None:
            return b
        lr = mon.long_run_bound
        return None if lr is None else self.epsilon + lr

    def agents(self, min_intervals: int | None = None) -> dict[str, np.ndarray]:
        """Per agent with at least ``min_intervals`` losses (default: the monitor's):
        ``key``, ``n`` (its losses), ``l_avg`` (its average loss), ``bound`` (its bound,
        NaN without one), ``lambda_1`` and ``lambda_last``."""
        k_min = self.min_intervals if min_intervals is None else int(min_intervals)
        items = [(k, m) for k, m in self.entries.items() if m.n >= k_min]
        bounds = [self.agent_bound(m) for _, m in items]
        return {
            "key": np.array([k for k, _ in items], dtype=np.int64),
            "n": np.array([m.n for _, m in items], dtype=np.int64),
            "l_avg": np.array([m.average for _, m in items], dtype=float),
            "bound": np.array([math.nan if b is None else b for b in bounds], dtype=float),
            "lambda_1": np.array([m.lambda_1 for _, m in items], dtype=float),
            "lambda_last": np.array([m.lam for _, m in items], dtype=float),
        }

    @property
    def identity_residual(self) -> float | None:
        """The largest identity residual over the agents (None: no identity applies)."""
        res = [r for m in self._scored() if (r := m.identity_residual) is not None]
        return max(res) if res else None

    @property
    def bound(self) -> float | None:
        """Pooled Theorem-2 bound epsilon + sum_j (lambda_j,1 - lambda_safe + eta) / (eta K)."""
        scored = self._scored()
        if (
            self.kind != "identity"
            or self.eta is None
            or self.eta <= 0
            or self.lambda_safe is None
            or not scored
        ):
            return None
        c = math.fsum(m.lambda_1 - self.lambda_safe + self.eta for m in scored)
        return self.epsilon + c / (self.eta * self.n)

    @property
    def bound_holds(self) -> bool | None:
        b = self.bound
        return None if b is None else bool(self.average <= b + _TOL)

    @property
    def long_run_bound(self) -> float | None:
        """Pooled long-run bound on |average - epsilon|: the K_j-weighted mean of the
        agents' bounds (None when an agent has none)."""
        if self.kind == "none":
            return None
        scored = self._scored()
        lrs = [m.long_run_bound for m in scored]
        if not scored or any(b is None for b in lrs):
            return None
        return math.fsum(m.n * float(b) for m, b in zip(scored, lrs, strict=True)) / self.n  # type: ignore[arg-type]  # None ruled out above

    @property
    def long_run_holds(self) -> bool | None:
        b = self.long_run_bound
        return None if b is None else bool(abs(self.average - self.epsilon) <= b + _TOL)

    @property
    def verdict(self) -> Theorem2Verdict:
        """Theorem 2 over the agents: ``"violated"`` if the pooled average or an agent's
        average exceeds its bound, else the first failing part among the agents (premise
        contradicted, assumption failing), ``"premise_untested"`` when no agent tested
        the premise, else ``"holds"``."""
        if self.bound is None:
            return "not_applicable"
        verdicts = {m.verdict for m in self._scored()}
        if not self.bound_holds or "violated" in verdicts:
            return "violated"
        if "premise_fails" in verdicts:
            return "premise_fails"
        if "assumption_fails" in verdicts:
            return "assumption_fails"
        if verdicts == {"premise_untested"}:
            return "premise_untested"
        return "holds"

    def history(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        """Agent ``key``'s updates: the intervals they closed (counted from 0) and the
        lambda each was decided with, both of shape (n_key,)."""
        ks = np.array([k for k, j, _ in self.sequence if j == key], dtype=np.int64)
        return ks, np.asarray(self.entries[key].lambdas, dtype=float)

    def running_average(self) -> np.ndarray:
        """Pooled average loss after each update, shape (n,)."""
        x = np.array([v for _, _, v in self.sequence], dtype=float)
        return np.cumsum(x) / np.arange(1, x.size + 1) if x.size else x

    def summary(self) -> dict[str, Any]:
        """Figures for metrics.json: :meth:`GuaranteeMonitor.summary`'s, pooled over the
        agents, and per agent (:data:`AGENT_FIGURES`, agents with at least
        ``min_intervals`` losses): the distribution the benchmark reports."""
        b = self.bound
        verdict = self.verdict
        scored = self._scored()
        per = self.agents()
        bound = per["bound"]
        has = np.isfinite(bound)
        met = per["l_avg"][has] <= bound[has] + _TOL
        return {
            "guarantee": self.kind,
            "lambda_per": "agent",
            "n_losses": self.n,
            "l_avg": self.average if self.n else None,
            "identity_residual": self.identity_residual,
            "lambda_safe": self.lambda_safe,
            "lambda_safe_source": self.lambda_safe_source,
            "theorem2_bound": b,
            "theorem2_bound_met": self.bound_holds,
            "theorem2_assumption": (
                None if b is None else all(bool(m.bound_assumption) for m in scored)
            ),
            "theorem2_premise_tested": (
                None if b is None else sum(m.premise_tested for m in scored)
            ),
            "theorem2_premise_violations": (
                None if b is None else sum(m.premise_violations for m in scored)
            ),
            "theorem2_verdict": verdict,
            "theorem2_holds": None if b is None else verdict == "holds",
            "long_run_bound": self.long_run_bound,
            "long_run_holds": self.long_run_holds,
            "n_lambda_clipped": self.n_clipped,
            "n_agents": self.n_agents,
            "n_agents_checked": int(per["n"].size),
            "n_agents_bound_met": int(met.sum()) if has.any() else None,
            **self.premise_figures(),
            "agent_min_intervals": int(self.min_intervals),
            "agent_n": per["n"].tolist(),
            "agent_l_avg": per["l_avg"].tolist(),
            "agent_bound": [None if not math.isfinite(x) else float(x) for x in bound.tolist()],
        }
