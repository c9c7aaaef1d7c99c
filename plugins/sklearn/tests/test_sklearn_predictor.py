"""The scikit-learn predictor plugin: fit, save/load by path, any regressor, frame rates."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import skops.io
from cc_sklearn import SklearnPredictor
from cc_sklearn.predictor import UNIT_TEST_WEIGHTS, make_unit_test_weights

from conformal_control.core import registry
from conformal_control.core.exceptions import InputError
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
    assert cls is SklearnPredictor and cls.capabilities.trainable


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


# ------------------------------------------------------------------ nothing is unpickled
class _RunsCode:
    """Pickles to a call of ``Path.write_text``: loading the pickle would create a file."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.write_text, (self.marker, "code ran"))


def _weights_folder(folder: Path) -> Path:
    folder.mkdir()
    cfg = {"class": "SklearnPredictor", "params": SklearnPredictor().get_params()}
    (folder / "config.json").write_text(json.dumps(cfg))
    return folder


def test_a_pickled_model_is_refused_without_running_it(tmp_path):
    folder = _weights_folder(tmp_path / "w")
    marker = tmp_path / "pwned"
    (folder / "model.joblib").write_bytes(pickle.dumps(_RunsCode(marker)))
    q = PredictionQuery(np.arange(1), np.zeros((1, 8, 2)), 0.4, 3)
    with pytest.raises(InputError, match=r"no model\.skops .*a pickle .* not loaded"):
        SklearnPredictor(weights=str(folder)).predict(q)
    assert not marker.exists()


class Smuggled:
    """A type outside scikit-learn: skops would have to import and build it."""

    built = 0

    def __setstate__(self, state):
        Smuggled.built += 1
        self.__dict__.update(state)


def test_a_skops_file_naming_an_untrusted_type_is_refused(tmp_path):
    folder = _weights_folder(tmp_path / "w")
    evil = Smuggled()
    evil.x = 1
    (folder / "model.skops").write_bytes(skops.io.dumps({"model": evil}))
    q = PredictionQuery(np.arange(1), np.zeros((1, 8, 2)), 0.4, 3)
    with pytest.raises(InputError, match=r"outside the trusted list \(.*Smuggled"):
        SklearnPredictor(weights=str(folder)).predict(q)
    assert Smuggled.built == 0
    # garbage where the skops zip should be: one clear error, not a zipfile traceback
    (folder / "model.skops").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="not a skops model file"):
        SklearnPredictor(weights=str(folder)).predict(q)


@pytest.mark.parametrize("estimator", ["Ridge", "KNeighborsRegressor", "RandomForestRegressor"])
def test_saved_models_load_without_untrusted_types(tmp_path, estimator):
    h, f = synthetic_windows(60, seed=0)
    params = {"n_estimators": 3} if estimator == "RandomForestRegressor" else None
    model = SklearnPredictor(estimator, params).fit(h, f, dt=0.4)
    folder = model.save(tmp_path / "w")
    assert sorted(p.name for p in folder.iterdir()) == ["config.json", "model.skops"]
    q = PredictionQuery(np.arange(3), h[:3].copy(), dt=0.4, horizon=12)
    loaded = SklearnPredictor(estimator, params, weights=str(folder)).predict(q)
    np.testing.assert_allclose(loaded.positions, model.predict(q).positions)


def test_a_modified_model_file_fails_its_checksum(tmp_path):
    folder = SklearnPredictor().fit(*synthetic_windows(60), dt=0.4).save(tmp_path / "w")
    digest = json.loads((folder / "config.json").read_text())["sha256"]["model.skops"]
    data = bytearray((folder / "model.skops").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (folder / "model.skops").write_bytes(bytes(data))
    assert len(digest) == 64
    q = PredictionQuery(np.arange(1), np.zeros((1, 8, 2)), 0.4, 3)
    with pytest.raises(InputError, match="does not match its SHA-256"):
        SklearnPredictor(weights=str(folder)).predict(q)
    (folder / "model.skops").unlink()
    with pytest.raises(InputError, match="missing"):
        SklearnPredictor(weights=str(folder)).predict(q)


def test_a_corrupt_cached_model_is_trained_again(tmp_path, monkeypatch, data_root):
    from conformal_control.core.exceptions import CacheWarning
    from conformal_control.predictors.training import cached_weights

    monkeypatch.setenv("CONFORMAL_CONTROL_CACHE", str(tmp_path / "cache"))
    args = ("sklearn", "ethucy:zara1", str(data_root), {}, 0, 8, 12)
    folder = cached_weights(*args)
    for p in folder.iterdir():  # every model file truncated (a full disk while saving)
        if p.suffix != ".json":
            p.write_bytes(p.read_bytes()[:100])
    with pytest.warns(CacheWarning, match="not usable"):
        again = cached_weights(*args)
    assert again == folder
    h, _ = synthetic_windows(3, seed=5)
    q = PredictionQuery(np.arange(3), h, dt=0.4, horizon=12)
    assert np.isfinite(SklearnPredictor(weights=str(again)).predict(q).positions).all()
    assert not [p for p in folder.parent.iterdir() if p.name.startswith(".")]  # no temp left
