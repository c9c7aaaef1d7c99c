"""Constant velocity: the fast paths give the original algorithm's numbers bit for bit."""

from __future__ import annotations

import numpy as np

from conformal_control.predictors import ConstantVelocityPredictor, PredictionQuery
from conformal_control.predictors.constant_velocity import trailing_valid


def _reference(window: int, query: PredictionQuery) -> np.ndarray:
    """The algorithm as first written: the whole history, the trailing finite run."""
    hist = np.asarray(query.history, dtype=float)
    n, t, _ = hist.shape
    steps = np.arange(1, query.horizon + 1, dtype=float)
    run = trailing_valid(hist)
    k = np.maximum(np.minimum(run - 1, window), 0)
    last = hist[:, -1, :]
    past = hist[np.arange(n), t - 1 - k, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        vel = np.where(k[:, None] > 0, (last - past) / (np.maximum(k, 1)[:, None] * query.dt), 0)
    out: np.ndarray = last[:, None, :] + vel[:, None, :] * (steps[None, :, None] * query.dt)
    return out


def test_fast_paths_equal_the_reference_bit_for_bit():
    rng = np.random.default_rng(1)
    for _ in range(2000):
        n, t, w = int(rng.integers(1, 8)), int(rng.integers(1, 20)), int(rng.integers(1, 8))
        hist = rng.normal(0.0, 10.0, (n, t, 2))
        if rng.random() < 0.5:  # gaps and short tracks
            hist[rng.random((n, t)) < 0.2] = np.nan
            hist[:, -1] = rng.normal(0.0, 10.0, (n, 2))
        q = PredictionQuery(
            np.arange(n), hist, dt=float(rng.choice([1 / 30, 0.1, 0.4])),
            horizon=int(rng.integers(1, 6)),
        )  # fmt: skip
        got = ConstantVelocityPredictor(window=w).predict(q).positions
        assert np.array_equal(got, _reference(w, q), equal_nan=True)
