"""The darts predictor plugin: registration, VARIMA fits, fallbacks, the forecast cache."""

from __future__ import annotations

import sqlite3
import warnings

import numpy as np
import pytest
from cc_darts import DartsPredictor, ForecastCache
from cc_darts.predictor import CacheCorruptWarning

from conformal_control.core import registry
from conformal_control.families.cbf.controller import merge_forecast_info
from conformal_control.predictors.base import PredictionQuery
from conformal_control.predictors.var import VARPredictor
from conformal_control.testing import parametrize_with_checks


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


@parametrize_with_checks([DartsPredictor])
def test_contract(plugin, check):
    check(plugin)


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
    # the core Yule-Walker VAR fits the same model structure by another estimator: close
    var = VARPredictor(fit_window=35).predict(q)
    assert var.info["n_fitted"] == 2
    assert np.abs(var.positions[:2] - fc.positions[:2]).max() < 0.02


def test_fit_failures_are_counted_with_reason_and_cached(tmp_path):
    kw = {"model_params": {"p": -3, "d": 1}, "min_history": 5}
    path = str(tmp_path / "c.sqlite")
    fc = DartsPredictor(cache_path=path, **kw).predict(_query([40, 40]))
    assert fc.info["n_fit_failed"] == 2
    # a list of short messages (one per distinct reason) that the controller keeps
    errors = fc.info["fit_errors"]
    assert isinstance(errors, list) and len(errors) == 1 and errors[0].endswith("(2 fits)")
    assert all(isinstance(e, str) and len(e) <= 120 for e in errors)
    total: dict = {}
    merge_forecast_info(total, fc.info)
    merge_forecast_info(total, fc.info)
    assert total["fit_errors"] == errors * 2 and total["n_fit_failed"] == 4
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

    assert conformal_control.core.registry is registry


def _corrupt(path, how):
    if how == "garbage":
        path.write_bytes(b"this is not an sqlite file" * 100)
        return
    # a real cache whose pages are then overwritten: "database disk image is malformed"
    cache = ForecastCache(path)
    cache.put_many({f"k{i}": np.full((5, 2), float(i)) for i in range(2000)})
    raw = bytearray(path.read_bytes())
    raw[4096:] = b"\xff" * (len(raw) - 4096)
    path.write_bytes(bytes(raw))
    with pytest.raises(sqlite3.DatabaseError, match="malformed"):
        with sqlite3.connect(path) as con:
            con.execute("SELECT COUNT(*) FROM forecasts").fetchone()


@pytest.mark.parametrize("how", ["garbage", "malformed"])
def test_corrupt_cache_is_moved_aside_and_replaced(tmp_path, how):
    path = tmp_path / "darts.sqlite"
    _corrupt(path, how)
    q = _query([12, 12])
    p = DartsPredictor("NaiveDrift", {}, min_history=2, cache_path=str(path))
    with pytest.warns(CacheCorruptWarning, match=str(path)) as rec:
        fc = p.predict(q)
    assert fc.info["n_fitted"] == 2 and fc.info["n_cache_reset"] == 1
    assert np.isfinite(fc.positions).all()
    moved = list(tmp_path.glob("darts.sqlite.corrupt-*"))
    assert len(moved) == 1 and str(moved[0]) in str(rec[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error", CacheCorruptWarning)
        again = p.predict(q)  # the fresh cache works: served from it, no further warning
    assert again.info["n_cached"] == 2 and again.info["n_cache_reset"] == 0
    np.testing.assert_array_equal(again.positions, fc.positions)


@pytest.mark.parametrize("how", ["short value", "flipped byte", "wrong shape", "text row"])
def test_corrupt_rows_are_recomputed_not_served(tmp_path, how):
    """A row-level corruption (the file itself is fine) must not break later runs."""
    path = tmp_path / "darts.sqlite"
    q = _query([12, 12])
    p = DartsPredictor("NaiveDrift", {}, min_history=2, cache_path=str(path))
    first = p.predict(q)
    with sqlite3.connect(path) as con:
        (table,) = con.execute("SELECT name FROM sqlite_master WHERE type = 'table'").fetchone()
        (key, h, v) = con.execute(f"SELECT k, h, v FROM {table} LIMIT 1").fetchone()
        bad = {
            "short value": (h, bytes(v)[:-8]),
            "flipped byte": (h, bytes([v[0] ^ 1]) + bytes(v)[1:]),
            "wrong shape": (h + 3, bytes(v)),
            "text row": (-1, b"\xff\xfe not utf-8"),
        }[how]
        con.execute(f"UPDATE {table} SET h = ?, v = ? WHERE k = ?", (*bad, key))
    with pytest.warns(CacheCorruptWarning, match="failed their checksum"):
        again = p.predict(q)
    assert again.info["n_cache_bad_rows"] == 1
    assert again.info["n_cached"] == 1 and again.info["n_fitted"] == 1
    np.testing.assert_array_equal(again.positions, first.positions)
    with warnings.catch_warnings():
        warnings.simplefilter("error", CacheCorruptWarning)
        third = p.predict(q)  # the recomputed row replaced the bad one
    assert third.info["n_cached"] == 2 and third.info["n_cache_bad_rows"] == 0
