"""The scikit-learn predictor plugin: fit, save/load by path, any regressor, frame rates."""

from __future__ import annotations

import numpy as np
import pytest
from cc_sklearn import SklearnPredictor
from cc_sklearn.predictor import UNIT_TEST_WEIGHTS, make_unit_test_weights

from conformal_control import registry
from conformal_control.predictors import ConstantVelocityPredictor
from conformal_control.predictors.base import PredictionQuery
from conformal_control.predictors.evaluation import Windows, evaluate_predictor
from conformal_control.predictors.learned import synthetic_windows
from conformal_control.testing import parametrize_with_checks


@parametrize_with_checks([SklearnPredictor])
def test_contract(plugin, check):
    check(plugin)


def test_unit_test_params_load_the_shipped_weights_without_fitting(monkeypatch):
    def no_fitting(*args, **kwargs):
        raise AssertionError("_unit_test_params must not fit")

    monkeypatch.setattr(SklearnPredictor, "_fit_arrays", no_fitting)
    (params,) = SklearnPredictor._unit_test_params()
    assert params == {"weights": str(UNIT_TEST_WEIGHTS)}
    h, _ = synthetic_windows(3, seed=5)
    fc = SklearnPredictor(**params).predict(PredictionQuery(np.arange(3), h, dt=0.4, horizon=12))
    assert np.isfinite(fc.positions).all()


def test_shipped_weights_are_reproducible(tmp_path):
    fresh = make_unit_test_weights(tmp_path / "w")
    h, _ = synthetic_windows(16, seed=7)
    q = PredictionQuery(np.arange(16), h, dt=0.4, horizon=12)
    shipped = SklearnPredictor(weights=str(UNIT_TEST_WEIGHTS)).predict(q)
    again = SklearnPredictor(weights=str(fresh)).predict(q)
    np.testing.assert_allclose(again.positions, shipped.positions, atol=1e-9)


def test_registered_and_trainable():
    cls = registry.get("predictor", "sklearn")
    assert cls is SklearnPredictor and cls.trainable


def test_ridge_learns_walks_and_round_trips(tmp_path):
    h, f = synthetic_windows(400, seed=0)
    model = SklearnPredictor().fit(h, f, dt=0.4)
    th, tf = synthetic_windows(200, seed=1)
    res = evaluate_predictor(model, Windows(th, tf, 0.4))
    cv = evaluate_predictor(ConstantVelocityPredictor(window=1), Windows(th, tf, 0.4))
    assert res["ade"] < 0.75 * cv["ade"]  # smooths the noise and learns the turning
    loaded = SklearnPredictor(weights=str(model.save(tmp_path / "w")))
    q = PredictionQuery(np.arange(5), th[:5].copy(), dt=0.4, horizon=12)
    np.testing.assert_allclose(loaded.predict(q).positions, model.predict(q).positions)


def test_other_regressor_and_30fps_query():
    h, f = synthetic_windows(200, seed=0)
    model = SklearnPredictor("KNeighborsRegressor", {"n_neighbors": 3}).fit(h, f, dt=0.4)
    # the same straight walk sampled at 30 fps: 90 frames of history, 20 frames ahead
    t = np.arange(90) / 30.0
    hist = np.stack([t, 0.5 * t], axis=-1)[None]
    fc = model.predict(PredictionQuery(np.arange(1), hist, dt=1 / 30, horizon=20))
    expect = hist[0, -1] + (np.arange(1, 21) / 30.0)[:, None] * np.array([1.0, 0.5])
    assert np.abs(fc.positions[0] - expect).max() < 0.1
    # 30 frames = 3 samples at 0.4 s: padded backwards at the first velocity, still continued
    padded = model.predict(PredictionQuery(np.arange(1), hist[:, -30:], dt=1 / 30, horizon=20))
    assert padded.info == {"n_short_history": 0, "n_padded_history": 1}
    assert np.abs(padded.positions[0] - expect).max() < 0.1
    short = PredictionQuery(np.arange(1), hist[:, -10:], dt=1 / 30, horizon=5)
    assert model.predict(short).info["n_short_history"] == 1


def test_clear_errors():
    with pytest.raises(ValueError, match="no weights"):
        SklearnPredictor().predict(PredictionQuery(np.arange(1), np.zeros((1, 8, 2)), 0.4, 3))
    with pytest.raises(ValueError, match="unknown scikit-learn regressor"):
        SklearnPredictor("Nope").fit(*synthetic_windows(20), dt=0.4)
