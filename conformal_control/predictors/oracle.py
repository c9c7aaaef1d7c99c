"""The perfect predictor: returns the true future (the paper's "gt" baseline)."""

from __future__ import annotations

import numpy as np

from .base import Forecast, PredictionQuery, Predictor

__all__ = ["OraclePredictor"]


class OraclePredictor(Predictor, compiled="oracle", batchable=True, requires_ground_truth=True):
    """Ground-truth future of each sensed agent (the "gt/noLearn" baseline).

    Reads the true future over the query's horizon through
    :meth:`PredictionQuery.future` (replaying environments attach it to every query, for
    any horizon: the CBF's interval or an MPC's whole plan; a reactive crowd cannot, and
    the oracle then raises :class:`~conformal_control.predictors.base.TruthUnavailableError`).

    **Agents who leave the data.** Where the true future is unknown -- the agent's track
    ends within the horizon (it walks out of the recorded area, its annotation stops, or
    the scene's data ends) -- the forecast is NaN from there on. Every decision family
    then holds the agent at its last known position for the rest of the horizon, and
    counts the agents concerned in ``n_nonfinite_predictions`` (the metrics of the run):
    the same rule as for any predictor's non-finite forecast, and what the compiled
    engine does with the oracle.
    """

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
