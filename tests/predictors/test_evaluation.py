"""Predictor evaluation protocol: ETH/UCY windows, ADE/FDE, the CLI and its CSV."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from conformal_control.cli import main
from conformal_control.data.ethucy import read_ethucy
from conformal_control.predictors import ConstantVelocityPredictor
from conformal_control.predictors.evaluation import (
    Windows,
    dataset_windows,
    evaluate_predictor,
    resample_future,
    resample_history,
    windows_from_tracks,
)

# Schöller et al. 2020, constant velocity model (last displacement only)
PUBLISHED_ADE = {"hotel": 0.32, "zara1": 0.43, "zara2": 0.32}


@pytest.mark.parametrize("scene", sorted(PUBLISHED_ADE))
def test_constant_velocity_reproduces_schoeller(ethucy_dir, scene):
    win = dataset_windows(f"ethucy:{scene}", ethucy_dir)
    res = evaluate_predictor(ConstantVelocityPredictor(window=1), win)
    assert abs(res["ade"] - PUBLISHED_ADE[scene]) < 0.01, res


def test_eth_fde_matches_published(ethucy_dir):
    res = evaluate_predictor(
        ConstantVelocityPredictor(window=1), dataset_windows("ethucy:eth", ethucy_dir)
    )
    assert abs(res["fde"] - 2.28) < 0.01


def test_windows_skip_gaps_and_short_runs(ethucy_dir):
    tracks = read_ethucy(ethucy_dir / "zara1" / "test" / "crowds_zara01.txt")
    hist, fut = windows_from_tracks(tracks, 8, 12)
    assert hist.shape[1:] == (8, 2) and fut.shape[1:] == (12, 2)
    assert hist.shape[0] == fut.shape[0] > 1000
    # consecutive samples of a pedestrian are < 1 m apart at 0.4 s
    steps = np.linalg.norm(np.diff(np.concatenate([hist, fut], axis=1), axis=1), axis=-1)
    assert steps.max() < 1.5


def test_resampling_round_trip():
    t = np.arange(121) / 30.0
    hist = np.stack([t, 2 * t], axis=-1)[None]  # 1 m/s, 2 m/s
    h = resample_history(hist, 1 / 30, 0.4, 8)
    assert np.allclose(np.diff(h[0], axis=0), [0.4, 0.8])
    pred = h[0, -1] + np.arange(1, 13)[:, None] * np.array([0.4, 0.8])
    out = resample_future(pred[None], h[:, -1], 0.4, 1 / 30, 200)
    expect = h[0, -1] + (np.arange(1, 201) / 30.0)[:, None] * np.array([1.0, 2.0])
    assert np.allclose(out[0], expect)


def test_eval_predictor_cli_writes_csv(tmp_path, data_root, capsys):
    rc = main(
        [
            "eval-predictor",
            "--predictor",
            "constant_velocity",
            "--param",
            "window=1",
            "--dataset",
            "ethucy:hotel",
            "--data-root",
            str(data_root),
            "--out",
            str(tmp_path),
        ]
    )
    assert rc == 0
    rows = list(csv.DictReader((tmp_path / "results.csv").open()))
    assert list(rows[0]) == ["predictor", "dataset", "ade", "fde", "n"]
    assert rows[0]["dataset"] == "ethucy:hotel" and abs(float(rows[0]["ade"]) - 0.32) < 0.01
    assert "ADE" in capsys.readouterr().out


def test_unknown_dataset_is_clear():
    with pytest.raises(ValueError, match=r"unknown ETH/UCY recording 'ethucy:nowhere'"):
        dataset_windows("ethucy:nowhere")


def test_forecast_info_is_merged_over_batches():
    class Talky(ConstantVelocityPredictor):
        """Constant velocity reporting a counter and a message per call."""

        def predict(self, query):
            fc = super().predict(query)
            fc.info = {"n_calls": 1, "fit_errors": ["LinAlgError: singular (2 fits)"]}
            return fc

    h = np.cumsum(np.ones((5, 8, 2)), axis=1)
    f = h[:, -1:] + np.cumsum(np.ones((5, 12, 2)), axis=1)
    res = evaluate_predictor(Talky(), Windows(h, f, 0.4), batch=2)
    assert res["info"]["n_calls"] == 3
    assert res["info"]["fit_errors"] == ["LinAlgError: singular (2 fits)"] * 3
