"""The Kalman predictor plugin: straight walks, covariance growth, gaps, bad parameters."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cc_kalman import KalmanPredictor

from conformal_control import registry
from conformal_control.cli import main
from conformal_control.predictors.base import PredictionQuery


def _walk(n=3, t=12, dt=0.4, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    v = rng.uniform(-1.5, 1.5, (n, 2))
    steps = np.arange(t + 6) * dt
    path = rng.uniform(0, 10, (n, 1, 2)) + v[:, None] * steps[None, :, None]
    hist = path[:, :t] + rng.normal(0, noise, (n, t, 2))
    return PredictionQuery(np.arange(n), hist, dt=dt, horizon=6), path[:, t:]


def test_registered_through_entry_point():
    assert registry.get("predictor", "kalman") is KalmanPredictor


@pytest.mark.parametrize("model", ["cv", "ca"])
def test_straight_walk_is_continued(model):
    q, truth = _walk()
    fc = KalmanPredictor(model=model).predict(q)
    assert np.abs(fc.positions - truth).max() < 0.1


def test_covariance_grows_with_horizon_and_is_psd():
    q, _ = _walk(noise=0.05)
    cov = KalmanPredictor().predict(q).covariance
    assert cov.shape == (3, 6, 2, 2)
    tr = np.trace(cov, axis1=-2, axis2=-1)
    assert (np.diff(tr, axis=1) > 0).all()
    assert (np.linalg.eigvalsh(cov) > 0).all()


def test_gaps_and_short_histories():
    q, truth = _walk(n=2)
    q.history[0, :-1] = np.nan  # a single sample: stands still
    q.history[1, 3:6] = np.nan  # a gap in the middle: predict-only steps
    fc = KalmanPredictor().predict(q)
    assert fc.info["n_short_history"] == 1
    np.testing.assert_allclose(fc.positions[0], np.repeat(q.history[0, -1:], 6, axis=0))
    assert np.abs(fc.positions[1] - truth[1]).max() < 0.1


def test_noise_is_configurable_and_validated():
    q, _ = _walk(noise=0.05)
    lo = KalmanPredictor(process_noise=0.01).predict(q).covariance
    hi = KalmanPredictor(process_noise=10.0).predict(q).covariance
    assert (np.trace(hi[:, -1], axis1=-2, axis2=-1) > np.trace(lo[:, -1], axis1=-2, axis2=-1)).all()
    with pytest.raises(ValueError, match="process_noise"):
        KalmanPredictor(process_noise=-1.0).predict(q)
    with pytest.raises(ValueError, match="model"):
        KalmanPredictor(model="jerk").predict(q)


def test_flagship_runs_with_kalman_and_records_it(tmp_path):
    rc = main(
        [
            "run",
            "--scene",
            "crossing",
            "--predictor",
            "kalman",
            "--predictor-param",
            "model=ca",
            "--frames",
            "30",
            "--no-plot",
            "--out",
            str(tmp_path / "run"),
        ]
    )
    assert rc == 0
    cfg = json.loads((tmp_path / "run" / "config.json").read_text())
    assert cfg["predictor"]["name"] == "kalman"
    assert cfg["predictor"]["params"]["model"] == "ca"
