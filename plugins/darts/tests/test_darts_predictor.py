"""The darts predictor plugin: registration, VARIMA fits, fallbacks, the forecast cache."""

from __future__ import annotations

import numpy as np
import pytest
from cc_darts import DartsPredictor, ForecastCache

from conformal_control import registry
from conformal_control.predictors.base import PredictionQuery


def _query(lengths, t=40, horizon=5, still=()):
    rng = np.random.default_rng(1)
    n = len(lengths)
    hist = np.full((n, t, 2), np.nan)
    for i, length in enumerate(lengths):
        steps = np.arange(length)[:, None]
        v = np.array([0.04, 0.02]) * (i + 1)
        xy = np.array([1.0, 2.0]) + steps * v + rng.normal(0, 0.005, (length, 2))
        hist[i, t - length :] = np.array([1.0, 2.0]) if i in still else xy
    return PredictionQuery(np.arange(n), hist, dt=1 / 30, horizon=horizon, scene="test")


def test_registered_through_entry_point():
    entry = next(e for e in registry.entries("predictor") if e.name == "darts")
    assert entry.origin == "conformal-control-darts"
    assert registry.get("predictor", "darts") is DartsPredictor


def test_varima_fits_then_cache_serves(tmp_path):
    q = _query([40, 40, 10, 40], still=(3,))
    p = DartsPredictor(fit_window=35, cache_path=str(tmp_path / "c.sqlite"))
    fc = p.predict(q)
    assert fc.positions.shape == (4, 5, 2) and np.isfinite(fc.positions).all()
    assert fc.info["n_fitted"] == 2 and fc.info["n_short_history"] == 1
    assert fc.info["n_degenerate"] == 1 and fc.info["n_cached"] == 0
    # a VARIMA forecast of a straight walk continues it (within 5 cm over 5 frames)
    truth = q.history[0, -1] + np.arange(1, 6)[:, None] * np.array([0.04, 0.02])
    assert np.abs(fc.positions[0] - truth).max() < 0.05
    again = DartsPredictor(fit_window=35, cache_path=str(tmp_path / "c.sqlite")).predict(q)
    assert again.info["n_cached"] == 2 and again.info["n_fitted"] == 0
    np.testing.assert_array_equal(again.positions, fc.positions)
    assert len(ForecastCache(tmp_path / "c.sqlite")) == 2


def test_fit_failures_are_counted_with_reason_and_cached(tmp_path):
    kw = {"model_params": {"p": -3, "d": 1}, "min_history": 5}
    path = str(tmp_path / "c.sqlite")
    fc = DartsPredictor(cache_path=path, **kw).predict(_query([40, 40]))
    assert fc.info["n_fit_failed"] == 2 and fc.info["fit_errors"]
    assert np.isfinite(fc.positions).all()  # constant-velocity fallback
    again = DartsPredictor(cache_path=path, **kw).predict(_query([40, 40]))
    assert again.info["n_fitted"] == 0 and again.info["n_cached"] == 2
    assert again.info["fit_errors"] == fc.info["fit_errors"]


def test_exactly_linear_motion_is_degenerate():
    q = _query([40])
    q.history[0] = np.array([1.0, 2.0]) + np.arange(40)[:, None] * np.array([0.03, 0.0])
    fc = DartsPredictor(cache=False).predict(q)
    assert fc.info["n_degenerate"] == 1 and fc.info["n_fitted"] == 0
    np.testing.assert_allclose(fc.positions[0, -1], q.history[0, -1] + [0.15, 0.0])


def test_other_model_by_name_and_parallel():
    q = _query([12, 12, 12])
    serial = DartsPredictor("NaiveDrift", {}, min_history=2, cache=False).predict(q)
    par = DartsPredictor("NaiveDrift", {}, min_history=2, cache=False, n_jobs=2).predict(q)
    assert serial.info["n_fitted"] == 3
    np.testing.assert_allclose(serial.positions, par.positions)


def test_unknown_model_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown darts model"):
        DartsPredictor("NoSuchModel").predict(_query([40]))


def test_missing_darts_reports_unavailable(monkeypatch):
    import importlib.util
    import sys

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "darts" else real(name, *a)
    )
    for mod in ("cc_darts", "cc_darts.predictor"):
        monkeypatch.delitem(sys.modules, mod)
    entry = registry.PluginEntry("predictor", "darts", "cc_darts:DartsPredictor", "test")
    assert not entry.available
    assert "needs the 'darts' package" in entry.error
    import conformal_control  # the core still imports

    assert conformal_control.registry is registry
