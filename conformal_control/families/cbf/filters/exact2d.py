"""The exact 2-D backend: incremental (Seidel-style) projection and lambda LP.

The decision is a velocity in the plane, so the filter's QP is the projection of the
nominal velocity onto an intersection of half-planes and the speed polygon, and the
lambda-search LP has three variables. :mod:`conformal_control.families.cbf.kernels2d` solves both
exactly up to floating point (no interior-point margin: the optimum lies on its active
constraints, no row is violated by more than 1e-13 times the problem's scale) in
microseconds, compiled with numba. Same problem, same fast path, same fallbacks and
counters as the piqp backend (:class:`~conformal_control.families.cbf.filters.piqp.QPSafetyFilter`).

With the APF barrier the controller fuses barrier, rows and this filter into one compiled
call (:meth:`Exact2DSafetyFilter.step_apf`, or :meth:`Exact2DSafetyFilter.step_apf_record`
which also writes the controller's record), for the ``lambda_search``, ``brake`` and
``hold`` fallbacks. Parameters, speed polygon, work vector and last decision live in one
flat buffer, so that compiled call takes few arguments (numba's dispatch cost grows with
them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ....core.base import CompiledForm
from ..constraint import time_to_contact
from ..fallbacks import Brake, Hold, LambdaSearch, resolve_fallback
from ..roles import EscapeRows, Fallback, FilterResult, InfeasibleStep
from .base import VelocityFilter

__all__ = ["Exact2DForm", "Exact2DSafetyFilter"]


@dataclass(frozen=True)
class Exact2DForm(CompiledForm):
    """The exact 2-D filter as the compiled step reads it.

    Attributes
    ----------
    speed_sides : int
        Sides of the speed polygon (0: a box).
    v_max : float
        Speed limit (m/s).
    lambda_margin : float
        Margin of the lambda search.
    fallback : str or None
        The compiled form its fallback declares (``lambda_search``, ``brake``, ``hold``;
        None: the fallback decides in Python, :meth:`Exact2DSafetyFilter.fall_back`).
    """

    kernel = "exact2d"
    speed_sides: int
    v_max: float
    lambda_margin: float
    fallback: str | None


class Exact2DSafetyFilter(VelocityFilter, compiled="exact2d"):
    """min ||v - v_ref||^2  s.t.  A v + b + lambda >= 0,  v in the speed polygon  (exact 2-D).

    The problem, the fast path, the fallbacks and the counters are those of
    :class:`~conformal_control.families.cbf.filters.base.VelocityFilter`; each call of the
    projection or the lambda LP counts as one solve.

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
        Margin added to the smallest feasible lambda, relative to the rows' scale
        ``max(1, |lambda*|, |b_j|, ||A_j|| v_max)``: 1000 times the solver's round-off
        tolerance, so the projection there is strictly feasible.
    compiled_step : bool
        Let the controller fuse barrier, rows and this filter into one compiled call when
        the barrier is the APF one (:meth:`step_apf`); False always takes the generic path.
    """

    def __init__(
        self,
        v_max: float = 2.0,
        fallback: str | Fallback = "lambda_search",
        speed_sides: int = 16,
        lambda_margin: float = 1e-10,
        compiled_step: bool = True,
    ) -> None:
        super().__init__(v_max=v_max, fallback=fallback, speed_sides=speed_sides)
        self.lambda_margin = lambda_margin
        self.compiled_step = compiled_step

    def _setup(self) -> None:
        if not (math.isfinite(self.lambda_margin) and 0 < self.lambda_margin < 1e-3):
            raise ValueError(
                f"lambda_margin must be a number in (0, 1e-3), got {self.lambda_margin!r}"
            )
        from .. import kernels2d, kernels_peers

        self._k = kernels2d
        self._kp = kernels_peers
        self._S = np.ascontiguousarray(self._S)
        self._verts = np.ascontiguousarray(self._verts)
        self._ns = self._S.shape[0]  # sides of the speed set (an escape polygon has more)
        poly = np.concatenate([self._S.ravel(), self._s, self._verts.ravel()])
        head = np.zeros(self._k.HEADER)
        head[6:11] = (self._radius, self._box, self.v_max, 0.0, self.lambda_margin)
        head[12:14] = (-1.0, 0.0)  # the edge rule: off until configure_apf sets it
        head[self._k.HEADER - 3] = self._S.shape[0]
        # one flat buffer (parameters, polygon, work vector: kernels2d.apf_control's
        # layout) with views for apf_step and the fallbacks
        self._buf = np.concatenate([head, poly])
        self._cap = -1
        self._buffers(16)
        # the compiled step handles these fallbacks itself (lambda_search) or reports the
        # infeasibility for the Python side to apply them (brake, hold)
        kind = type(self.fallback_)
        self._fused = bool(self.compiled_step) and kind in (LambdaSearch, Brake, Hold)
        self._prm[9] = kind is LambdaSearch

    def compiled_state(self) -> Exact2DForm:
        """The filter's constants for the compiled step, with the compiled form its
        fallback declares (the reset one, else the one ``fallback`` names)."""
        fallback = self.__dict__.get("fallback_") or resolve_fallback(self.fallback)
        kernel = fallback.capabilities.compiled
        return Exact2DForm(self.speed_sides, self.v_max, self.lambda_margin, kernel)

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state.pop("_k", None)  # modules: re-imported on unpickling
        state.pop("_kp", None)
        if "_lastv" in state and state.get("_last") is state["_lastv"]:
            state["_last"] = np.array(state["_lastv"])  # a copy, not a view of _buf
        for name in ("_prm", "_poly", "_work", "_lastv"):  # views of _buf, rebuilt
            state.pop(name, None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        if "_buf" in state:
            from .. import kernels2d, kernels_peers

            self._k = kernels2d
            self._kp = kernels_peers
            self._views()

    def _views(self) -> None:
        """The parameters, polygon, work vector and last decision as views of ``_buf``."""
        k, ns, buf = self._k, self._ns, self._buf
        self._prm = buf[: len(k.PARAMS)]
        self._lastv = buf[k.HEADER - 2 : k.HEADER]
        self._poly = buf[k.HEADER : k.HEADER + 5 * ns]
        self._work = buf[k.HEADER + 5 * ns :]

    def _buffers(self, m: int) -> None:
        if m <= self._cap:
            return
        cap = max(m, 2 * self._cap, 16)
        ns = self._ns
        self._G = np.zeros((cap + ns, 2))
        self._h = np.zeros(cap + ns)
        self._Ak = np.zeros((cap, 2))
        self._bk = np.zeros(cap)
        fixed = self._k.HEADER + 5 * ns
        buf = np.zeros(fixed + self._k.work_size(cap, ns))
        buf[:fixed] = self._buf[:fixed]
        buf[11] = cap
        last = getattr(self, "_lastv", None)
        self._buf = buf
        self._views()
        if last is not None and self._last is last:  # keep the last decision in the new buffer
            self._lastv[:] = last
            self._last = self._lastv
        self._cap = cap

    # ------------------------------------------------------------------ primitives
    def project(self, nominal: np.ndarray, A: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
        self._buffers(A.shape[0])
        if self._G.shape[0] < A.shape[0] + self._S.shape[0]:  # an escape polygon's sides
            self._G = np.zeros((A.shape[0] + self._S.shape[0], 2))
            self._h = np.zeros(self._G.shape[0])
        self.n_solves_ += 1
        ok, v0, v1 = self._k.solve_rows(
            float(nominal[0]),
            float(nominal[1]),
            np.ascontiguousarray(A, dtype=float),
            np.ascontiguousarray(rhs, dtype=float),
            self._S,
            self._s,
            self._radius,
            self._G,
            self._h,
        )
        return np.array([v0, v1]) if ok else None

    def min_lambda(self, A: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
        self._buffers(A.shape[0])
        self.n_solves_ += 1
        lam, v0, v1 = self._k.smallest_lambda(
            np.ascontiguousarray(A, dtype=float),
            np.ascontiguousarray(b, dtype=float),
            self._S,
            self._s,
            self._verts,
            self._radius,
            self._Ak,
            self._bk,
        )
        return float(lam), np.array([v0, v1])

    def search_margin(self, lam_star: float, A: np.ndarray, b: np.ndarray) -> float:
        return float(
            self._k.lambda_margin(
                lam_star,
                np.ascontiguousarray(A, dtype=float),
                np.ascontiguousarray(b, dtype=float),
                self._radius,
                self.lambda_margin,
            )
        )

    # ------------------------------------------------------------------ fused step
    @property
    def fused(self) -> bool:
        """Whether :meth:`step_apf` may be used (``compiled_step`` and a fallback it fuses)."""
        return self._fused

    def configure_apf(
        self,
        barrier_params: tuple[float, float, float, float, bool],
        a: float,
        edge: tuple[float, float, float] = (-1.0, 0.0, 0.0),
    ) -> None:
        """Set the APF barrier ``(K_rep, rho0, d_c, delta, surface)``, the slope ``a`` that
        :meth:`step_apf` builds its rows from and the edge rule ``(collision distance,
        push gain, escape margin)`` (the controller does, at ``reset``).

        Parameters
        ----------
        barrier_params : tuple
            ``(K_rep, rho0, d_c, delta, surface)`` of the APF barrier.
        a : float
            Slope of alpha(h) = a h (1/s).
        edge : (float, float, float)
            The edge rule's collision distance (m, centre to centre; negative: the rule is
            off), push gain (1/s) and escape margin (m), :meth:`ConformalConstraint.edge_settings
            <conformal_control.families.cbf.constraint.ConformalConstraint.edge_settings>`.
        """
        self._prm[:6] = (*barrier_params, a)
        self._prm[12:15] = edge

    @staticmethod
    def escape_in(work: np.ndarray, cap: int, ns: int) -> EscapeRows | None:
        """The escape rows the compiled step left in its work vector ``work`` (laid out for
        ``cap`` agents and ``ns`` polygon sides), or None when no agent was within the
        edge rule's distance.

        Parameters
        ----------
        work : ndarray
            The compiled step's work vector.
        cap : int
            The agents it is laid out for.
        ns : int
            The sides of the speed polygon.
        """
        from .. import kernels2d as k2

        region = work[10 * cap + 3 * ns :]
        n, k = int(region[0]), int(region[1])
        if region[2] < 0 or not n:
            return None
        idx, U, c, push = k2.edge_views(region, cap, ns)[:4]
        return EscapeRows(idx[:n].astype(np.int64), U[:k].copy(), c[:k].copy(), push[:k].copy())

    def step_apf(
        self,
        x_ego: np.ndarray,
        x_agents: np.ndarray,
        v_agents: np.ndarray,
        nominal: np.ndarray,
        lam: float,
        offsets: np.ndarray | None = None,
    ) -> FilterResult:
        """One compiled control step with the APF barrier's rows (:meth:`configure_apf`):
        the same decision, status, lambda and counters as ``solve(nominal,
        *constraint.rows(x_ego, x_agents, v_agents), lam)`` (to round-off), without
        building the rows in Python. Predictions must be finite (the controller sanitises
        them); a non-finite row, lambda or nominal raises ``ValueError`` as ``solve`` does.

        Parameters
        ----------
        x_ego : ndarray of shape (2,) or more
            The robot's position (m; its first two numbers).
        x_agents : ndarray of shape (M, 2)
            The agents' predicted positions (m).
        v_agents : ndarray of shape (M, 2)
            Their predicted velocities (m/s).
        nominal : ndarray of shape (2,)
            The nominal velocity (m/s).
        lam : float
            lambda (1/s).
        offsets : ndarray of shape (M,), optional
            Per agent, added to its row's ``b`` (lambda run per agent: row j's slack is
            ``lam + offsets[j]``); None: every row's slack is ``lam``.
        """
        n = x_agents.shape[0]
        if n > self._cap:
            self._buffers(n)
        k = self._k
        code, v0, v1, lam_used, solves = k.apf_step(
            x_ego[0], x_ego[1], x_agents, v_agents, nominal[0], nominal[1], lam,
            self._prm, self._poly, self._work, _no_offsets(offsets),
        )  # fmt: skip
        self.n_solves_ += solves
        if code == 0:  # unconstrained
            self._last = nominal
            self._fell_back = False
            return FilterResult(nominal, "unconstrained", lam)
        if code == 1:  # optimal
            v = np.array((v0, v1))
            self._last = v
            self._fell_back = False
            return FilterResult(v, "optimal", lam)
        if code == k.ESCAPED:
            v = np.array((v0, v1))
            self._count_escaped()
            self._last = v
            return FilterResult(v, "fallback", math.nan, "escape")
        ttc = None
        if code == k.INFEASIBLE:
            ttc = self.contact_times(x_ego, x_agents, v_agents, nominal)
        return self._step_apf_fallback(code, v0, v1, lam_used, n, nominal, lam, ttc)

    def step_apf_record(
        self,
        x0: float,
        x1: float,
        n0: float,
        n1: float,
        lam: float,
        pv: np.ndarray,
        s: int,
        rec: np.ndarray,
        i: int,
        offsets: np.ndarray | None = None,
    ) -> FilterResult | None:
        """:meth:`step_apf` for the controller, recorded by the compiled step itself.

        The same step (decision, status, lambda, counters, last decision) on the ego
        position ``(x0, x1)``, the nominal velocity ``(n0, n1)`` and step ``s`` of an
        interval's predictions ``pv`` (positions ``pv[0]``, velocities ``pv[1]``, C-ordered
        float64); row ``i`` of the record ``rec`` receives the result (the layout of
        :func:`~conformal_control.families.cbf.kernels2d.apf_control`; ``i`` must be a row of it).
        Returns None when the compiled step decided (the decision, lambda applied and
        result code are in ``rec``), or the result of the ``brake`` / ``hold`` fallback
        (only the ego position and the code are then recorded). A step outside ``pv``
        raises ``IndexError``; non-finite input raises ``ValueError`` as :meth:`solve` does.

        Parameters
        ----------
        x0, x1 : float
            The robot's position (m).
        n0, n1 : float
            The nominal velocity (m/s).
        lam : float
            lambda (1/s).
        pv : ndarray of shape (2, S, M, 2)
            The interval's predictions at its control steps: positions (m) and
            velocities (m/s) of its M sensed agents.
        s : int
            The control step within the interval.
        rec : ndarray
            The interval's record (one row per control step).
        i : int
            The row of ``rec`` this step writes.
        offsets : ndarray of shape (M,), optional
            Per agent, added to its row's ``b`` (see :meth:`step_apf`).
        """
        off = _no_offsets(offsets)
        code = self._k.apf_control(x0, x1, n0, n1, lam, s, i, pv, self._buf, rec, off)
        if code == 0 or code == 1:  # unconstrained / optimal: one solve for optimal
            self.n_solves_ += code
            self._last = self._lastv
            self._fell_back = False
            return None
        return self._step_record_rest(code, x0, x1, n0, n1, lam, pv, s, rec, i, off)

    def step_buffer(self) -> np.ndarray:
        """The compiled step's buffer (parameters, polygon, last decision, work space), as
        :meth:`step_apf_record_peers` hands it to
        :func:`~conformal_control.families.cbf.kernels_peers.apf_control_peers`: what a
        lockstep engine calling that kernel itself passes (then :meth:`add_compiled_steps`)."""
        return self._buf

    def add_compiled_steps(self, solves: int) -> None:
        """Count steps decided by a lockstep engine on :meth:`step_buffer`, each of them
        unconstrained or optimal (``solves``: how many optimal), as
        :meth:`step_apf_record_peers` counts such a step.

        Parameters
        ----------
        solves : int
            The optimal steps among them (one solve each).
        """
        self.n_solves_ += int(solves)
        self._last = self._lastv
        self._fell_back = False

    def step_apf_record_peers(
        self,
        x0: float,
        x1: float,
        n0: float,
        n1: float,
        lam: float,
        pv: np.ndarray,
        s: int,
        rec: np.ndarray,
        i: int,
        rows: tuple[np.ndarray, int],
        peers: tuple[np.ndarray, np.ndarray, float, float, np.ndarray, float, float],
        floor: np.ndarray | None = None,
    ) -> FilterResult | bool | None:
        """:meth:`step_apf_record` with robot rows (a multi-robot world's reciprocal rows).

        ``rows = (col, npred)``: per column of ``pv`` the weight of ``a h``, 1 for a row
        without lambda and the collision distance added (``col``, shape (3, N)), and the
        number of predicted columns; ``peers = (positions, references, own_x, own_y,
        turn, vx, vy)``: the peers' positions and reference velocities now and the robot's
        own reference, written into ``pv``'s columns ``npred:`` at step ``s``, the
        side-step rule and the robot's velocity
        (:func:`~conformal_control.families.cbf.kernels_peers.apf_control_peers`).
        Same results, counters and fallbacks as :meth:`step_apf_record`; a fallback
        decided in Python starts from the nominal velocity as given. With the robot rows
        giving way first (``turn[6]``) the floor rows join (``floor``: the robots'
        collision distance and the floor margin, m) and a step the compiled call does not
        decide (an agent or a peer within the edge rule's distance, a coinciding peer, an
        infeasible step: :data:`~conformal_control.families.cbf.kernels_peers.PYTHON_STEP`)
        returns False, nothing recorded or counted: the caller decides it on the generic
        path.

        Parameters
        ----------
        x0, x1, n0, n1, lam, pv, s, rec, i
            As for :meth:`step_apf_record` (``pv`` with columns for the peers after the
            ``npred`` predicted ones).
        rows : (ndarray of shape (3, N), int)
            ``(col, npred)`` as above.
        peers : tuple
            ``(positions, references, own_x, own_y, turn, vx, vy)`` as above: the peers'
            positions (K, 2) m and reference velocities (K, 2) m/s, the robot's own
            reference velocity (m/s), :meth:`Reciprocity.turn`'s options and the robot's
            velocity (m/s).
        floor : ndarray of shape (2,), optional
            The robots' collision distance and the floor margin (m), read with ``turn[6]``.
        """
        kernels_peers = self._kp
        col, npred = rows
        pos, ref, o0, o1, turn, vx, vy = peers
        if floor is None:
            floor = np.zeros(2)
        code = kernels_peers.apf_control_peers(
            x0, x1, n0, n1, lam, s, i, pv, self._buf, rec, col, npred, pos, ref, o0, o1, turn,
            vx, vy, floor,
        )  # fmt: skip
        if code == kernels_peers.PYTHON_STEP:
            return False
        if code == 0 or code == 1:
            self.n_solves_ += code
            self._last = self._lastv
            self._fell_back = False
            return None
        k = self._k
        if code == k.TOO_MANY:
            m = pv.shape[2]
            self._buffers(2 * m - npred if turn[6] != 0.0 else m)  # the floor rows too
            return self.step_apf_record_peers(
                x0, x1, n0, n1, lam, pv, s, rec, i, rows, peers, floor
            )
        if code == k.OUT_OF_RANGE:
            raise IndexError(
                f"control step {s} is outside the interval's {pv.shape[1]} predicted steps"
            )
        if code == k.ESCAPED:
            self.n_solves_ += 1
            self._count_escaped()
            self._last = self._lastv
            return None
        if code in (k.SEARCHED, k.SEARCH_VERTEX, kernels_peers.SEARCH_ALL):
            self.n_solves_ += 3
            self._count_search(k.SEARCHED if code == kernels_peers.SEARCH_ALL else code)
            if code == kernels_peers.SEARCH_ALL:
                self.count("hard_rows_relaxed")
            self._last = self._lastv
            return None
        ttc = None
        if code == k.INFEASIBLE:
            self.n_solves_ += 1
            ttc = self.contact_times(np.array((x0, x1)), pv[0, s], pv[1, s], np.array((n0, n1)))
        return self._step_apf_fallback(code, n0, n1, lam, pv.shape[2], np.array((n0, n1)), lam, ttc)

    def _step_record_rest(
        self,
        code: int,
        x0: float,
        x1: float,
        n0: float,
        n1: float,
        lam: float,
        pv: np.ndarray,
        s: int,
        rec: np.ndarray,
        i: int,
        off: np.ndarray,
    ) -> FilterResult | None:
        k = self._k
        if code == k.TOO_MANY:
            self._buffers(pv.shape[2])
            return self.step_apf_record(x0, x1, n0, n1, lam, pv, s, rec, i, off)
        if code == k.OUT_OF_RANGE:
            if -pv.shape[1] <= s < 0:  # counted from the end, as numpy indexing does
                return self.step_apf_record(x0, x1, n0, n1, lam, pv, s + pv.shape[1], rec, i, off)
            raise IndexError(
                f"control step {s} is outside the interval's {pv.shape[1]} predicted steps"
            )
        if code == k.SEARCHED or code == k.SEARCH_VERTEX:
            self.n_solves_ += 3
            self._count_search(code)
            self._last = self._lastv
            return None
        if code == k.ESCAPED:
            self.n_solves_ += 1
            self._count_escaped()
            self._last = self._lastv
            return None
        ttc = None
        if code == k.INFEASIBLE:
            self.n_solves_ += 1
            ttc = self.contact_times(np.array((x0, x1)), pv[0, s], pv[1, s], np.array((n0, n1)))
        return self._step_apf_fallback(code, n0, n1, lam, pv.shape[2], np.array((n0, n1)), lam, ttc)

    def contact_times(
        self,
        x_ego: np.ndarray,
        x_agents: np.ndarray,
        v_agents: np.ndarray,
        v_ego: np.ndarray,
    ) -> np.ndarray:
        """The agents' predicted times to contact (s) with the distance the compiled step
        was configured with (the larger of the edge rule's and the barrier's ``d_c``),
        the robot moving at ``v_ego``,
        :func:`~conformal_control.families.cbf.constraint.time_to_contact`.

        Parameters
        ----------
        x_ego : ndarray of shape (2,)
            The robot's position (m).
        x_agents, v_agents : ndarrays of shape (N, 2)
            The agents' predicted positions (m) and velocities (m/s).
        v_ego : ndarray of shape (2,)
            The robot's (nominal) velocity (m/s).
        """
        d = float(max(self._prm[12], self._prm[2]))
        return time_to_contact(x_ego, x_agents, v_agents, d, v_ego)

    def _step_apf_fallback(
        self,
        code: int,
        v0: float,
        v1: float,
        lam_used: float,
        n: int,
        nominal: np.ndarray,
        lam: float,
        ttc: np.ndarray | None = None,
    ) -> FilterResult:
        k = self._k
        if code == k.NONFINITE:
            raise ValueError(
                f"{type(self).__name__} received non-finite constraints, lambda or nominal "
                "decision; predictions must be sanitised before building constraints"
            )
        if code == k.INFEASIBLE:  # brake / hold: the Python fallback decides
            cap = self._cap
            A = self._work[: 2 * n].reshape(n, 2).copy()
            b = self._work[2 * cap : 2 * cap + n].copy()
            escape = self.escape_in(self._work, cap, self._ns)
            step = InfeasibleStep(
                np.asarray(nominal, dtype=float), A, b, lam, self._last.copy(), escape=escape,
                ttc=ttc,
            )  # fmt: skip
            return self._fall_back(step)
        self._count_search(code)
        v = np.array((v0, v1))
        self._last = v
        return FilterResult(v, "fallback", lam_used, "lambda_search")

    def _count_escaped(self) -> None:
        """Count a step the compiled edge rule decided alone (it fell back)."""
        self.n_infeasible_ += 1
        self.n_fallback_ += 1
        self.fallback_counts_["escape"] = self.fallback_counts_.get("escape", 0) + 1
        self._fell_back = True

    def _count_search(self, code: int) -> None:
        """Count a step the compiled lambda search decided (it fell back)."""
        self.n_infeasible_ += 1
        self.n_fallback_ += 1
        self.fallback_counts_["lambda_search"] = self.fallback_counts_.get("lambda_search", 0) + 1
        if code == self._k.SEARCH_VERTEX:
            self.count("lambda_search_vertex")
        self._fell_back = True


#: No per-agent offsets (one lambda for every row): what the compiled step is given then.
_NO_OFFSETS = np.zeros(0)


def _no_offsets(offsets: np.ndarray | None) -> np.ndarray:
    """The compiled step's ``off`` argument: ``offsets`` as float64, or no offsets."""
    if offsets is None:
        return _NO_OFFSETS
    return np.ascontiguousarray(offsets, dtype=np.float64)
