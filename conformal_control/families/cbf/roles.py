"""The flagship's roles: barrier, safety filter, reference controller, robot dynamics.

The conformal CBF controller
(:class:`~conformal_control.families.cbf.controller.ConformalCBFController`)
is one :class:`~conformal_control.core.base.DecisionFamily` built from these parts. Each is a
small abstract base class; implementations are plugins found by name
(``conformal-control plugins``).

==========================  ============================================================
``Barrier``                 ego position, agent positions -> h, dh/dx_ego, dh/dx_agent
``SafetyFilter``            nominal velocity + rows ``A v + b + lambda >= 0`` -> safe velocity
``Fallback``                what a safety filter does when the rows are infeasible at lambda
``ReferenceController``     ego state, time, goal -> nominal velocity
``Dynamics``                state, command, dt -> next state
==========================  ============================================================
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar, Literal, Protocol

import numpy as np

from ...core.base import Plugin

__all__ = [
    "Barrier",
    "CommandKind",
    "Dynamics",
    "EscapeRows",
    "Fallback",
    "FilterPrimitives",
    "FilterResult",
    "FilterStatus",
    "InfeasibleStep",
    "ReferenceController",
    "SafetyFilter",
]

#: ``"unconstrained"``: the nominal decision met every constraint and was returned as is;
#: ``"optimal"``: the filter's optimum at the requested lambda; ``"fallback"``: the
#: constraints could not be met at the requested lambda and the fallback named in
#: :attr:`FilterResult.fallback` decided.
FilterStatus = Literal["unconstrained", "optimal", "fallback"]


class Barrier(Plugin, ABC):
    """Pairwise control barrier function h(x_ego, x_agent) on positions (metres).

    ``h >= 0`` is the safe set. Implementations are vectorised: ``x_ego`` and
    ``x_agent`` broadcast against each other over leading dimensions.
    """

    @abstractmethod
    def evaluate(
        self, x_ego: np.ndarray, x_agent: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return ``(h, dh_dego, dh_dagent)``.

        Parameters
        ----------
        x_ego : ndarray of shape (..., 2)
        x_agent : ndarray of shape (..., 2)

        Returns
        -------
        h : ndarray of shape (...)
        dh_dego : ndarray of shape (..., 2)
            Exact gradient with respect to the ego position.
        dh_dagent : ndarray of shape (..., 2)
            Exact gradient with respect to the agent position.
        """

    def value(self, x_ego: np.ndarray, x_agent: np.ndarray) -> np.ndarray:
        """Barrier value only."""
        return self.evaluate(x_ego, x_agent)[0]

    @property
    def upper_bound(self) -> float | None:
        """Supremum of h (used to compute the feasibility floor), or None if unbounded."""
        return None


@dataclass(frozen=True)
class FilterResult:
    """Output of a safety filter for one decision.

    Attributes
    ----------
    decision : ndarray of shape (2,)
        The (safe) velocity actually applied (m/s).
    status : FilterStatus
    lambda_applied : float
        The lambda every returned row satisfies: the requested lambda unless a fallback
        raised it; ``nan`` for a fallback that meets the rows at no lambda (``brake``,
        ``hold``).
    fallback : str or None
        Name of the fallback used, if any.
    row_lambda : ndarray of shape (N,) or None
        Per-row lambda the decision satisfies, when it differs between rows (a fallback
        that relaxes only some constraints); ``None`` when it is ``lambda_applied`` for
        every row.
    """

    decision: np.ndarray
    status: FilterStatus
    lambda_applied: float
    fallback: str | None = None
    row_lambda: np.ndarray | None = None


@dataclass(frozen=True)
class EscapeRows:
    """The edge rule's input: the agents already within the collision distance.

    Built by :meth:`~conformal_control.families.cbf.constraint.ConformalConstraint.escape` from the
    same positions and velocities as the rows; a safety filter handed them
    (:meth:`SafetyFilter.solve_escaping`) neutralises the agents' own rows (``A_j = 0``,
    ``b_j = -lambda``: met at every lambda the filter may apply, so they never raise the
    lambda the other rows share) and takes its decision within the escape polygon: the
    commands that do not close in on any of them (``U v + c >= 0``) and move out of their
    discs at ``push`` as far as the speed set allows
    (:func:`~conformal_control.families.cbf.kernels2d.escape_polygon`).

    Attributes
    ----------
    rows : ndarray of int64, shape (n,)
        The rows (agents) within the collision distance.
    U : ndarray of shape (k, 2)
        Unit vectors from each of them to the robot (k <= n: an agent at the robot's very
        position has none).
    c : ndarray of shape (k,)
        ``-U . v_agent``: the distance grows at ``U v + c`` for the command ``v`` (m/s).
    push : ndarray of shape (k,)
        Speed (m/s, >= 0) at which to move out of each disc, ``a (d_c - d)``.
    """

    rows: np.ndarray
    U: np.ndarray
    c: np.ndarray
    push: np.ndarray

    def closing(self, v: np.ndarray) -> np.ndarray:
        """Closing speed (m/s) of the command ``v`` toward each agent: ``-(U v + c)``."""
        out: np.ndarray = -(self.U @ np.asarray(v, dtype=float) + self.c)
        return out

    def neutralise(self, A: np.ndarray, b: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the rows with those of :attr:`rows` neutralised: ``A_j = 0``, ``b_j =
        -lam`` (met at every lambda >= ``lam``).

        Parameters
        ----------
        A : ndarray of shape (N, 2)
            The rows' velocity coefficients.
        b : ndarray of shape (N,)
            Their constant terms.
        lam : float
            The lambda of the step (1/s).
        """
        A = np.array(A, dtype=float)
        b = np.array(b, dtype=float)
        A[self.rows] = 0.0
        b[self.rows] = -lam
        return A, b


class SafetyFilter(Plugin, ABC):
    """Minimally modify a nominal velocity so that the conformal constraints hold.

    The constraints are ``A @ v + b + lam >= 0`` row-wise (one row per sensed agent),
    plus the filter's own admissible set (a speed bound).
    """

    @abstractmethod
    def solve(self, nominal: np.ndarray, A: np.ndarray, b: np.ndarray, lam: float) -> FilterResult:
        """Return the decision closest to ``nominal`` satisfying the constraints.

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

    def solve_escaping(
        self,
        nominal: np.ndarray,
        A: np.ndarray,
        b: np.ndarray,
        lam: float,
        escape: EscapeRows | None,
        ttc: np.ndarray | None = None,
    ) -> FilterResult:
        """:meth:`solve` with the edge rule: no command closing in on an agent already
        within the collision distance (``escape``) when one that does not exists.

        This default, for a filter that knows nothing of the rule, solves without it and
        brakes (zero velocity, which closes in on no standing agent) when the decision
        closes in on one of them;
        :class:`~conformal_control.families.cbf.filters.base.VelocityFilter`
        takes the decision within the escape polygon instead.

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
            The rows' predicted times to contact (s), for a fallback that uses them
            (:attr:`InfeasibleStep.ttc`); this default ignores them.
        """
        res = self.solve(nominal, A, b, lam)
        if escape is None or not escape.U.shape[0]:
            return res
        # closing in no faster than braking does (not at all on a standing agent)
        allowed = np.maximum(-escape.c, 0.0) + 1e-12 * max(1.0, float(np.abs(escape.c).max()))
        if not (escape.closing(res.decision) > allowed).any():
            return res
        return FilterResult(np.zeros(2), "fallback", math.nan, "escape")

    def reset(self) -> None:
        """Reset counters and warm-start state (validate parameters here)."""

    def stats(self) -> dict[str, float]:
        """Counters since :meth:`reset`: ``n_solves`` (solver calls), ``n_infeasible``
        (decisions whose rows were infeasible at the requested lambda), ``n_fallback``
        (fallback uses), ``n_fallback_<name>`` per fallback, and ``n_solver_failure``
        (numerical failures answered by a documented last resort)."""
        return {}


@dataclass(frozen=True)
class InfeasibleStep:
    """A decision whose rows ``A v + b + lam >= 0`` admit no velocity (the fallback's input).

    Attributes
    ----------
    nominal : ndarray of shape (2,)
    A : ndarray of shape (N, 2)
    b : ndarray of shape (N,)
    lam : float
        The requested lambda.
    previous : ndarray of shape (2,)
        The decision the filter returned last (zero after ``reset``).
    lam_star, v_star : float and ndarray, or None
        The smallest feasible lambda and a velocity attaining it, when the filter already
        computed them to detect the infeasibility.
    escape : EscapeRows or None
        The agents within the collision distance (their rows in ``A``, ``b`` already
        neutralised); the filter's primitives then work within the escape polygon, and
        the fallback's decision is projected onto it if it leaves it.
    ttc : ndarray of shape (N,) or None
        Each row's agent's predicted time to contact (s): when it would reach the
        collision distance of the robot moving at its nominal velocity (0 within it,
        ``inf`` if never),
        when the family computed it (:meth:`ConformalConstraint.contact_times
        <conformal_control.families.cbf.constraint.ConformalConstraint.contact_times>`).
    """

    nominal: np.ndarray
    A: np.ndarray
    b: np.ndarray
    lam: float
    previous: np.ndarray
    lam_star: float | None = None
    v_star: np.ndarray | None = None
    escape: EscapeRows | None = None
    ttc: np.ndarray | None = None


class FilterPrimitives(Protocol):
    """Solver primitives a safety filter hands to its fallback (all over the filter's own
    admissible set, e.g. its speed polygon)."""

    def project(self, nominal: np.ndarray, A: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
        """argmin ||v - nominal||^2 s.t. ``A v + rhs >= 0``, or None if infeasible."""

    def min_lambda(self, A: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
        """Smallest lambda with a v meeting ``A v + b + lambda >= 0``, and that v (which
        meets every row at the returned lambda)."""

    def search_margin(self, lam_star: float, A: np.ndarray, b: np.ndarray) -> float:
        """Margin above ``lam_star`` at which :meth:`project` reliably finds the rows
        ``A v + b + lam_star + margin >= 0`` feasible (the solver's tolerance)."""

    def project_relaxed(
        self, nominal: np.ndarray, A: np.ndarray, rhs: np.ndarray, weights: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Smallest weighted relaxation ``s >= 0`` (min ``weights @ s``) making
        ``A v + rhs + s >= 0`` feasible, then the v closest to ``nominal`` there: ``(v, s)``.

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

    def count(self, event: str) -> None:
        """Count an event in the filter's stats (``n_<event>``)."""


class Fallback(Plugin, ABC):
    """What a safety filter does when its rows are infeasible at the requested lambda.

    The filter detects the infeasibility, counts it, and calls :meth:`decide` with the
    problem and its solver primitives; the fallback returns the decision with status
    ``"fallback"`` and its :attr:`name` in :attr:`FilterResult.fallback`.
    """

    #: Name reported in :attr:`FilterResult.fallback` and the per-fallback counters.
    name: ClassVar[str] = "fallback"

    @abstractmethod
    def decide(self, step: InfeasibleStep, solver: FilterPrimitives) -> FilterResult:
        """The decision for an infeasible step."""

    def reset(self) -> None:
        """Reset internal state (validate parameters here)."""


class ReferenceController(Plugin, ABC):
    """Nominal controller the safety filter minimally modifies."""

    @abstractmethod
    def __call__(self, state: np.ndarray, t: float, goal: np.ndarray) -> np.ndarray:
        """Nominal velocity (m/s) at ego state ``state``, time ``t`` (s), toward ``goal`` (m).

        The environment owns the task and hands over its current goal (waypoint).
        """

    def reset(self) -> None:
        """Reset internal state (validate parameters here)."""


#: What a dynamics' command is: ``"velocity"`` (a world-frame velocity, m/s, bounded by the
#: run's speed limit), ``"acceleration"`` (m/s^2) or ``"unicycle"`` (forward speed v in m/s
#: and turn rate omega in rad/s, bounded by :meth:`Dynamics.command_limits`).
CommandKind = Literal["velocity", "acceleration", "unicycle"]


class Dynamics(Plugin, ABC):
    """Plant of the ego agent: ``state`` is a flat float array starting ``(x, y, vx, vy)``
    (position and world-frame velocity, SI); a plant with more state appends it (the
    unicycle's heading is ``state[4]``).

    Besides :meth:`step`, a plant tells planners what its command is (:attr:`command_kind`,
    :meth:`command_limits`) and rolls many command sequences out at once
    (:meth:`rollout`; the default loops over :meth:`step`, plants override it with a
    vectorised equivalent that the contract kit compares with the loop).
    """

    state_dim: ClassVar[int] = 4
    command_kind: ClassVar[CommandKind] = "velocity"

    @abstractmethod
    def step(self, state: np.ndarray, command: np.ndarray, dt: float) -> np.ndarray:
        """State after holding ``command`` for ``dt`` seconds (returns a new array)."""

    def initial_state(self, position: np.ndarray, heading: float = 0.0) -> np.ndarray:
        """The state of a robot at rest at ``position`` (m) facing ``heading`` (rad; plants
        without a heading ignore it)."""
        out = np.zeros(self.state_dim)
        out[:2] = np.asarray(position, dtype=float)[:2]
        return out

    def command_limits(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Box ``(low, high)`` of admissible commands, or ``None`` when the plant itself
        has none (a velocity command is then bounded by the run's speed limit)."""
        return None

    def rollout(self, state: np.ndarray, commands: np.ndarray, dt: float) -> np.ndarray:
        """States after each step of many command sequences, all from ``state``.

        Parameters
        ----------
        state : ndarray of shape (state_dim,)
        commands : ndarray of shape (N, H, 2)
            N sequences of H commands, each held for ``dt`` seconds.
        dt : float

        Returns
        -------
        ndarray of shape (N, H, state_dim)
            ``out[n, h]`` is the state after commands ``0..h`` of sequence ``n``.
        """
        cmd = np.asarray(commands, dtype=float)
        n, h = cmd.shape[:2]
        out = np.empty((n, h, self.state_dim))
        for i in range(n):
            x = np.asarray(state, dtype=float)
            for j in range(h):
                x = self.step(x, cmd[i, j], dt)
                out[i, j] = x
        return out

    def position(self, state: np.ndarray) -> np.ndarray:
        """Position part of the state (metres)."""
        return state[:2]

    def velocity(self, state: np.ndarray) -> np.ndarray:
        """Velocity part of the state (m/s)."""
        return state[2:4]
