"""Fallbacks: what a safety filter does when its rows are infeasible at the requested lambda.

Each is a :class:`~conformal_control.families.cbf.roles.Fallback` plugin (role ``fallback``, entry
points ``conformal_control.fallbacks``); a safety filter takes one as an instance or by
registered name (``fallback="relax"``).

================  =====================================================================
``lambda_search``  the smallest lambda at which the rows are feasible (one LP with lambda
                   as a variable), then the projection there: the ONE shared lambda is
                   raised for every row (default, the paper's suggestion)
``relax``          one slack per row: the minimal weighted relaxation, then the projection
                   there; only the rows that must be relaxed are (per-row lambda)
``brake``          zero velocity (meets the rows at no particular lambda)
``hold``           the previous decision again
``goal_aware``     the rows of the most imminent agents (smallest predicted time to
                   contact), as many as can be met at lambda, and among the commands
                   meeting them the one that makes the most progress toward the goal
================  =====================================================================

Within the edge rule's escape polygon (an agent already within the collision distance,
:class:`~conformal_control.families.cbf.roles.EscapeRows`) every fallback decides among the
commands of that polygon: the filter's primitives work in it, and a decision leaving it is
projected onto it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...core import registry
from .reciprocal import lexicographic_search
from .roles import Fallback, FilterPrimitives, FilterResult, InfeasibleStep

__all__ = ["Brake", "GoalAware", "Hold", "LambdaSearch", "Relax", "resolve_fallback"]


class LambdaSearch(Fallback, compiled="lambda_search"):
    """Raise lambda to the smallest feasible value (plus the solver's margin) and project.

    ``lambda_applied`` is the lambda actually used, ``lambda* + margin`` with the margin the
    filter's solver needs to find the rows feasible (:meth:`FilterPrimitives.search_margin`);
    every row holds there. Should the projection fail there (a solver stopping a tolerance
    inside a thin feasible set), it is retried at 10 and 100 times the margin (counted as
    ``n_lambda_search_retry``); should it still fail, the LP's own velocity, which meets
    every row at ``lambda*``, is returned (counted as ``n_lambda_search_vertex``).
    """

    name = "lambda_search"

    def decide(self, step: InfeasibleStep, solver: FilterPrimitives) -> FilterResult:
        lam_star, v_star = step.lam_star, step.v_star
        if lam_star is None or v_star is None:
            lam_star, v_star = solver.min_lambda(step.A, step.b)
        lam_floor = max(step.lam, lam_star)
        margin = solver.search_margin(lam_floor, step.A, step.b)
        for attempt in range(3):
            lam_used = lam_floor + margin * 10.0**attempt
            v = solver.project(step.nominal, step.A, step.b + lam_used)
            if v is not None:
                if attempt:
                    solver.count("lambda_search_retry")
                return FilterResult(v, "fallback", lam_used, self.name)
        solver.count("lambda_search_vertex")
        return FilterResult(np.array(v_star, dtype=float), "fallback", lam_floor, self.name)


class Relax(Fallback):
    """Relax only the rows that must be relaxed: one slack per row, minimal weighted sum.

    Lexicographic: first the minimal weighted relaxation (an LP)::

        s* = argmin  sum_j w_j s_j   s.t.  A v + b + lam + s >= 0,  s >= 0,  v admissible

    then the velocity closest to the nominal at that relaxation (the filter's QP with the
    rows ``A v + b + lam + s* >= 0``). When the minimal relaxation is not unique the
    decision is the projection at the LP's own optimum ``s*``: every row is then relaxed by
    no more than ``s*_j``, so the decision still has the minimal weighted relaxation.

    A row in no infeasible subsystem (one that can be met together with the others) keeps
    ``s_j = 0``: at any optimum of the weighted relaxation a positive slack forces the row's
    dual multiplier to its weight, which only an infeasible subsystem's certificate can
    carry. :attr:`FilterResult.row_lambda` is ``lam + s``; ``lambda_applied`` its maximum.

    Parameters
    ----------
    weights : {"uniform", "inverse_gradient"}
        ``w_j = 1``, or ``w_j = 1 / max(||A_j||, gradient_floor)`` (relaxing a row with a
        steep barrier gradient costs less: its slack is a smaller change of velocity).
    gradient_floor : float
        Floor of ``||A_j||`` for ``"inverse_gradient"`` (> 0).
    """

    name = "relax"

    def __init__(self, weights: str = "uniform", gradient_floor: float = 1e-3) -> None:
        self.weights = weights
        self.gradient_floor = gradient_floor

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{}, {"weights": "inverse_gradient"}]

    def reset(self) -> None:
        if self.weights not in ("uniform", "inverse_gradient"):
            raise ValueError(
                f"weights must be 'uniform' or 'inverse_gradient', got {self.weights!r}"
            )
        if not (math.isfinite(self.gradient_floor) and self.gradient_floor > 0):
            raise ValueError(
                f"gradient_floor must be a finite number > 0, got {self.gradient_floor!r}"
            )

    def row_weights(self, A: np.ndarray) -> np.ndarray:
        """The weight of each row."""
        if self.weights == "uniform":
            return np.ones(A.shape[0])
        w: np.ndarray = 1.0 / np.maximum(np.hypot(A[:, 0], A[:, 1]), self.gradient_floor)
        return w

    def decide(self, step: InfeasibleStep, solver: FilterPrimitives) -> FilterResult:
        rhs = step.b + step.lam
        v, s = solver.project_relaxed(step.nominal, step.A, rhs, self.row_weights(step.A))
        row_lambda = step.lam + s
        lam_max = float(row_lambda.max()) if row_lambda.size else step.lam
        return FilterResult(v, "fallback", lam_max, self.name, row_lambda)


class Brake(Fallback, compiled="brake"):
    """Command zero velocity (``lambda_applied`` is ``nan``: no lambda is guaranteed)."""

    name = "brake"

    def decide(self, step: InfeasibleStep, solver: FilterPrimitives) -> FilterResult:
        return FilterResult(np.zeros(2), "fallback", math.nan, self.name)


class Hold(Fallback, compiled="hold"):
    """Repeat the previous decision (``lambda_applied`` is ``nan``)."""

    name = "hold"

    def decide(self, step: InfeasibleStep, solver: FilterPrimitives) -> FilterResult:
        return FilterResult(np.array(step.previous, dtype=float), "fallback", math.nan, self.name)


class GoalAware(Fallback):
    """Meet the rows of the most imminent agents; among those commands, head for the goal.

    The rows are ordered by the agents' predicted time to contact
    (:attr:`InfeasibleStep.ttc`: when each would reach the collision distance of the robot
    moving at its nominal velocity; ties and rows without one, by how far standing still
    violates them). The
    largest prefix of that order whose rows can all be met at the requested lambda is
    found by bisection on the projection's feasibility (monotone in the prefix); when even
    the most imminent row cannot be met there, lambda is raised for the prefix only, to
    that row's smallest feasible lambda (plus the solver's margin). The decision is the
    command meeting the prefix that makes the most progress toward the goal: the
    projection onto its rows of a point 1 km/s along the nominal velocity (the reference
    points at the goal; with a zero nominal, the projection of 0). The other rows --
    agents that are not imminent -- are, with ``rest="relaxed"`` (default), met at the
    smallest common lambda the prefix allows (the lexicographic search of
    :func:`~conformal_control.families.cbf.reciprocal.lexicographic_search`, the prefix kept at its
    level), the projection then taken there; with ``rest="dropped"``, not met at all.
    Where ``lambda_search`` raises every row alike and returns the command closest to the
    nominal there, this keeps the most imminent agents' rows as they are and heads for the
    goal. :attr:`FilterResult.row_lambda` is, per row, the lambda that row satisfies at
    the decision; ``lambda_applied`` its maximum.

    Parameters
    ----------
    rest : {"relaxed", "dropped"}
        What becomes of the rows after the prefix.
    """

    name = "goal_aware"

    #: Speed (m/s) of the point along the nominal velocity that is projected: far beyond
    #: any speed set, so the projection is the most progress along it.
    REACH = 1000.0

    def __init__(self, rest: str = "relaxed") -> None:
        self.rest = rest

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{}, {"rest": "dropped"}]

    def reset(self) -> None:
        if self.rest not in ("relaxed", "dropped"):
            raise ValueError(f"rest must be 'relaxed' or 'dropped', got {self.rest!r}")

    def decide(self, step: InfeasibleStep, solver: FilterPrimitives) -> FilterResult:
        A, b, lam = step.A, step.b, step.lam
        m = A.shape[0]
        nominal = np.asarray(step.nominal, dtype=float)
        speed = float(np.hypot(nominal[0], nominal[1]))
        target = nominal * (self.REACH / speed) if speed > 0.0 else np.zeros(2)
        ttc = step.ttc
        if ttc is None or np.shape(ttc) != (m,):
            ttc = np.full(m, math.inf)
        order = np.lexsort((b, np.asarray(ttc, dtype=float)))

        def at(k: int, level: float) -> np.ndarray | None:
            idx = order[:k]
            out: np.ndarray | None = solver.project(target, A[idx], b[idx] + level)
            return out

        level = lam
        v = at(1, level) if m else solver.project(target, A, b + lam)
        if v is None:  # the most imminent row alone: its own smallest lambda
            first = order[:1]
            star, _ = solver.min_lambda(A[first], b[first])
            level = max(lam, float(star))
            level += solver.search_margin(level, A[first], b[first])
            v = at(1, level)
            if v is None:  # (round-off) the row at ten times the margin
                level += 9.0 * solver.search_margin(level, A[first], b[first])
                v = at(1, level)
        if v is None:  # the row cannot be met at all within the speed set: brake
            return FilterResult(np.zeros(2), "fallback", math.nan, self.name)
        lo, hi = 1, m  # at(lo) feasible; find the largest feasible prefix
        best = v
        while lo < hi:
            mid = (lo + hi + 1) // 2
            w = at(mid, level)
            if w is None:
                hi = mid - 1
            else:
                lo, best = mid, w
        if lo < m and self.rest == "relaxed":
            # the other rows at the smallest common lambda the prefix (at `level`) allows
            hard = np.zeros(m, dtype=bool)
            hard[order[:lo]] = True
            w, _, _ = lexicographic_search(solver, target, A, b, hard, level, keep=True)
            if w is not None and np.all(np.isfinite(w)):
                best = np.asarray(w, dtype=float)
        row_lambda = np.maximum(-(A @ best + b), level) if m else np.zeros(0)
        applied = float(row_lambda.max()) if m else lam
        return FilterResult(best, "fallback", applied, self.name, row_lambda)


def resolve_fallback(fallback: str | Fallback) -> Fallback:
    """A fresh :class:`Fallback` from a registered name (the ``fallback`` role: the core
    ones and any third-party one, all through the registry), or the instance itself."""
    if isinstance(fallback, Fallback):
        return fallback
    if not isinstance(fallback, str):
        raise TypeError(
            f"fallback must be a Fallback instance or a registered name, got {fallback!r}"
        )
    created: Fallback = registry.create("fallback", fallback)
    return created
