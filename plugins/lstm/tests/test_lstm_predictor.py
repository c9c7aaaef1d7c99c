"""The LSTM predictor plugin: a tiny seeded model trains, saves, loads and predicts."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cc_lstm import LSTMPredictor
from cc_lstm.predictor import UNIT_TEST_PARAMS, UNIT_TEST_WEIGHTS, make_unit_test_weights

from conformal_control.cli import main
from conformal_control.core import registry
from conformal_control.predictors.base import PredictionQuery
from conformal_control.predictors.evaluation import Windows, evaluate_predictor
from conformal_control.predictors.learned import synthetic_windows
from conformal_control.testing import parametrize_with_checks

TINY = {"hidden": 16, "epochs": 15, "batch_size": 64}


@pytest.fixture(scope="module")
def tiny():
    return LSTMPredictor(**TINY).fit(*synthetic_windows(512, seed=0), dt=0.4)


@parametrize_with_checks([LSTMPredictor])
def test_contract(plugin, check):
    check(plugin)


def test_unit_test_params_load_the_shipped_weights_without_training(monkeypatch):
    def no_training(*args, **kwargs):
        raise AssertionError("_unit_test_params must not train")

    monkeypatch.setattr(LSTMPredictor, "_fit_arrays", no_training)
    (params,) = LSTMPredictor._unit_test_params()
    assert params["weights"] == str(UNIT_TEST_WEIGHTS)
    h, _ = synthetic_windows(3, seed=5)
    fc = LSTMPredictor(**params).predict(PredictionQuery(np.arange(3), h, dt=0.4, horizon=12))
    assert np.isfinite(fc.positions).all()


def test_shipped_weights_are_reproducible(tmp_path):
    # re-create the tiny model the package ships; it must still predict the same
    fresh = make_unit_test_weights(tmp_path / "w")
    h, _ = synthetic_windows(16, seed=7)
    q = PredictionQuery(np.arange(16), h, dt=0.4, horizon=12)
    shipped = LSTMPredictor(**UNIT_TEST_PARAMS, weights=str(UNIT_TEST_WEIGHTS)).predict(q)
    again = LSTMPredictor(**UNIT_TEST_PARAMS, weights=str(fresh)).predict(q)
    np.testing.assert_allclose(again.positions, shipped.positions, atol=1e-4)


def test_registered_and_trainable():
    assert registry.get("predictor", "lstm") is LSTMPredictor


def test_training_reduces_loss_and_beats_standing_still(tiny):
    assert tiny.train_losses_[-1] < 0.5 * tiny.train_losses_[0]
    h, f = synthetic_windows(200, seed=1)
    res = evaluate_predictor(tiny, Windows(h, f, 0.4))
    still = np.linalg.norm(f - h[:, -1:], axis=-1).mean()
    assert res["ade"] < 0.5 * still


def test_seeded_training_is_deterministic(tiny):
    again = LSTMPredictor(**TINY).fit(*synthetic_windows(512, seed=0), dt=0.4)
    assert again.train_losses_ == tiny.train_losses_


def test_save_load_by_path(tiny, tmp_path):
    folder = tiny.save(tmp_path / "w")
    assert {"model.pt", "normalisation.json", "config.json"} <= {p.name for p in folder.iterdir()}
    loaded = LSTMPredictor(weights=str(folder))
    h, _ = synthetic_windows(4, seed=2)
    q = PredictionQuery(np.arange(4), h, dt=0.4, horizon=12)
    np.testing.assert_allclose(loaded.predict(q).positions, tiny.predict(q).positions, atol=1e-6)
    with pytest.raises(ValueError, match="horizon"):
        LSTMPredictor(weights=str(folder), horizon=5).predict(q)


def test_train_predictor_command_on_a_slice(tmp_path, data_root, capsys):
    rc = main(
        [
            "train-predictor",
            "lstm",
            "--dataset",
            "ethucy:hotel",
            "--data-root",
            str(data_root),
            "--out",
            str(tmp_path / "w"),
            "--param",
            "hidden=8",
            "--param",
            "epochs=1",
            "--seed",
            "3",
        ]
    )
    assert rc == 0
    info = json.loads((tmp_path / "w" / "training.json").read_text())
    assert info["n_windows"] > 1000 and info["seed"] == 3
    assert LSTMPredictor(weights=str(tmp_path / "w"), hidden=8, epochs=1, random_state=3)
    assert "trained lstm" in capsys.readouterr().out
