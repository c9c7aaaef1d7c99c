"""Algorithm 1: the conformal CBF-based safe controller (a decision family)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..base import (
    Barrier,
    DecisionFamily,
    Forecast,
    PredictionQuery,
    ReferenceController,
    SafetyFilter,
)
from ..interp import forward_fill, interpolate_at_substeps

__all__ = ["CBFIntervalRecord", "ConformalCBFController", "ControlState"]


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


class ConformalCBFController(DecisionFamily):
    """Conformal CBF controller (Huriot & Sibai, Algorithm 1).

    At each control instant t of interval I_k it reads the predicted position and velocity
    of every sensed agent at t, builds one conformal constraint per agent::

        dh/dx_ego . v + dh/dx_agent . v_pred + a h(x_ego, x_pred) + lambda >= 0

    and asks the safety filter for the velocity closest to the reference that satisfies
    them. Smaller lambda is more conservative.

    Predictions are sanitised here, with counters: a forecast of the wrong shape is an
    error; non-finite predicted samples are replaced by the last finite sample before them
    (the agent is held still from there; ``n_nonfinite_predictions_`` counts affected
    agent-intervals).

    Parameters
    ----------
    barrier : Barrier
        The pairwise barrier h.
    safety_filter : SafetyFilter
        The QP (or another filter) solving for the safe velocity.
    reference : ReferenceController
        Nominal controller (called with the environment's current goal).
    a : float
        Slope of the linear extended class-K function alpha(h) = a h, in 1/s (> 0).
    substeps : int
        Control instants per prediction sample.
    """

    def __init__(
        self,
        barrier: Barrier,
        safety_filter: SafetyFilter,
        reference: ReferenceController,
        a: float = 1.0,
        substeps: int = 4,
    ) -> None:
        self.barrier = barrier
        self.safety_filter = safety_filter
        self.reference = reference
        self.a = a
        self.substeps = substeps

    def reset(self) -> None:
        if not (math.isfinite(self.a) and self.a > 0):
            raise ValueError(f"a must be a finite number > 0, got {self.a!r}")
        if int(self.substeps) != self.substeps or self.substeps < 1:
            raise ValueError(f"substeps must be a positive integer, got {self.substeps!r}")
        self.safety_filter.reset()
        self.reference.reset()
        self.n_nonfinite_predictions_ = 0
        self.n_steps_ = 0
        self.forecast_info_: dict[str, float] = {}
        self._begin_empty()

    def _begin_empty(self) -> None:
        self._ids = np.zeros(0, dtype=np.int64)
        self._xp = np.zeros((0, 0, 2))
        self._vp = np.zeros((0, 0, 2))
        self._rec_x: list[np.ndarray] = []
        self._rec_v: list[np.ndarray] = []
        self._rec_lam: list[float] = []
        self._rec_status: list[str] = []

    # ------------------------------------------------------------------ sampling time
    def begin_interval(self, observation: PredictionQuery, prediction: Forecast | None) -> None:
        self._begin_empty()
        n = observation.n_agents
        self._ids = np.asarray(observation.ids)
        if n == 0:
            return
        if prediction is None:
            raise ValueError("ConformalCBFController needs a prediction for the sensed agents")
        for key, value in prediction.info.items():  # the predictor's own counters
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                self.forecast_info_[key] = self.forecast_info_.get(key, 0) + value
        pos = np.asarray(prediction.positions, dtype=float)
        horizon = observation.horizon
        if pos.ndim != 3 or pos.shape[0] != n or pos.shape[1] < horizon or pos.shape[2] != 2:
            raise ValueError(
                f"predictor returned positions of shape {pos.shape}; expected "
                f"({n}, >= {horizon}, 2) for {n} sensed agents and horizon {horizon}"
            )
        samples = np.concatenate([observation.current[:, None, :], pos[:, :horizon]], axis=1)
        samples, had_bad = forward_fill(samples)
        self.n_nonfinite_predictions_ += int(had_bad.sum())
        n_steps = horizon * int(self.substeps)
        self._xp, self._vp = interpolate_at_substeps(
            samples, observation.dt, int(self.substeps), n_steps
        )

    # ------------------------------------------------------------------ control instant
    def decide(self, state: ControlState, lam: float) -> np.ndarray:
        x_ego = state.x[:2]
        v_ref = self.reference(state.x, state.t, state.goal)
        if self._ids.size:
            x_pred, v_pred = self._xp[state.step], self._vp[state.step]
            h, dh_dego, dh_dagent = self.barrier.evaluate(x_ego, x_pred)
            A = dh_dego
            b = np.einsum("ij,ij->i", dh_dagent, v_pred) + self.a * h
        else:
            A, b = np.zeros((0, 2)), np.zeros(0)
        res = self.safety_filter.solve(v_ref, A, b, lam)
        self._rec_x.append(x_ego.copy())
        self._rec_v.append(res.decision)
        self._rec_lam.append(res.lambda_applied)
        self._rec_status.append(res.status if res.fallback is None else res.fallback)
        self.n_steps_ += 1
        return res.decision

    def interval_record(self) -> CBFIntervalRecord:
        s = len(self._rec_x)
        return CBFIntervalRecord(
            ids=self._ids,
            x_ego=np.array(self._rec_x).reshape(s, 2),
            v_ego=np.array(self._rec_v).reshape(s, 2),
            x_pred=self._xp[:s] if self._ids.size else np.zeros((s, 0, 2)),
            v_pred=self._vp[:s] if self._ids.size else np.zeros((s, 0, 2)),
            lam_applied=np.array(self._rec_lam, dtype=float),
            status=list(self._rec_status),
        )
