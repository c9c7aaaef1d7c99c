"""The piqp backend: the general QP safety filter and the reference for the others.

piqp (a proximal interior-point solver) solves the projection QP and the lambda LP. Its
rows are presolved for scale (:func:`normalised_rows`): rows met everywhere in the disc
around the speed set are dropped, the others normalised to unit gradient, so predictions
offset by 1e10 m or scaled down to 1e-10 m give the same, well-scaled problems. A solver
status other than solved / primal infeasible is retried once with a fresh solver (no warm
start); if that fails too the exact 2-D solver answers, counted as ``n_solver_failure``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import piqp

from ..roles import Fallback
from .base import VelocityFilter

__all__ = ["QPSafetyFilter", "normalised_rows"]


def normalised_rows(
    A: np.ndarray, rhs: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Rows ``A v + rhs >= 0`` as unit-gradient ``G v <= h``, without the rows every v in
    the disc of radius ``radius`` meets; None if a row is met by no v in that disc."""
    nrm = np.hypot(A[:, 0], A[:, 1])
    reach = nrm * radius
    if np.any(rhs + reach < 0.0):
        return None
    keep = rhs < reach
    if not keep.any():
        return np.zeros((0, 2)), np.zeros(0)
    n = nrm[keep]
    return -A[keep] / n[:, None], rhs[keep] / n


class QPSafetyFilter(VelocityFilter, probe_floor_first=True):
    """min ||v - v_ref||^2  s.t.  A v + b + lambda >= 0,  v in the speed polygon  (piqp).

    The problem, the fast path, the fallbacks and the counters are those of
    :class:`~conformal_control.families.cbf.filters.base.VelocityFilter`.

    Parameters
    ----------
    v_max : float
        Speed bound (m/s).
    fallback : str or Fallback
        Fallback when the rows are infeasible at the requested lambda (default
        ``"lambda_search"``).
    speed_sides : int
        Number of sides of the speed polygon (>= 3), or 0 for a box.
    lambda_margin : float
        Margin added to the smallest feasible lambda so the QP is strictly feasible,
        relative to the rows' scale ``max(1, |lambda*|, |b_j|, ||A_j|| v_max)``: 10 times
        piqp's tolerance (a thinner feasible set may be called infeasible; the fallback then
        retries at 10 and 100 times the margin).
    eps : float
        piqp's absolute and relative tolerances (``eps_abs``, ``eps_rel``).
    polish : bool
        Polish piqp's solution on the constraints its multipliers mark active (exact KKT
        solve, kept only if primal feasible with non-negative multipliers); piqp alone
        stops up to about 1e-5 m/s inside the active constraints. Failures to polish are
        counted as ``n_unpolished``.
    """

    def __init__(
        self,
        v_max: float = 2.0,
        fallback: str | Fallback = "lambda_search",
        speed_sides: int = 16,
        lambda_margin: float = 1e-8,
        eps: float = 1e-9,
        polish: bool = True,
    ) -> None:
        super().__init__(v_max=v_max, fallback=fallback, speed_sides=speed_sides)
        self.lambda_margin = lambda_margin
        self.eps = eps
        self.polish = polish

    def _setup(self) -> None:
        if not (math.isfinite(self.lambda_margin) and self.lambda_margin > 0):
            raise ValueError(
                f"lambda_margin must be a finite number > 0, got {self.lambda_margin!r}"
            )
        if not (math.isfinite(self.eps) and 0 < self.eps < 1e-3):
            raise ValueError(f"eps must be a number in (0, 1e-3), got {self.eps!r}")
        self._P = np.asfortranarray(2.0 * np.eye(2))
        self._qp_solver: piqp.DenseSolver | None = None
        self._qp_shape: int | None = None
        self._lp_solver: piqp.DenseSolver | None = None
        self._lp_shape: int | None = None

    def _polygon_changed(self) -> None:
        # the set-ups hold the speed set's rows: built afresh on the next solve
        self._qp_solver = None
        self._lp_solver = None

    def __getstate__(self) -> dict[str, Any]:
        # piqp solvers cannot be pickled: drop them, they are rebuilt on the next solve
        state = self.__dict__.copy()
        for name in ("_qp_solver", "_qp_shape", "_lp_solver", "_lp_shape"):
            if name in state:
                state[name] = None
        return state

    def search_margin(self, lam_star: float, A: np.ndarray, b: np.ndarray) -> float:
        scale = max(1.0, abs(lam_star))
        if A.shape[0]:
            # sqrt(2) max|A_ij| >= max ||A_j||: the rows' scale without a norm per row
            scale = max(scale, float(np.abs(b).max()), float(np.abs(A).max()) * 1.5 * self._radius)
        return self.lambda_margin * scale

    # ------------------------------------------------------------------ solver plumbing
    def _new_solver(self) -> piqp.DenseSolver:
        solver = piqp.DenseSolver()
        solver.settings.verbose = False
        solver.settings.eps_abs = self.eps
        solver.settings.eps_rel = self.eps
        return solver

    @staticmethod
    def _capacity(m: int) -> int:
        """Rows the solver is set up for: the next power of two (>= 4), so a changing number
        of sensed agents rarely needs a new set-up; unused rows read ``0 v <= 1``."""
        return max(4, 1 << max(m - 1, 0).bit_length())

    def _run_qp(
        self, nominal: np.ndarray, G: np.ndarray, h: np.ndarray, fresh: bool
    ) -> piqp.Status:
        m = G.shape[0]
        cap = self._capacity(m)
        self._qp_m = m
        c = -2.0 * nominal
        if fresh or self._qp_solver is None or self._qp_shape != cap:
            self._qp_G = np.asfortranarray(np.vstack([np.zeros((cap, 2)), self._S]))
            self._qp_h = np.concatenate([np.ones(cap), self._s])
            self._qp_G[:m] = G
            self._qp_h[:m] = h
            self._qp_solver = self._new_solver()
            self._qp_solver.setup(P=self._P, c=c, G=self._qp_G, h_u=self._qp_h)
            self._qp_shape = cap
        else:
            self._qp_G[:m] = G
            self._qp_G[m:cap] = 0.0
            self._qp_h[:m] = h
            self._qp_h[m:cap] = 1.0
            self._qp_solver.update(c=c, G=self._qp_G, h_u=self._qp_h)
        self.n_solves_ += 1
        return self._qp_solver.solve()

    def project(self, nominal: np.ndarray, A: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
        rows = normalised_rows(A, rhs, self._radius)
        if rows is None:
            return None
        G, h = rows
        status = self._run_qp(nominal, G, h, fresh=False)
        if status not in (piqp.PIQP_SOLVED, piqp.PIQP_PRIMAL_INFEASIBLE):
            status = self._run_qp(nominal, G, h, fresh=True)  # stale warm start
        if status == piqp.PIQP_SOLVED:
            assert self._qp_solver is not None  # _run_qp has set it up
            x = np.array(self._qp_solver.result.x, dtype=float)
            if self.polish:
                x = self._polish(nominal, x, np.asarray(self._qp_solver.result.z_u))
            return x
        if status == piqp.PIQP_PRIMAL_INFEASIBLE:
            return None
        return self._exact_project(nominal, G, h)

    def _polish(self, nominal: np.ndarray, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Active-set polish (as OSQP does): the constraints piqp's multipliers mark active
        are solved as equalities; the result replaces piqp's iterate if it is primal
        feasible to round-off with non-negative multipliers, otherwise piqp's is kept."""
        G, h = self._qp_G, self._qp_h
        z = z.copy()
        z[self._qp_m : self._qp_shape] = 0.0  # padding rows 0 v <= 1
        i = int(z.argmax())
        zi = float(z[i])
        if zi <= 0.0:
            return x
        z[i] = 0.0
        j = int(z.argmax())
        n0, n1 = float(nominal[0]), float(nominal[1])
        tol = 1e-12 * self._radius
        sets = ((i, j), (i,)) if z[j] > 1e-6 * zi else ((i,),)
        for act in sets:
            a, b, hi = float(G[i, 0]), float(G[i, 1]), float(h[i])
            if len(act) == 1:  # projection onto the line of constraint i
                e = (a * n0 + b * n1 - hi) / (a * a + b * b)
                if e < -tol:
                    continue
                v0, v1 = n0 - e * a, n1 - e * b
            else:  # the vertex of constraints i and j, with multipliers >= 0
                c, d, hj = float(G[j, 0]), float(G[j, 1]), float(h[j])
                det = a * d - b * c
                if abs(det) < 1e-9:
                    continue
                v0, v1 = (d * hi - b * hj) / det, (a * hj - c * hi) / det
                r0, r1 = 2.0 * (n0 - v0), 2.0 * (n1 - v1)  # G_a^T mu = -2 (v - n)
                mu0, mu1 = (d * r0 - c * r1) / det, (a * r1 - b * r0) / det
                if min(mu0, mu1) < -1e-9 * max(1.0, abs(mu0), abs(mu1)):
                    continue
            v = np.array((v0, v1))
            if float((G @ v - h).max()) <= tol:
                return v
        self.count("unpolished")
        return x

    def _exact_project(
        self, nominal: np.ndarray, G: np.ndarray, h: np.ndarray
    ) -> np.ndarray | None:
        """Last resort after two solver failures: the exact 2-D projection (counted)."""
        from .. import kernels2d

        self.n_solver_failure_ += 1
        Gs = np.ascontiguousarray(np.vstack([G, self._S]))
        hs = np.concatenate([h, self._s])
        ok, v0, v1 = kernels2d.project(
            float(nominal[0]), float(nominal[1]), Gs, hs, Gs.shape[0], 1e-13 * self._radius
        )
        return np.array([v0, v1]) if ok else None

    def _run_lp(self, A: np.ndarray, b: np.ndarray, fresh: bool) -> piqp.Status:
        m = A.shape[0]
        cap = self._capacity(m)
        if fresh or self._lp_solver is None or self._lp_shape != cap:
            ns = self._S.shape[0]
            self._lp_G = np.asfortranarray(np.zeros((cap + ns, 3)))
            self._lp_G[:m, 2] = -1.0
            self._lp_G[cap:, :2] = self._S
            self._lp_h = np.concatenate([np.ones(cap), self._s])
            self._lp_G[:m, :2] = -A
            self._lp_h[:m] = b
            self._lp_solver = self._new_solver()
            self._lp_solver.setup(
                P=np.asfortranarray(np.diag([1e-9, 1e-9, 0.0])),
                c=np.array([0.0, 0.0, 1.0]),
                G=self._lp_G,
                h_u=self._lp_h,
            )
            self._lp_shape = cap
        else:
            self._lp_G[:m, :2] = -A
            self._lp_G[:m, 2] = -1.0
            self._lp_G[m:cap] = 0.0
            self._lp_h[:m] = b
            self._lp_h[m:cap] = 1.0
            self._lp_solver.update(G=self._lp_G, h_u=self._lp_h)
        self.n_solves_ += 1
        return self._lp_solver.solve()

    def min_lambda(self, A: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
        """min lambda by one LP in (v, mu) with lambda = sigma mu, sigma the rows' scale.

        Rows with a zero gradient only bound lambda from below and stay out of the LP.
        """
        if A.shape[0] == 0:
            return -math.inf, np.zeros(2)
        nrm = np.hypot(A[:, 0], A[:, 1])
        if nrm.min() > 0.0:  # the usual case: every row has a gradient
            floor, Al, bl = -math.inf, A, b
        else:
            flat = nrm == 0.0
            floor = float(np.max(-b[flat]))
            live = ~flat
            if not live.any():
                return floor, np.zeros(2)
            Al, bl, nrm = A[live], b[live], nrm[live]
        sigma = max(1.0, float(np.abs(bl).max()), float(nrm.max()))
        status = self._run_lp(Al / sigma, bl / sigma, fresh=False)
        if status != piqp.PIQP_SOLVED:
            status = self._run_lp(Al / sigma, bl / sigma, fresh=True)
        if status == piqp.PIQP_SOLVED:
            assert self._lp_solver is not None  # _run_lp has set it up
            v = np.array(self._lp_solver.result.x[:2], dtype=float)
        else:  # last resort: the exact LP (counted)
            from .. import kernels2d

            self.n_solver_failure_ += 1
            m = Al.shape[0]
            _, v0, v1 = kernels2d.smallest_lambda(
                np.ascontiguousarray(Al),
                bl.copy(),
                self._S,
                self._s,
                self._verts,
                self._radius,
                np.zeros((m, 2)),
                np.zeros(m),
            )
            v = np.array([v0, v1])
        # the optimum is where the worst row is tight: recompute lambda exactly at v
        return max(floor, float(np.max(-(Al @ v) - bl))), v
