"""The flagship's roles as the RL environments use them: the action as the reference.

* :class:`GivenVelocity` -- a reference controller that returns the velocity it was last
  given: an RL policy's action takes the place of the attractive field, so the conformal
  CBF controller filters *the policy's* action.
* :class:`MonitorFilter` -- a "safety filter" that changes nothing: it returns the nominal
  velocity as it is and records whether it meets the conformal constraints. The
  environment's own conformal monitor uses it to score the actions the agent takes
  (constraint status, loss, lambda) without altering them.
* :class:`RecordingFilter` -- wraps any safety filter and keeps the rows, lambda and
  result of its last solve, which the shield reports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..families.cbf.roles import FilterResult, ReferenceController, SafetyFilter

__all__ = ["GivenVelocity", "LastSolve", "MonitorFilter", "RecordingFilter"]


class GivenVelocity(ReferenceController):
    """Reference velocity = the one set in :attr:`velocity` (m/s) before each decision."""

    def reset(self) -> None:
        self.velocity = np.zeros(2)

    def __call__(self, state: np.ndarray, t: float, goal: np.ndarray) -> np.ndarray:
        return np.array(self.velocity, dtype=float)


@dataclass
class LastSolve:
    """The last problem a filter solved: rows ``A v + b + lambda >= 0`` and its answer."""

    nominal: np.ndarray
    A: np.ndarray
    b: np.ndarray
    lam: float
    result: FilterResult

    def slack(self) -> np.ndarray:
        """``A v + b + lambda_applied`` at the returned decision (per row)."""
        lam = self.result.lambda_applied
        lam = self.lam if math.isnan(lam) else lam
        out: np.ndarray = self.A @ self.result.decision + self.b + lam
        return out


class MonitorFilter(SafetyFilter):
    """Returns the nominal velocity unchanged; records whether the constraints hold.

    The result's status is ``"unconstrained"`` when every row holds at lambda, otherwise
    ``"fallback"`` with fallback ``"unfiltered"`` and ``lambda_applied`` the smallest
    lambda at which the (unchanged) velocity meets every row -- what it did satisfy.
    """

    def reset(self) -> None:
        self.last_: LastSolve | None = None
        self.n_solves_ = 0
        self.n_violations_ = 0

    def solve(self, nominal: np.ndarray, A: np.ndarray, b: np.ndarray, lam: float) -> FilterResult:
        """``nominal`` unchanged, with the constraint violation counted (the monitor only
        watches).

        Parameters
        ----------
        nominal : ndarray of shape (2,)
            The reference decision (m/s).
        A : ndarray of shape (N, 2)
            One constraint row per agent: ``A v + b + lam >= 0``.
        b : ndarray of shape (N,)
            The rows' constant terms.
        lam : float
            The conformal slack lambda (1/s).
        """
        v = np.asarray(nominal, dtype=float)
        slack = A @ v + b + lam
        self.n_solves_ += 1
        if slack.size == 0 or slack.min() >= 0:
            res = FilterResult(v, "unconstrained", lam)
        else:
            self.n_violations_ += 1
            res = FilterResult(v, "fallback", float(lam - slack.min()), "unfiltered")
        self.last_ = LastSolve(v, A, b, lam, res)
        return res

    def solve_escaping(
        self,
        nominal: np.ndarray,
        A: np.ndarray,
        b: np.ndarray,
        lam: float,
        escape: Any,
        ttc: np.ndarray | None = None,
    ) -> FilterResult:
        """:meth:`solve`: the monitor changes nothing, not even next to an agent within the
        collision distance (the edge rule is a safety filter's; the environment applies the
        policy's action as it is, and a shield filters it).

        Parameters
        ----------
        nominal : ndarray of shape (2,)
            The reference decision (m/s).
        A : ndarray of shape (N, 2)
            One constraint row per agent.
        b : ndarray of shape (N,)
            The rows' constant terms.
        lam : float
            The conformal slack lambda (1/s).
        escape : EscapeRows or None
            The agents within the collision distance (not used).
        ttc : ndarray of shape (N,), optional
            The rows' times to contact (not used).
        """
        return self.solve(nominal, A, b, lam)

    def stats(self) -> dict[str, float]:
        return {"n_solves": self.n_solves_, "n_violations": self.n_violations_}


class RecordingFilter(SafetyFilter):
    """A safety filter that keeps what it last solved (for the shield's reports).

    Parameters
    ----------
    inner : SafetyFilter
        The filter doing the work.
    """

    def __init__(self, inner: SafetyFilter) -> None:
        self.inner = inner

    def reset(self) -> None:
        if not isinstance(self.inner, SafetyFilter):
            raise ValueError(f"inner must be a SafetyFilter, got {type(self.inner).__name__}")
        self.inner.reset()
        self.last_: LastSolve | None = None

    def solve(self, nominal: np.ndarray, A: np.ndarray, b: np.ndarray, lam: float) -> FilterResult:
        """The inner filter's solution, the problem and the result kept in ``last_``.

        Parameters
        ----------
        nominal : ndarray of shape (2,)
            The reference decision (m/s).
        A : ndarray of shape (N, 2)
            One constraint row per agent: ``A v + b + lam >= 0``.
        b : ndarray of shape (N,)
            The rows' constant terms.
        lam : float
            The conformal slack lambda (1/s).
        """
        res = self.inner.solve(nominal, A, b, lam)
        self.last_ = LastSolve(np.array(nominal, dtype=float), A.copy(), b.copy(), lam, res)
        return res

    def stats(self) -> dict[str, float]:
        return self.inner.stats()

    def __getattr__(self, name: str) -> Any:
        # parameters of the inner filter (v_max, fallback, ...) read through the wrapper
        if name.startswith("_") or name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)
