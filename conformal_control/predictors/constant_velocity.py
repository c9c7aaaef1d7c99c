"""Constant-velocity extrapolation (Schöller et al. 2020's strong baseline)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.base import CompiledForm
from ..core.jit import kernel
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
        w = int(self.window)
        # only the last window + 1 samples can enter the velocity (a long history costs
        # nothing then; the numbers are the same)
        hist = np.asarray(query.history[:, -(w + 1) :], dtype=float)
        if hist.shape[0] == 0:
            return Forecast(np.zeros((0, query.horizon, 2)), info={"n_short_history": 0})
        dt, horizon = query.dt, query.horizon
        if isinstance(dt, float) and isinstance(horizon, (int, np.integer)):
            # one compiled call (the numpy form's numbers; see _extrapolate)
            pos, n_short = _extrapolate(
                np.ascontiguousarray(hist), w, float(dt), max(int(horizon), 0)
            )
            return Forecast(pos, info={"n_short_history": int(n_short)})
        pos, n_short = _extrapolate_numpy(hist, w, dt, horizon)
        return Forecast(pos, info={"n_short_history": int(n_short)})


def _extrapolate_numpy(hist: np.ndarray, w: int, dt: Any, horizon: Any) -> tuple[np.ndarray, int]:
    """The extrapolation in numpy: positions ``(N, horizon, 2)`` and the number of agents
    without a velocity, from the last ``w + 1`` samples ``hist`` (N >= 1, float64).

    The interpreted form of :func:`_extrapolate`, and the form for a ``dt`` that is not a
    Python/numpy float64 or a non-integer ``horizon`` (numpy's promotion rules then decide
    the arithmetic's precision, as they did before the compiled form).
    """
    n, t, _ = hist.shape
    steps = np.arange(1, horizon + 1, dtype=float)
    if t == w + 1 and np.isfinite(hist).all():  # every agent seen for w + 1 samples
        last = hist[:, -1, :]
        vel = (last - hist[:, 0, :]) / (w * dt)  # the general path's arithmetic
        pos = last[:, None, :] + vel[:, None, :] * (steps[None, :, None] * dt)
        return pos, 0
    run = trailing_valid(hist)
    k = np.minimum(run - 1, w)  # sample intervals usable
    k = np.maximum(k, 0)
    last = hist[:, -1, :]
    past = hist[np.arange(n), t - 1 - k, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        vel = np.where(k[:, None] > 0, (last - past) / (np.maximum(k, 1)[:, None] * dt), 0.0)
    pos = last[:, None, :] + vel[:, None, :] * (steps[None, :, None] * dt)
    return pos, int((k == 0).sum())


@kernel(cache=True, nogil=True, error_model="numpy", python=_extrapolate_numpy)
def _extrapolate(hist: np.ndarray, w: int, dt: float, horizon: int) -> tuple[np.ndarray, int]:
    """:func:`_extrapolate_numpy` in scalar loops, compiled (a numpy call costs more than
    the arithmetic of an episode's query: 5-10 agents, 6 samples, about 150 steps ahead).

    The same IEEE operations in the same order: the velocity ``(last - past) / (k dt)``
    over the ``k = min(run - 1, w)`` intervals of the trailing run of samples with both
    coordinates finite (0 when ``k = 0``), the position ``last + v (s dt)`` at step ``s``
    (``+ 0.0`` for an agent standing still, as numpy adds it). ``hist`` is C-contiguous
    float64 of shape (N, T, 2) with T <= w + 1; ``horizon`` >= 0.
    """
    n, t = hist.shape[0], hist.shape[1]
    pos = np.empty((n, horizon, 2))
    n_short = 0
    for i in range(n):
        run = 0
        while run < t:
            x, y = hist[i, t - 1 - run, 0], hist[i, t - 1 - run, 1]
            if not (np.isfinite(x) and np.isfinite(y)):
                break
            run += 1
        k = max(min(run - 1, w), 0)
        lx, ly = hist[i, t - 1, 0], hist[i, t - 1, 1]
        vx = vy = 0.0
        if k > 0:
            den = k * dt
            vx = (lx - hist[i, t - 1 - k, 0]) / den
            vy = (ly - hist[i, t - 1 - k, 1]) / den
        else:
            n_short += 1
        for s in range(horizon):
            h = (s + 1) * dt
            pos[i, s, 0] = lx + vx * h
            pos[i, s, 1] = ly + vy * h
    return pos, n_short
