"""The perfect predictor: returns the true future (the paper's "gt" baseline)."""

from __future__ import annotations

import numpy as np

from .base import Forecast, PredictionQuery, Predictor

__all__ = ["OraclePredictor"]


class OraclePredictor(Predictor):
    """Ground-truth future of each sensed agent (the "gt/noLearn" baseline).

    Reads the true future through :meth:`PredictionQuery.future` (replaying
    environments attach it to every query; a reactive crowd cannot, and the oracle then
    raises :class:`~conformal_control.predictors.base.TruthUnavailableError`). Where the
    true future is unknown (the agent leaves the data) the forecast is NaN and the
    controller holds the agent at its last known position (a counted fallback).
    """

    #: the compiled engine runs this class as compiled code
    compiled_as = "oracle"

    fast = True

    requires_ground_truth = True

    def predict(self, query: PredictionQuery) -> Forecast:
        if not np.isfinite(query.current).all():
            raise ValueError(
                "the current position (history[:, -1]) of every sensed agent must be finite"
            )
        gt = np.asarray(query.future(), dtype=float)
        expected = (query.n_agents, query.horizon, 2)
        if gt.shape != expected:
            raise ValueError(f"ground truth has shape {gt.shape}, expected {expected}")
        return Forecast(gt.copy())
