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
``guarantee`` kind (see :mod:`conformal_control.update_rules`).

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

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .base import GuaranteeKind, UpdateRule

__all__ = ["GuaranteeMonitor", "Theorem2Verdict"]

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
