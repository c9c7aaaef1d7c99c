"""The conformal CBF constraint, written once for the controller and the loss.

For the ego at ``x`` moving with velocity ``v`` and an agent at ``x_j`` moving with
``v_j``, the constraint of the paper is

    dh/dx . v + dh/dx_j . v_j + a h(x, x_j) + lambda >= 0.

:class:`ConformalConstraint` holds the barrier ``h`` and the slope ``a`` of the linear
class-K function alpha(h) = a h. The controller evaluates it on *predicted* agents to
build the safety filter's rows; the loss evaluates it on predicted and on *true* agents
and scores the gap. Both receive the same instance, so they cannot disagree on ``h`` or
``a``.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.base import Plugin
from .roles import Barrier, EscapeRows

__all__ = ["EDGES", "ConformalConstraint", "time_to_contact"]


#: The edge rule's settings: ``"escape"`` (the toolkit's default) or ``"paper"`` (the rows
#: as published, Algorithm 1 read literally).
EDGES = ("escape", "paper")


class ConformalConstraint(Plugin):
    """``dh/dx . v + dh/dx_j . v_j + a h + lambda >= 0`` for a barrier ``h``.

    The edge rule (``edge="escape"``, the default): the row of an agent already within
    the collision distance is not a row like the others -- a barrier is flat or steep
    there, and no lambda makes its row informative -- but an escape row
    (:meth:`escape`): the safety filter neutralises the agent's row and takes its
    decision among the commands that do not close in on it and move out of its disc at
    ``escape_gain (d_c + escape_margin - d)`` where the speed set allows
    (:meth:`~conformal_control.families.cbf.roles.SafetyFilter.solve_escaping`). ``edge="paper"``
    keeps the published rows (then an overlapped agent's APF row has no gradient and
    the filter's fallback decides, e.g. the nominal velocity at a raised lambda).

    Parameters
    ----------
    barrier : Barrier
        The pairwise barrier h (positions in metres).
    a : float
        Slope of alpha(h) = a h, in 1/s (> 0).
    edge : {"escape", "paper"}
        The edge rule (see above).
    collision_distance : float, optional
        Centre distance (m) below which an agent counts as already too close; default the
        barrier's ``d_c`` (a barrier without one: the edge rule never applies).
    escape_gain : float
        Push gain of the escape rows (1/s, >= 0): move out of a disc entered by ``p``
        metres at ``escape_gain * p`` m/s (a time constant of ``1 / escape_gain``). The
        default, 5/s, was chosen on the benchmark's dev split among 1, 5 and 20/s (see the
        Benchmark page, "At the edges").
    escape_margin : float
        Distance (m, >= 0) beyond the collision distance the escape rows aim at: the push
        is ``escape_gain (d_c + escape_margin - d)``, so a robot ``p`` metres inside moves
        out at ``escape_gain (p + escape_margin)`` m/s at least and leaves the disc in
        finite time (with no margin the push fades as it nears the edge, and it only
        approaches it). The default, 0.1 m, was chosen on the benchmark's dev split among
        0, 0.1, 0.2, 0.3 and 0.5 m and on a ten-robot fleet (see the Benchmark page, "At
        the edges").
    """

    def __init__(
        self,
        barrier: Barrier,
        a: float = 1.0,
        edge: str = "escape",
        collision_distance: float | None = None,
        escape_gain: float = 5.0,
        escape_margin: float = 0.1,
    ) -> None:
        self.barrier = barrier
        self.a = a
        self.edge = edge
        self.collision_distance = collision_distance
        self.escape_gain = escape_gain
        self.escape_margin = escape_margin

    def validate(self) -> None:
        """Raise ``ValueError`` for a nonsensical slope, edge rule or collision distance."""
        if not (isinstance(self.a, (int, float)) and math.isfinite(self.a) and self.a > 0):
            raise ValueError(f"a must be a finite number > 0, got {self.a!r}")
        if self.edge not in EDGES:
            raise ValueError(f"edge must be one of {EDGES}, got {self.edge!r}")
        d = self.collision_distance
        if d is not None and not (
            isinstance(d, (int, float)) and not isinstance(d, bool) and math.isfinite(d) and d >= 0
        ):
            raise ValueError(f"collision_distance must be a finite number >= 0, got {d!r}")
        g = self.escape_gain
        number = isinstance(g, (int, float)) and not isinstance(g, bool)
        if not (number and math.isfinite(g) and g >= 0):
            raise ValueError(f"escape_gain must be a finite number >= 0, got {g!r}")
        m = self.escape_margin
        number = isinstance(m, (int, float)) and not isinstance(m, bool)
        if not (number and math.isfinite(m) and m >= 0):
            raise ValueError(f"escape_margin must be a finite number >= 0 (m), got {m!r}")

    def edge_distance(self) -> float | None:
        """The distance of the edge rule (m), or None when the rule is off (``edge="paper"``,
        or no distance given and the barrier has no ``d_c``): the collision distance, or the
        barrier's own ``d_c`` when that is larger (a barrier inflated by a margin is flat
        within its ``d_c``: its rows say nothing there either)."""
        if self.edge != "escape":
            return None
        found = [
            float(d)
            for d in (self.collision_distance, getattr(self.barrier, "d_c", None))
            if isinstance(d, (int, float)) and not isinstance(d, bool)
        ]
        return max(found) if found else None

    def contact_distance(self) -> float:
        """The collision distance (m) of :meth:`contact_times`: the edge rule's
        (:meth:`edge_distance`), else the barrier's ``d_c``, else 0."""
        d = self.edge_distance()
        if d is None:
            d = getattr(self.barrier, "d_c", None)
        if d is None or isinstance(d, bool) or not isinstance(d, (int, float)):
            return 0.0
        return float(d)

    def contact_times(
        self,
        x_ego: np.ndarray,
        x_agents: np.ndarray,
        v_agents: np.ndarray,
        v_ego: np.ndarray | None = None,
    ) -> np.ndarray:
        """Each agent's predicted time to contact (s): when, moving at its (predicted)
        velocity, it would come within :meth:`contact_distance` of the robot at ``x_ego``
        moving at ``v_ego`` (its nominal velocity; standing still if None); 0 for an agent
        already that close, ``inf`` for one that never comes.

        Parameters
        ----------
        x_ego : ndarray of shape (2,)
            The robot's position (m).
        x_agents, v_agents : ndarrays of shape (N, 2)
            The agents' (predicted) positions (m) and velocities (m/s).
        v_ego : ndarray of shape (2,), optional
            The robot's velocity (m/s).
        """
        return time_to_contact(x_ego, x_agents, v_agents, self.contact_distance(), v_ego)

    def edge_settings(self) -> tuple[float, float, float]:
        """``(collision distance, push gain, escape margin)`` of the edge rule as the
        compiled step takes them (a negative distance: the rule is off)."""
        d = self.edge_distance()
        if d is None:
            return (-1.0, 0.0, 0.0)
        return (d, float(self.escape_gain), float(self.escape_margin))

    def escape(
        self, x_ego: np.ndarray, x_agents: np.ndarray, v_agents: np.ndarray
    ) -> EscapeRows | None:
        """The edge rule's rows for the agents within the collision distance, or None
        when none is (or the rule is off).

        Parameters
        ----------
        x_ego : ndarray of shape (2,)
            The robot's position (m).
        x_agents, v_agents : ndarrays of shape (N, 2)
            The agents' (predicted) positions (m) and velocities (m/s), as for :meth:`rows`.
        """
        d_edge = self.edge_distance()
        if d_edge is None or not len(x_agents):
            return None
        diff = np.subtract(x_ego[:2], x_agents, dtype=float)
        d = np.hypot(diff[:, 0], diff[:, 1])
        rows = np.flatnonzero(d < d_edge)
        if not rows.size:
            return None
        out = rows[d[rows] > 0.0]
        U = diff[out] / d[out, None]
        c = -np.einsum("ij,ij->i", U, np.asarray(v_agents, dtype=float)[out])
        push = float(self.escape_gain) * (d_edge + float(self.escape_margin) - d[out])
        return EscapeRows(rows.astype(np.int64), U, c, push)

    def rows(
        self, x_ego: np.ndarray, x_agents: np.ndarray, v_agents: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The safety filter's rows ``A v + b + lambda >= 0`` for the agents.

        Parameters
        ----------
        x_ego : ndarray of shape (2,)
        x_agents, v_agents : ndarrays of shape (N, 2)

        Returns
        -------
        A : ndarray of shape (N, 2)
            dh/dx_ego for each agent.
        b : ndarray of shape (N,)
            dh/dx_agent . v_agent + a h.
        """
        h, dh_dego, dh_dagent = self.barrier.evaluate(x_ego, x_agents)
        b = np.einsum("ij,ij->i", dh_dagent, v_agents) + self.a * h
        return dh_dego, b

    def value(
        self,
        x_ego: np.ndarray,
        v_ego: np.ndarray,
        x_agents: np.ndarray,
        v_agents: np.ndarray,
        share: np.ndarray | None = None,
    ) -> np.ndarray:
        """``dh/dx . v + dh/dx_j . v_j + a h`` (lambda excluded), broadcast over leading axes.

        Parameters
        ----------
        x_ego, v_ego : ndarrays of shape (..., 2)
        x_agents, v_agents : ndarrays of shape (..., 2)
        share : ndarray broadcastable to (...), optional
            Weight of ``a h`` (a robot's share of a reciprocal pair,
            :mod:`~conformal_control.families.cbf.reciprocal`); 1 when not given.

        Returns
        -------
        ndarray of shape (...)
        """
        h, dh_dego, dh_dagent = self.barrier.evaluate(x_ego, x_agents)
        ah = self.a * h if share is None else self.a * share * h
        out: np.ndarray = (dh_dego * v_ego).sum(-1) + (dh_dagent * v_agents).sum(-1) + ah
        return out

    def lambda_floor(self) -> float:
        """Smallest lambda at which a far agent's row (h = h_max, no gradient) holds.

        ``-a * h_max``, or ``-inf`` when the barrier is unbounded above.
        """
        h_max = self.barrier.upper_bound
        return -math.inf if h_max is None else -self.a * h_max


def time_to_contact(
    x_ego: np.ndarray,
    x_agents: np.ndarray,
    v_agents: np.ndarray,
    d_c: float,
    v_ego: np.ndarray | None = None,
) -> np.ndarray:
    """When each agent, moving at its velocity, comes within ``d_c`` (centre distance) of
    the robot at ``x_ego`` moving at ``v_ego`` (s): the first root of ``|r + w t| = d_c``
    with ``r`` the agent's position and ``w`` its velocity relative to the robot; 0 for an
    agent already within ``d_c``, ``inf`` for one that never comes that close.

    Parameters
    ----------
    x_ego : ndarray of shape (2,)
        The robot's position (m).
    x_agents, v_agents : ndarrays of shape (N, 2)
        The agents' positions (m) and velocities (m/s).
    d_c : float
        The collision distance (m).
    v_ego : ndarray of shape (2,), optional
        The robot's velocity (m/s); None: standing still.
    """
    r = np.asarray(x_agents, dtype=float).reshape(-1, 2) - np.asarray(x_ego, dtype=float)[:2]
    w = np.asarray(v_agents, dtype=float).reshape(-1, 2)
    if v_ego is not None:
        w = w - np.asarray(v_ego, dtype=float)[:2]
    rr = np.einsum("ij,ij->i", r, r)
    rw = np.einsum("ij,ij->i", r, w)
    ww = np.einsum("ij,ij->i", w, w)
    disc = rw * rw - ww * (rr - d_c * d_c)
    out = np.full(r.shape[0], math.inf)
    come = (rw < 0.0) & (disc >= 0.0) & (ww > 0.0)
    out[come] = (-rw[come] - np.sqrt(disc[come])) / ww[come]
    out[rr < d_c * d_c] = 0.0
    return out
