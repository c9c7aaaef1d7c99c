"""Constant-velocity extrapolation (Schöller et al. 2020's strong baseline)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.base import CompiledForm
from .base import Forecast, PredictionQuery, Predictor

__all__ = ["ConstantVelocityForm", "ConstantVelocityPredictor", "trailing_valid"]


@dataclass(frozen=True)
class ConstantVelocityForm(CompiledForm):
    """The constant-velocity predictor as the compiled engine runs it.

    Attributes
    ----------
    window : int
        Samples the velocity is averaged over (as given; the engine checks it is a
        positive integer and reports a bad one as the predictor's failure).
    """

    kernel = "constant_velocity"
    window: Any


def trailing_valid(history: np.ndarray) -> np.ndarray:
    """Number of consecutive finite samples at the end of each history, shape (N,)."""
    valid = np.isfinite(history).all(axis=-1)  # (N, T)
    # index of the last invalid sample counted from the end
    rev = valid[:, ::-1]
    all_valid = rev.all(axis=1)
    first_bad = np.argmin(rev, axis=1)
    n: np.ndarray = np.where(all_valid, valid.shape[1], first_bad)
    return n


class ConstantVelocityPredictor(Predictor, compiled="constant_velocity", batchable=True):
    """Extrapolate each agent at its recent average velocity.

    The velocity is the displacement over the last ``window`` sample intervals divided by
    their duration, using only the trailing run of finite samples. An agent observed for
    a single sample is predicted to stand still; such agents are counted in
    ``forecast.info["n_short_history"]``.

    Parameters
    ----------
    window : int
        Number of sample intervals the velocity is averaged over (>= 1).
    """

    def __init__(self, window: int = 5) -> None:
        self.window = window

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{}, {"window": 1}]

    def compiled_state(self) -> ConstantVelocityForm:
        """The window, as the compiled engine's predictor reads it."""
        return ConstantVelocityForm(self.window)

    def predict(self, query: PredictionQuery) -> Forecast:
        if int(self.window) != self.window or self.window < 1:
            raise ValueError(f"window must be a positive integer, got {self.window!r}")
        # only the last window + 1 samples can enter the velocity (a long history costs
        # nothing then; the numbers are the same)
        hist = np.asarray(query.history[:, -(int(self.window) + 1) :], dtype=float)
        n, t, _ = hist.shape
        steps = np.arange(1, query.horizon + 1, dtype=float)
        if n == 0:
            return Forecast(np.zeros((0, query.horizon, 2)), info={"n_short_history": 0})
        w = int(self.window)
        if t == w + 1 and np.isfinite(hist).all():  # every agent seen for w + 1 samples
            last = hist[:, -1, :]
            vel = (last - hist[:, 0, :]) / (w * query.dt)  # the general path's arithmetic
            pos = last[:, None, :] + vel[:, None, :] * (steps[None, :, None] * query.dt)
            return Forecast(pos, info={"n_short_history": 0})
        run = trailing_valid(hist)
        k = np.minimum(run - 1, int(self.window))  # sample intervals usable
        k = np.maximum(k, 0)
        last = hist[:, -1, :]
        past = hist[np.arange(n), t - 1 - k, :]
        with np.errstate(invalid="ignore", divide="ignore"):
            vel = np.where(
                k[:, None] > 0, (last - past) / (np.maximum(k, 1)[:, None] * query.dt), 0.0
            )
        pos = last[:, None, :] + vel[:, None, :] * (steps[None, :, None] * query.dt)
        return Forecast(pos, info={"n_short_history": int((k == 0).sum())})
