"""The velocity-level QP safety filter (piqp) and its feasibility fallbacks."""

from __future__ import annotations

import math

import numpy as np
import piqp

from ..base import FilterResult, SafetyFilter

__all__ = ["FALLBACKS", "QPSafetyFilter"]

#: Fallbacks used when the QP is infeasible at the requested lambda.
#: ``lambda_search`` (default, the paper's suggestion): use the smallest lambda at which
#: the constraints are feasible (found by one LP with lambda as a variable), then solve
#: the QP there. ``brake``: command zero velocity. ``hold``: repeat the previous decision.
FALLBACKS = ("lambda_search", "brake", "hold")


class QPSafetyFilter(SafetyFilter):
    """min ||v - v_ref||^2  s.t.  A v + b + lambda >= 0,  ||v|| <= v_max  (piqp).

    The speed bound is the polygon with ``speed_sides`` vertices inscribed in the disc
    of radius ``v_max`` (so every admissible v satisfies ||v|| <= v_max exactly), or the
    box ``|v_x|, |v_y| <= v_max`` with ``speed_sides=0``.

    When the nominal decision already satisfies every constraint it is returned without
    calling the solver (it is then the QP's optimum: all multipliers are zero).

    Parameters
    ----------
    v_max : float
        Speed bound (m/s).
    fallback : {"lambda_search", "brake", "hold"}
        What to do when the QP is infeasible at the requested lambda. Every use is counted
        in ``n_fallback_`` (and ``n_infeasible_``).
    speed_sides : int
        Number of sides of the speed polygon (>= 3), or 0 for a box.
    lambda_margin : float
        Relative margin added to the smallest feasible lambda so the QP is strictly
        feasible.
    """

    def __init__(
        self,
        v_max: float = 2.0,
        fallback: str = "lambda_search",
        speed_sides: int = 16,
        lambda_margin: float = 1e-6,
    ) -> None:
        self.v_max = v_max
        self.fallback = fallback
        self.speed_sides = speed_sides
        self.lambda_margin = lambda_margin

    def reset(self) -> None:
        if not (math.isfinite(self.v_max) and self.v_max > 0):
            raise ValueError(f"v_max must be a finite number > 0, got {self.v_max!r}")
        if self.fallback not in FALLBACKS:
            raise ValueError(f"fallback must be one of {FALLBACKS}, got {self.fallback!r}")
        if self.speed_sides != 0 and self.speed_sides < 3:
            raise ValueError(f"speed_sides must be 0 (box) or >= 3, got {self.speed_sides!r}")
        n = int(self.speed_sides)
        if n:
            ang = 2.0 * np.pi * (np.arange(n) + 0.5) / n
            self._S = np.column_stack([np.cos(ang), np.sin(ang)])
            self._s = np.full(n, self.v_max * math.cos(math.pi / n))
        else:
            self._S = np.zeros((0, 2))
            self._s = np.zeros(0)
        self._P = np.asfortranarray(2.0 * np.eye(2))
        self._solver: piqp.DenseSolver | None = None
        self._shape: tuple[int, int] | None = None
        self._last = np.zeros(2)
        self.n_solves_ = 0
        self.n_infeasible_ = 0
        self.n_fallback_ = 0

    # ------------------------------------------------------------------ internals
    def _box(self) -> dict[str, np.ndarray]:
        if self.speed_sides:
            return {}
        return {"x_l": np.full(2, -self.v_max), "x_u": np.full(2, self.v_max)}

    def _admissible(self, v: np.ndarray) -> bool:
        if self.speed_sides:
            return bool(np.all(self._S @ v <= self._s))
        return bool(np.all(np.abs(v) <= self.v_max))

    def _qp(self, nominal: np.ndarray, A: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
        """Solve min ||v - nominal||^2 s.t. -A v <= rhs and the speed bound."""
        G = np.asfortranarray(np.vstack([-A, self._S]))
        h_u = np.concatenate([rhs, self._s])
        c = -2.0 * nominal
        if self._solver is None or self._shape != G.shape:
            self._solver = piqp.DenseSolver()
            self._solver.settings.verbose = False
            self._solver.setup(P=self._P, c=c, G=G, h_u=h_u, **self._box())
            self._shape = G.shape
        else:
            self._solver.update(c=c, G=G, h_u=h_u)
        self.n_solves_ += 1
        status = self._solver.solve()
        if status == piqp.PIQP_SOLVED:
            return np.array(self._solver.result.x, dtype=float)
        return None

    def smallest_feasible_lambda(self, A: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
        """min lambda s.t. there is an admissible v with A v + b + lambda >= 0 (one LP).

        Returns the minimal lambda and the velocity attaining it.
        """
        m = A.shape[0]
        G = np.asfortranarray(
            np.vstack(
                [
                    np.hstack([-A, -np.ones((m, 1))]),
                    np.hstack([self._S, np.zeros((self._S.shape[0], 1))]),
                ]
            )
        )
        h_u = np.concatenate([b, self._s])
        c = np.array([0.0, 0.0, 1.0])
        P = np.asfortranarray(np.diag([1e-9, 1e-9, 0.0]))
        solver = piqp.DenseSolver()
        solver.settings.verbose = False
        box = {}
        if not self.speed_sides:
            box = {
                "x_l": np.array([-self.v_max, -self.v_max, -np.inf]),
                "x_u": np.array([self.v_max, self.v_max, np.inf]),
            }
        solver.setup(P=P, c=c, G=G, h_u=h_u, **box)
        self.n_solves_ += 1
        status = solver.solve()
        if status != piqp.PIQP_SOLVED:  # pragma: no cover - LP is always feasible & bounded
            raise RuntimeError(f"feasibility LP failed with status {status}")
        x = np.array(solver.result.x, dtype=float)
        # the LP optimum is attained where the worst row is tight: recompute exactly
        lam_star = float(np.max(-(A @ x[:2]) - b))
        return lam_star, x[:2]

    # ------------------------------------------------------------------ API
    def solve(self, nominal: np.ndarray, A: np.ndarray, b: np.ndarray, lam: float) -> FilterResult:
        nominal = np.asarray(nominal, dtype=float)
        if not (np.all(np.isfinite(A)) and np.all(np.isfinite(b)) and math.isfinite(lam)):
            raise ValueError(
                "QPSafetyFilter received non-finite constraints or lambda; predictions must be "
                "sanitised before building constraints"
            )
        if not np.all(np.isfinite(nominal)):
            raise ValueError(f"QPSafetyFilter received a non-finite nominal decision {nominal}")
        rhs = b + lam
        if self._admissible(nominal) and (A.shape[0] == 0 or np.all(A @ nominal + rhs >= 0)):
            self._last = nominal
            return FilterResult(nominal, "unconstrained", lam)
        v = self._qp(nominal, A, rhs)
        if v is not None:
            self._last = v
            return FilterResult(v, "optimal", lam)
        # infeasible at lambda (or a numerical failure): counted fallback
        self.n_infeasible_ += 1
        self.n_fallback_ += 1
        if self.fallback == "brake":
            self._last = np.zeros(2)
            return FilterResult(self._last, "fallback", math.nan, "brake")
        if self.fallback == "hold":
            return FilterResult(self._last.copy(), "fallback", math.nan, "hold")
        lam_star, v_star = self.smallest_feasible_lambda(A, b)
        lam_used = max(lam, lam_star) + self.lambda_margin * max(1.0, abs(lam_star))
        v = self._qp(nominal, A, b + lam_used)
        if v is None:  # pragma: no cover - strictly feasible by construction
            v, lam_used = v_star, lam_star
        self._last = v
        return FilterResult(v, "fallback", lam_used, "lambda_search")
