"""The velocity-level QP safety filter (piqp) and its feasibility fallbacks."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import piqp

from .roles import FilterResult, SafetyFilter

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

    When the nominal decision already satisfies every conformal constraint and the speed
    bound ``||v|| <= v_max`` it is returned without calling the solver (it is then the
    optimum of the QP with the exact disc: all multipliers are zero). Otherwise the QP
    uses the polygon, so a filtered decision may be up to ``1 - cos(pi / speed_sides)``
    (2 % for 16 sides) slower than ``v_max`` in the worst direction.

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

    @classmethod
    def _unit_test_params(cls) -> list[dict]:
        return [{}, {"fallback": "brake", "speed_sides": 0}, {"fallback": "hold", "v_max": 1.0}]

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
        self._shape: int | None = None
        self._last = np.zeros(2)
        self._lp: piqp.DenseSolver | None = None
        self._lp_shape: int | None = None
        self._fell_back = False
        self.n_solves_ = 0
        self.n_infeasible_ = 0
        self.n_fallback_ = 0

    # ------------------------------------------------------------------ internals
    def _box(self) -> dict[str, np.ndarray]:
        if self.speed_sides:
            return {}
        return {"x_l": np.full(2, -self.v_max), "x_u": np.full(2, self.v_max)}

    def _admissible(self, v: np.ndarray) -> bool:
        """Whether v meets the speed bound itself (the disc for the polygon: the polygon
        is only the QP's linear stand-in for it, so a nominal decision inside the disc is
        returned unchanged)."""
        if self.speed_sides:
            return v[0] * v[0] + v[1] * v[1] <= self.v_max * self.v_max * (1.0 + 1e-12)
        return abs(v[0]) <= self.v_max and abs(v[1]) <= self.v_max

    def _qp(self, nominal: np.ndarray, A: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
        """Solve min ||v - nominal||^2 s.t. -A v <= rhs and the speed bound."""
        m = A.shape[0]
        if self._solver is None or self._shape != m:
            # buffers sized for m conformal rows + the constant speed-polygon rows
            self._G = np.asfortranarray(np.vstack([np.zeros((m, 2)), self._S]))
            self._h = np.concatenate([np.zeros(m), self._s])
            np.negative(A, out=self._G[:m])
            self._h[:m] = rhs
            self._solver = piqp.DenseSolver()
            self._solver.settings.verbose = False
            self._solver.setup(P=self._P, c=-2.0 * nominal, G=self._G, h_u=self._h, **self._box())
            self._shape = m
        else:
            np.negative(A, out=self._G[:m])
            self._h[:m] = rhs
            self._solver.update(c=-2.0 * nominal, G=self._G, h_u=self._h)
        self.n_solves_ += 1
        status = self._solver.solve()
        if status == piqp.PIQP_SOLVED:
            return np.array(self._solver.result.x, dtype=float)
        return None

    def smallest_feasible_lambda(self, A: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
        """min lambda s.t. there is an admissible v with A v + b + lambda >= 0 (one LP).

        Solved with piqp in the variables (v, lambda). Returns the minimal lambda and the
        velocity attaining it.
        """
        m = A.shape[0]
        if self._lp is None or self._lp_shape != m:
            ns = self._S.shape[0]
            self._lp_G = np.asfortranarray(np.zeros((m + ns, 3)))
            self._lp_G[:m, 2] = -1.0
            self._lp_G[m:, :2] = self._S
            self._lp_h = np.concatenate([np.zeros(m), self._s])
            self._lp_G[:m, :2] = -A
            self._lp_h[:m] = b
            box = {}
            if not self.speed_sides:
                box = {
                    "x_l": np.array([-self.v_max, -self.v_max, -np.inf]),
                    "x_u": np.array([self.v_max, self.v_max, np.inf]),
                }
            self._lp = piqp.DenseSolver()
            self._lp.settings.verbose = False
            self._lp.setup(
                P=np.asfortranarray(np.diag([1e-9, 1e-9, 0.0])),
                c=np.array([0.0, 0.0, 1.0]),
                G=self._lp_G,
                h_u=self._lp_h,
                **box,
            )
            self._lp_shape = m
        else:
            self._lp_G[:m, :2] = -A
            self._lp_h[:m] = b
            self._lp.update(G=self._lp_G, h_u=self._lp_h)
        self.n_solves_ += 1
        status = self._lp.solve()
        if status != piqp.PIQP_SOLVED:  # pragma: no cover - LP is always feasible & bounded
            raise RuntimeError(f"feasibility LP failed with status {status}")
        v = np.array(self._lp.result.x[:2], dtype=float)
        # the optimum is where the worst row is tight: recompute lambda exactly at v
        return float(np.max(-(A @ v) - b)), v

    # ------------------------------------------------------------------ API
    def solve(self, nominal: np.ndarray, A: np.ndarray, b: np.ndarray, lam: float) -> FilterResult:
        nominal = np.asarray(nominal, dtype=float)
        rhs = b + lam
        slack = A @ nominal + rhs
        # one finiteness test covers A, b, lam and the nominal decision (NaN/inf propagate)
        if not (math.isfinite(slack.sum()) and math.isfinite(nominal[0] + nominal[1])):
            raise ValueError(
                "QPSafetyFilter received non-finite constraints, lambda or nominal decision; "
                "predictions must be sanitised before building constraints"
            )
        if (slack.size == 0 or slack.min() >= 0) and self._admissible(nominal):
            self._last = nominal
            self._fell_back = False
            return FilterResult(nominal, "unconstrained", lam)
        lam_star = v_star = None
        if self._fell_back and self.fallback == "lambda_search":
            # infeasibility tends to persist: find the floor first, skip a doomed QP
            lam_star, v_star = self.smallest_feasible_lambda(A, b)
        if lam_star is None or lam >= lam_star + self._margin(lam_star):
            v = self._qp(nominal, A, rhs)
            if v is not None:
                self._last = v
                self._fell_back = False
                return FilterResult(v, "optimal", lam)
        # infeasible at lambda (or a numerical failure): counted fallback
        self.n_infeasible_ += 1
        self.n_fallback_ += 1
        self._fell_back = True
        if self.fallback == "brake":
            self._last = np.zeros(2)
            return FilterResult(self._last, "fallback", math.nan, "brake")
        if self.fallback == "hold":
            return FilterResult(self._last.copy(), "fallback", math.nan, "hold")
        if lam_star is None:
            lam_star, v_star = self.smallest_feasible_lambda(A, b)
        lam_used = max(lam, lam_star) + self._margin(lam_star)
        v = self._qp(nominal, A, b + lam_used)
        if v is None:  # pragma: no cover - strictly feasible by construction
            v, lam_used = v_star, lam_star
        self._last = v
        return FilterResult(v, "fallback", lam_used, "lambda_search")

    def __getstate__(self) -> dict[str, Any]:
        # piqp solvers cannot be pickled: drop them, they are rebuilt on the next solve
        state = self.__dict__.copy()
        for name in ("_solver", "_lp", "_shape", "_lp_shape"):
            if name in state:
                state[name] = None
        return state

    def stats(self) -> dict[str, float]:
        return {
            "n_solves": self.n_solves_,
            "n_infeasible": self.n_infeasible_,
            "n_fallback": self.n_fallback_,
        }

    def _margin(self, lam_star: float) -> float:
        return self.lambda_margin * max(1.0, abs(lam_star))
