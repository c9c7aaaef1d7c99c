"""What every velocity safety-filter backend shares: the problem, the checks, the fallback.

A backend (one module per solver, qpsolvers style) provides the solver primitives of
:class:`~conformal_control.families.cbf.roles.FilterPrimitives` (``project``, ``min_lambda``,
``search_margin``); :class:`VelocityFilter` turns them into a
:class:`~conformal_control.families.cbf.roles.SafetyFilter`: input checks, the unconstrained fast
path, infeasibility detection, the fallback (a
:class:`~conformal_control.families.cbf.roles.Fallback` instance or a registered name) and the
counters of :meth:`VelocityFilter.stats`, identical for every backend.

The problem, for every backend::

    min ||v - v_ref||^2  s.t.  A v + b + lambda >= 0 (one row per sensed agent),  v in P

with ``P`` the regular polygon with ``speed_sides`` sides inscribed in the disc of radius
``v_max`` (so every admissible v has ``||v|| <= v_max``), or the box ``|v_x|, |v_y| <=
v_max`` for ``speed_sides=0``. A nominal decision meeting every row and the speed bound
itself (the disc for the polygon) is returned unchanged: it is then the optimum with the
exact disc. Otherwise the polygon applies, so a filtered decision may be up to
``1 - cos(pi / speed_sides)`` (2 % for 16 sides) slower than ``v_max`` in the worst
direction.
"""

from __future__ import annotations

import math
from abc import abstractmethod
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import numpy.typing as npt

from ....core import registry
from ....core.spec import parameter_info
from ..fallbacks import resolve_fallback
from ..roles import EscapeRows, Fallback, FilterResult, InfeasibleStep, SafetyFilter
from ..speed import speed_polygon

__all__ = ["VelocityFilter"]


class VelocityFilter(
    SafetyFilter,
    run_values={"v_max": "v_max", "fallback": "fallback", "speed_sides": "speed_sides"},
):
    """Base of the velocity safety filters (see the module docstring for the problem).

    Parameters
    ----------
    v_max : float
        Speed bound (m/s).
    fallback : str or Fallback
        What to do when the rows are infeasible at the requested lambda: a registered
        fallback name (``"lambda_search"``, ``"relax"``, ``"brake"``, ``"hold"``, or a
        plugin's) or a :class:`~conformal_control.families.cbf.roles.Fallback` instance. Every use
        is
        counted (``n_fallback_``, ``n_infeasible_``, per fallback in :meth:`stats`).
    speed_sides : int
        Number of sides of the speed polygon (>= 3), or 0 for a box.

    Notes
    -----
    :meth:`solve` never raises on finite input of the right shapes: infeasibility goes to
    the fallback, a solver failure to a counted last resort. NaN or infinite input (or
    finite values so large, ~1e308, that the residuals overflow) is a ``ValueError``.
    """

    def __init__(
        self, v_max: float = 2.0, fallback: str | Fallback = "lambda_search", speed_sides: int = 16
    ) -> None:
        self.v_max = v_max
        self.fallback = fallback
        self.speed_sides = speed_sides

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [
            {},
            {"fallback": "brake", "speed_sides": 0},
            {"fallback": "hold", "v_max": 1.0},
            {"fallback": "relax"},
        ]

    # ------------------------------------------------------------------ set-up
    def reset(self) -> None:
        if not (isinstance(self.v_max, (int, float)) and math.isfinite(self.v_max)):
            raise ValueError(f"v_max must be a finite number > 0, got {self.v_max!r}")
        if self.v_max <= 0:
            raise ValueError(f"v_max must be a finite number > 0, got {self.v_max!r}")
        top = int(parameter_info("speed_sides").high)
        if self.speed_sides != 0 and not (
            int(self.speed_sides) == self.speed_sides and 3 <= self.speed_sides <= top
        ):
            raise ValueError(
                f"speed_sides must be 0 (box) or from 3 to {top}, got {self.speed_sides!r}"
            )
        try:
            self.fallback_ = resolve_fallback(self.fallback)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"fallback: {exc}") from exc
        self.fallback_.reset()
        self._S, self._s, self._verts, self._radius = speed_polygon(
            int(self.speed_sides), float(self.v_max)
        )
        self._box = not self.speed_sides
        self._last = np.zeros(2)
        self._fell_back = False
        self.n_solves_ = 0
        self.n_infeasible_ = 0
        self.n_fallback_ = 0
        self.n_solver_failure_ = 0
        self.fallback_counts_: dict[str, int] = {}
        self.events_: dict[str, int] = {}
        self._setup()
        # the speed set the primitives work in: this polygon, or an escape polygon
        # (solve_escaping) whose rows beyond the speed set's are _hard
        self._base = (self._S, self._s, self._verts)
        self._hard: tuple[np.ndarray, np.ndarray] | None = None
        self._escaping: EscapeRows | None = None
        self._ttc: np.ndarray | None = None  # the rows' times to contact (contact())

    def _polygon_changed(self) -> None:
        """Called when the speed set the primitives work in changes (a backend holding
        solver set-ups built on it drops them)."""

    def _setup(self) -> None:
        """Backend set-up (solver objects, buffers), called at the end of :meth:`reset`."""

    def stats(self) -> dict[str, float]:
        out: dict[str, float] = {
            "n_solves": self.n_solves_,
            "n_infeasible": self.n_infeasible_,
            "n_fallback": self.n_fallback_,
            "n_solver_failure": self.n_solver_failure_,
        }
        for name in dict.fromkeys((*registry.names("fallback"), self.fallback_.name, "escape")):
            out[f"n_fallback_{name}"] = self.fallback_counts_.get(name, 0)
        for event, n in self.events_.items():
            out[f"n_{event}"] = n
        return out

    # ------------------------------------------------------------------ primitives
    @abstractmethod
    def project(self, nominal: np.ndarray, A: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
        """argmin ||v - nominal||^2 s.t. ``A v + rhs >= 0`` and v in the speed set, or
        None if no v meets them."""

    @abstractmethod
    def min_lambda(self, A: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
        """min lambda s.t. some admissible v meets ``A v + b + lambda >= 0``: ``(lambda*, v*)``
        with lambda* recomputed at v* (so v* meets every row there); ``-inf`` without rows."""

    @abstractmethod
    def search_margin(self, lam_star: float, A: np.ndarray, b: np.ndarray) -> float:
        """Margin above lambda* at which :meth:`project` reliably finds the rows feasible."""

    def count(self, event: str) -> None:
        """Count an event (reported as ``n_<event>`` by :meth:`stats`)."""
        self.events_[event] = self.events_.get(event, 0) + 1

    def project_relaxed(
        self, nominal: np.ndarray, A: np.ndarray, rhs: np.ndarray, weights: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Minimal weighted relaxation, then the projection there: ``(v, s)``.

        The LP ``min weights @ s s.t. A v + rhs + s >= 0, s >= 0, v in P`` is solved by
        HiGHS' dual simplex (a vertex: rows that need no slack get exactly 0), on rows
        normalised to unit gradient (rows with a zero gradient have a fixed slack
        ``max(0, -rhs_j)``). Relaxed rows get the backend's margin on top, so the
        projection finds them feasible; should it still fail, the LP's own velocity is
        returned (counted as ``n_relax_vertex``). ``v`` meets ``A v + rhs + s >= 0``.

        Parameters
        ----------
        nominal : ndarray of shape (2,)
            The reference decision (m/s).
        A : ndarray of shape (N, 2)
            Constraint rows.
        rhs : ndarray of shape (N,)
            Their constant terms (lambda included).
        weights : ndarray of shape (N,)
            The cost of relaxing each row.
        """
        from scipy.optimize import linprog  # only the relax fallback needs it

        m = A.shape[0]
        s = np.zeros(m)
        nrm = np.hypot(A[:, 0], A[:, 1])
        flat = nrm == 0.0
        s[flat] = np.maximum(0.0, -rhs[flat])
        # rows met everywhere in the disc around the speed set never need a slack
        live = np.flatnonzero(~flat & (rhs < nrm * self._radius))
        v_lp = np.zeros(2)
        if live.size:
            An = A[live] / nrm[live, None]
            rn = rhs[live] / nrm[live]
            k = live.size
            ns = self._S.shape[0]
            A_ub = np.zeros((k + ns, 2 + k))
            A_ub[:k, :2] = -An
            A_ub[:k, 2:] = -np.eye(k)
            A_ub[k:, :2] = self._S
            b_ub = np.concatenate([rn, self._s])
            cost = np.concatenate([[0.0, 0.0], weights[live] * nrm[live]])
            bounds = [(None, None), (None, None)] + [(0.0, None)] * k
            self.n_solves_ += 1
            lp = linprog(cost, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs-ds")
            if lp.status != 0:  # pragma: no cover - bounded and feasible by construction
                self.n_solver_failure_ += 1
                x = np.zeros(2 + k)
                x[2:] = np.maximum(0.0, -rn)  # v = 0 with the slack it needs
            else:
                x = lp.x
            v_lp = np.asarray(x[:2], dtype=float)
            s[live] = np.maximum(x[2:], 0.0) * nrm[live]
        relaxed = s > 0
        if relaxed.any():
            pad = self.search_margin(float(np.max(s)), A, rhs)
            s = np.where(relaxed, s + pad, 0.0)
        v = self.project(nominal, A, rhs + s)
        if v is None:
            self.count("relax_vertex")
            v = v_lp
            s = np.maximum(s, -(A @ v + rhs))
        return v, s

    # ------------------------------------------------------------------ API
    def _admissible(self, v: np.ndarray) -> bool:
        """Whether v meets the speed bound itself (the disc for the polygon) and, within an
        escape polygon, its rows."""
        if self._hard is not None and not self._meets_hard(v):
            return False
        if self._box:
            return bool(abs(v[0]) <= self.v_max and abs(v[1]) <= self.v_max)
        return bool(v[0] * v[0] + v[1] * v[1] <= self.v_max * self.v_max * (1.0 + 1e-12))

    def _checked(
        self, nominal: npt.ArrayLike, A: npt.ArrayLike, b: npt.ArrayLike
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if type(nominal) is not np.ndarray or nominal.dtype != np.float64:
            nominal = np.asarray(nominal, dtype=float)
        if type(A) is not np.ndarray or A.dtype != np.float64:
            A = np.asarray(A, dtype=float)
        if type(b) is not np.ndarray or b.dtype != np.float64:
            b = np.asarray(b, dtype=float)
        m = b.shape[0] if b.ndim == 1 else -1
        if nominal.shape != (2,) or A.shape != (m, 2):
            raise ValueError(
                f"{type(self).__name__} expects a nominal velocity of shape (2,), A of shape "
                f"(N, 2) and b of shape (N,); got {nominal.shape}, {A.shape} and {b.shape}"
            )
        return nominal, A, b

    def solve(self, nominal: np.ndarray, A: np.ndarray, b: np.ndarray, lam: float) -> FilterResult:
        """The velocity closest to ``nominal`` with ``A v + b + lam >= 0`` in the speed set;
        the fallback decides when there is none.

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
        nominal, A, b = self._checked(nominal, A, b)
        rhs = b + lam
        slack = A @ nominal + rhs
        # one finiteness test covers A, b, lam and the nominal decision (NaN/inf propagate)
        if not (math.isfinite(slack.sum() + lam) and math.isfinite(nominal[0] + nominal[1])):
            raise ValueError(
                f"{type(self).__name__} received non-finite constraints, lambda or nominal "
                "decision; predictions must be sanitised before building constraints"
            )
        if (slack.size == 0 or slack.min() >= 0) and self._admissible(nominal):
            self._last = nominal
            self._fell_back = False
            return FilterResult(nominal, "unconstrained", lam)
        lam_star = v_star = None
        feasible = True
        if self.capabilities.probe_floor_first and self._fell_back and A.shape[0]:
            # infeasibility tends to persist: find the floor first, skip a doomed solve
            lam_star, v_star = self.min_lambda(A, b)
            feasible = lam >= lam_star + self.search_margin(lam_star, A, b)
        if feasible:
            v = self.project(nominal, A, rhs)
            if v is not None:
                self._last = v
                self._fell_back = False
                return FilterResult(v, "optimal", lam)
        last = self._last.copy()
        step = InfeasibleStep(nominal, A, b, lam, last, lam_star, v_star, self._escaping, self._ttc)
        return self._fall_back(step)

    def fall_back(self, step: InfeasibleStep) -> FilterResult:
        """An infeasible step decided by the filter's fallback, counted as the filter's own
        (the hand-over of a step solved elsewhere: the compiled engine's step pauses an
        episode whose fallback decides in Python and hands its rows over here).

        Parameters
        ----------
        step : InfeasibleStep
            The step's nominal decision, rows, lambda and previous decision.
        """
        return self._fall_back(step)

    def _fall_back(self, step: InfeasibleStep) -> FilterResult:
        """Count the infeasible decision and let the fallback decide (within the escape
        polygon when ``step.escape`` gives one: a decision leaving it is projected onto
        it, counted as ``n_escape_projected``)."""
        self.n_infeasible_ += 1
        self.n_fallback_ += 1
        name = self.fallback_.name
        self.fallback_counts_[name] = self.fallback_counts_.get(name, 0) + 1
        if step.escape is not None and self._hard is None:
            # a step handed over by a compiled path: enter its escape polygon here
            escaped = self._enter_escape(step.nominal, step.escape)
            if escaped is not None:
                self._last = escaped.decision
                self._fell_back = True
                return escaped
            try:
                return self._fall_back(step)
            finally:
                self._leave_escape()
        res = self.fallback_.decide(step, self)
        if self._hard is not None and not self._meets_hard(res.decision):
            self.count("escape_projected")
            v = self.project(np.asarray(res.decision, dtype=float), np.zeros((0, 2)), np.zeros(0))
            decision = np.zeros(2) if v is None else v
            res = FilterResult(decision, res.status, math.nan, res.fallback)
        self._last = np.asarray(res.decision, dtype=float)
        self._fell_back = True
        return res

    def speed_set(self) -> tuple[np.ndarray, np.ndarray, float]:
        """The speed set the primitives work in now: half-planes ``S v <= s`` (the speed
        polygon, or within :meth:`escaping` the escape polygon) and the radius of a disc
        containing the speed polygon (read by fallbacks that solve their own programs,
        e.g. :func:`~conformal_control.families.cbf.reciprocal.priority_relax`)."""
        return self._S, self._s, float(self._radius)

    # ------------------------------------------------------------------ the edge rule
    def _meets_hard(self, v: np.ndarray) -> bool:
        """Whether v meets the escape polygon's rows (to round-off)."""
        assert self._hard is not None
        G, h = self._hard
        v = np.asarray(v, dtype=float)
        return bool((G @ v - h <= 1e-13 * np.maximum(1.0, np.abs(h))).all())

    def _enter_escape(self, nominal: np.ndarray, escape: EscapeRows) -> FilterResult | None:
        """Make the escape polygon of ``escape`` the speed set of the primitives
        (:func:`~conformal_control.families.cbf.kernels2d.escape_polygon`); or, when the rule
        decides alone (no non-closing command, or a degenerate polygon), return that
        decision (status ``"fallback"``, fallback ``"escape"``)."""
        from .. import kernels2d as k2

        S, s, verts = self._base
        k = escape.U.shape[0]
        ns, nv = S.shape[0], verts.shape[0]
        r = max(ns, nv) + 2 * k
        ES, es = np.zeros((r, 2)), np.zeros(r)
        ev, ev2 = np.zeros((r, 2)), np.zeros((2 * r, 2))
        mode, nsq, nvq, v0, v1 = k2.escape_polygon(
            np.ascontiguousarray(escape.U, dtype=float),
            np.ascontiguousarray(escape.c, dtype=float),
            np.ascontiguousarray(escape.push, dtype=float),
            k, S, s, verts, self._radius, ES, es, ev, ev2, np.zeros(k),
        )  # fmt: skip
        if mode == k2.ESCAPE_MINIMAX:
            return FilterResult(np.array((v0, v1)), "fallback", math.nan, "escape")
        if mode == k2.ESCAPE_DEGENERATE:
            _, w0, w1 = k2.project(
                float(nominal[0]), float(nominal[1]), ES[:nsq].copy(), es[:nsq].copy(),
                nsq, k2.REL_TOL * self._radius,
            )  # fmt: skip
            return FilterResult(np.array((w0, w1)), "fallback", math.nan, "escape")
        self._S = np.ascontiguousarray(ES[:nsq])
        self._s = np.ascontiguousarray(es[:nsq])
        self._verts = np.ascontiguousarray(ev[:nvq])
        self._hard = (self._S[ns:], self._s[ns:])
        self._escaping = escape
        self._polygon_changed()
        return None

    def _leave_escape(self) -> None:
        """Back to the speed set itself."""
        self._S, self._s, self._verts = self._base
        self._hard = None
        self._escaping = None
        self._polygon_changed()

    @contextmanager
    def contact(self, ttc: np.ndarray | None) -> Iterator[None]:
        """Within this context an infeasible step hands ``ttc`` (the rows' predicted times
        to contact, s) to the fallback (:attr:`InfeasibleStep.ttc
        <conformal_control.families.cbf.roles.InfeasibleStep.ttc>`).

        Parameters
        ----------
        ttc : ndarray of shape (N,) or None
            One time per row of the next :meth:`solve` (None: none).
        """
        before, self._ttc = self._ttc, ttc
        try:
            yield
        finally:
            self._ttc = before

    @contextmanager
    def escaping(self, nominal: np.ndarray, escape: EscapeRows) -> Iterator[FilterResult | None]:
        """Within this context the primitives, :meth:`solve` and every fallback work
        within the escape polygon of ``escape``; yields None, or the decision when the
        edge rule decides alone (no command that does not close in exists, or the
        polygon is degenerate; counted as a fallback ``"escape"``). The rows of the
        agents in ``escape.rows`` must be neutralised
        (:meth:`~conformal_control.families.cbf.roles.EscapeRows.neutralise`).

        Parameters
        ----------
        nominal : ndarray of shape (2,)
            The reference decision (m/s).
        escape : EscapeRows
            The agents within the collision distance.
        """
        if not escape.U.shape[0]:
            yield None
            return
        if not math.isfinite(float(escape.U.sum() + escape.c.sum() + escape.push.sum())):
            raise ValueError(f"{type(self).__name__} received non-finite escape rows")
        escaped = self._enter_escape(np.asarray(nominal, dtype=float), escape)
        if escaped is not None:
            self.n_solves_ += 1
            self.n_infeasible_ += 1
            self.n_fallback_ += 1
            self.fallback_counts_["escape"] = self.fallback_counts_.get("escape", 0) + 1
            self._last = escaped.decision
            self._fell_back = True
            yield escaped
            return
        try:
            yield None
        finally:
            self._leave_escape()

    def solve_escaping(
        self,
        nominal: np.ndarray,
        A: np.ndarray,
        b: np.ndarray,
        lam: float,
        escape: EscapeRows | None,
        ttc: np.ndarray | None = None,
    ) -> FilterResult:
        """:meth:`solve` with the edge rule (see
        :class:`~conformal_control.families.cbf.roles.EscapeRows`).

        The rows of the agents within the collision distance are neutralised and the
        decision -- the projection, the unconstrained fast path and every fallback's -- is
        taken within the escape polygon (:meth:`escaping`): no command closing in on them
        when one that does not exists; moving out of their discs as fast as
        ``escape.push`` asks where the speed set allows
        (:func:`~conformal_control.families.cbf.kernels2d.escape_polygon`). Without such agents
        this is :meth:`solve`.

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
        escape : EscapeRows or None
            The agents within the collision distance (None: none).
        ttc : ndarray of shape (N,), optional
            The rows' predicted times to contact (s), handed to the fallback
            (:meth:`contact`).
        """
        with self.contact(ttc):
            if escape is None or not escape.rows.size:
                return self.solve(nominal, A, b, lam)
            nominal, A, b = self._checked(nominal, A, b)
            A, b = escape.neutralise(A, b, lam)
            with self.escaping(nominal, escape) as escaped:
                if escaped is not None:
                    return escaped
                return self.solve(nominal, A, b, lam)
