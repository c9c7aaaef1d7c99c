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

from ..base import Plugin
from .roles import Barrier

__all__ = ["ConformalConstraint"]


class ConformalConstraint(Plugin):
    """``dh/dx . v + dh/dx_j . v_j + a h + lambda >= 0`` for a barrier ``h``.

    Parameters
    ----------
    barrier : Barrier
        The pairwise barrier h (positions in metres).
    a : float
        Slope of alpha(h) = a h, in 1/s (> 0).
    """

    def __init__(self, barrier: Barrier, a: float = 1.0) -> None:
        self.barrier = barrier
        self.a = a

    def validate(self) -> None:
        """Raise ``ValueError`` for a nonsensical slope."""
        if not (isinstance(self.a, (int, float)) and math.isfinite(self.a) and self.a > 0):
            raise ValueError(f"a must be a finite number > 0, got {self.a!r}")

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
            :mod:`~conformal_control.cbf.reciprocal`); 1 when not given.

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
