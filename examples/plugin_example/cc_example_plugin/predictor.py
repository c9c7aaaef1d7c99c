"""A damped constant-velocity predictor."""

from __future__ import annotations

import math

import numpy as np

from conformal_control import Forecast, PredictionQuery, Predictor
from conformal_control.predictors.constant_velocity import trailing_valid

__all__ = ["DampedConstantVelocity"]


class DampedConstantVelocity(Predictor):
    """Constant velocity whose speed decays by a factor ``damping`` per sample.

    The velocity is estimated over the last ``window`` sample intervals of the trailing run
    of finite samples (as in the core ``constant_velocity``); the k-th predicted step moves
    by ``v dt damping^k``. An agent observed once is predicted to stand still and counted in
    ``forecast.info["n_short_history"]``.

    Parameters
    ----------
    window : int
        Sample intervals the velocity is averaged over (>= 1).
    damping : float
        Speed factor per sample, in [0, 1]; 1 is plain constant velocity, 0 stands still.
    """

    def __init__(self, window: int = 3, damping: float = 0.9) -> None:
        # store the arguments unchanged: no validation or conversion here
        self.window = window
        self.damping = damping

    @classmethod
    def _unit_test_params(cls) -> list[dict]:
        """Constructor kwargs the contract kit checks (cheap)."""
        return [{}, {"window": 1, "damping": 0.5}, {"damping": 1.0}]

    def predict(self, query: PredictionQuery) -> Forecast:
        if int(self.window) != self.window or self.window < 1:
            raise ValueError(f"window must be a positive integer, got {self.window!r}")
        if not (math.isfinite(self.damping) and 0.0 <= self.damping <= 1.0):
            raise ValueError(f"damping must be in [0, 1], got {self.damping!r}")
        hist = np.asarray(query.history, dtype=float)
        n, t, _ = hist.shape
        if n == 0:
            return Forecast(np.zeros((0, query.horizon, 2)), info={"n_short_history": 0})
        last = hist[:, -1, :]
        if not np.isfinite(last).all():
            raise ValueError("the current position (history[:, -1]) must be finite for every agent")
        k = np.clip(trailing_valid(hist) - 1, 0, int(self.window))
        past = hist[np.arange(n), t - 1 - k, :]
        vel = (last - past) / (np.maximum(k, 1)[:, None] * query.dt)  # k = 0 gives 0
        # cumulative damped displacement after 1..H steps: dt * sum_{j=1..s} damping^j
        factors = np.cumsum(float(self.damping) ** np.arange(1, query.horizon + 1))
        pos = last[:, None, :] + vel[:, None, :] * (factors[None, :, None] * query.dt)
        return Forecast(pos, info={"n_short_history": int((k == 0).sum())})
