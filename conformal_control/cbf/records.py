"""The data the CBF decision family exchanges with its world and its loss: the state at a
control instant, the record of an interval, the truth revealed at its end."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

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
    """

    x: np.ndarray
    t: float
    step: int
    goal: np.ndarray


@dataclass
class CBFIntervalRecord:
    """What the controller did during one interval (the loss's input)."""

    ids: np.ndarray
    x_ego: np.ndarray  # (S, 2) ego position at each executed control instant
    v_ego: np.ndarray  # (S, 2) velocity decision applied (v_QP)
    x_pred: np.ndarray  # (S, N, 2) interpolated predicted positions
    v_pred: np.ndarray  # (S, N, 2) their time derivatives (m/s)
    lam_applied: np.ndarray  # (S,) lambda the decision satisfies (nan for brake/hold)
    status: list[str] = field(default_factory=list)

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
