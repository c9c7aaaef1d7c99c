"""The data the CBF decision family exchanges with its world and its loss: the state at a
control instant, the record of an interval, the truth revealed at its end."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .reciprocal import PeerView

__all__ = ["CBFIntervalRecord", "CBFTruth", "ControlState"]


@dataclass
class ControlState:
    """Decision input at one control instant.

    Attributes
    ----------
    x : ndarray of shape (4,)
        Ego state (x, y, vx, vy) in SI units.
    t : float
        Time (s) since the episode started.
    step : int
        Index of the control instant within the current interval.
    goal : ndarray of shape (2,)
        The task's current goal (m).
    peers : PeerView or None
        In a multi-robot world, what the robot knows now of the robots it sensed at the
        sampling time (:class:`~conformal_control.families.cbf.reciprocal.PeerView`); None alone
        or when the world hands out no such view.
    """

    x: np.ndarray
    t: float
    step: int
    goal: np.ndarray
    peers: PeerView | None = None


@dataclass
class CBFIntervalRecord:
    """What the controller did during one interval (the loss's input).

    Agents are in the order of the sensor's query. For a robot handled reciprocally
    (:mod:`~conformal_control.families.cbf.reciprocal`) ``x_pred`` holds its measured position at
    each control instant, ``v_pred`` the reference velocity ``v~_j`` of its row and
    ``share`` the robot's share ``s_ij``.

    Attributes
    ----------
    share : ndarray of shape (N,) or None
        Weight of ``a h`` in each agent's predicted constraint (None: 1 for every agent).
    scored : ndarray of shape (N,) or None
        The agents the loss scores (None: every agent).
    margin : ndarray of shape (N,) or None
        Distance added to the barrier's collision distance for each agent (m; a robot
        larger than a pedestrian); None: 0 for every agent.
    """

    ids: np.ndarray
    x_ego: np.ndarray  # (S, 2) ego position at each executed control instant
    v_ego: np.ndarray  # (S, 2) velocity decision applied (v_QP)
    x_pred: np.ndarray  # (S, N, 2) interpolated predicted positions
    v_pred: np.ndarray  # (S, N, 2) their time derivatives (m/s)
    lam_applied: np.ndarray  # (S,) lambda the decision satisfies (nan for brake/hold)
    status: list[str] = field(default_factory=list)
    share: np.ndarray | None = None
    scored: np.ndarray | None = None
    margin: np.ndarray | None = None

    @property
    def n_steps(self) -> int:
        return int(self.x_ego.shape[0])


@dataclass
class CBFTruth:
    """The sensor's true trajectories of the agents sensed at the interval's start.

    Attributes
    ----------
    samples : ndarray of shape (N, F + 1, 2)
        True positions at the interval's sample times (its start included), NaN where an
        agent was not observed (vanished, left the view).
    dt : float
        Sample spacing (s).
    substeps : int
        Control instants per sample.
    """

    samples: np.ndarray
    dt: float
    substeps: int
