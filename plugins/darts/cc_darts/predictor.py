"""darts forecasting models per pedestrian, refit at every prediction time.

The default is the predictor of the paper's experiments, as the published code set it up:
VARIMA(p=10, d=1, trend='c') on each pedestrian's (x, y) series, refit on its last 50
samples at every prediction time. Fits are independent per pedestrian and run in parallel
(joblib, loky backend), and every forecast is stored in a persistent on-disk cache keyed
by the exact input series (which fingerprints the scene, the track and the prediction
time), the model, its parameters and the horizon: a sweep over epsilon, eta or tau, or a
rerun, computes each forecast once.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import sqlite3
import time
import warnings
from collections.abc import Callable
from contextlib import closing
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from conformal_control.core.progress import progress
from conformal_control.predictors.base import Forecast, PredictionQuery, Predictor
from conformal_control.predictors.cache import cache_dir
from conformal_control.predictors.constant_velocity import (
    ConstantVelocityPredictor,
    trailing_valid,
)

if importlib.util.find_spec("darts") is None:  # report "unavailable" without importing darts
    raise ImportError("the darts predictor needs the 'darts' package (pip install darts)")

__all__ = ["DEFAULT_MODEL_PARAMS", "CacheCorruptWarning", "DartsPredictor", "ForecastCache"]

DEFAULT_MODEL_PARAMS: dict[str, Any] = {"p": 10, "d": 1, "trend": "c"}

_T = TypeVar("_T")


class CacheCorruptWarning(RuntimeWarning):
    """The forecast cache file was unreadable; it was moved aside and replaced."""


class ForecastCache:
    """A persistent key -> (H, 2) float array store (one SQLite file, safe across processes).

    A file SQLite cannot read ("file is not a database", "database disk image is
    malformed": a crash or a full disk mid-write, or a copy gone wrong) is never fatal:
    it is moved aside to ``<name>.corrupt-<time>-<pid>`` with a :class:`CacheCorruptWarning`
    naming both files, counted in :attr:`n_reset_`, and a fresh cache takes its place
    (the forecasts are recomputed).

    Every row stores the SHA-256 of its key, shape and value; a row that fails it (a
    value of the wrong length, a flipped byte, a row written by hand) is not served: it is
    counted in :attr:`n_bad_rows_`, reported once per cache with a
    :class:`CacheCorruptWarning`, deleted, and its forecast recomputed.

    Parameters
    ----------
    path : path-like
        The SQLite file (created with its folder).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.n_reset_ = 0
        self.n_bad_rows_ = 0
        self._guard(self._create)

    def _connect(self) -> sqlite3.Connection:
        return sqlite3.connect(self.path, timeout=60)

    def _create(self) -> None:
        with closing(self._connect()) as con, con:
            # table "f" of earlier versions had no checksums: its rows are never read
            con.execute(
                "CREATE TABLE IF NOT EXISTS forecasts "
                "(k TEXT PRIMARY KEY, h INT NOT NULL, v BLOB NOT NULL, c TEXT NOT NULL)"
            )

    def _guard(self, fn: Callable[[], _T]) -> _T:
        """Run ``fn``; if the file is corrupt, move it aside, start afresh, run it again."""
        try:
            return fn()
        except sqlite3.DatabaseError as exc:
            if isinstance(exc, sqlite3.OperationalError):  # locked, read-only, ...: not ours
                raise
            self._move_aside(exc)
        self._create()
        return fn()

    def _move_aside(self, exc: Exception) -> None:
        dest = self.path.with_name(
            f"{self.path.name}.corrupt-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}"
        )
        try:
            os.replace(self.path, dest)
            where = f"moved it to {dest}"
        except FileNotFoundError:  # another process moved it first
            where = "another process already moved it aside"
        self.n_reset_ += 1
        warnings.warn(
            f"darts forecast cache {self.path} is unreadable ({exc}); {where} and continue "
            "with a fresh cache (its forecasts will be recomputed)",
            CacheCorruptWarning,
            stacklevel=4,
        )

    def get_many(self, keys: list[str]) -> dict[str, np.ndarray | str]:
        """Cached entries for the keys present: an (H, 2) array, or the reason of a failure."""
        if not keys:
            return {}
        return self._guard(lambda: self._get_many(keys))

    def _get_many(self, keys: list[str]) -> dict[str, np.ndarray | str]:
        out: dict[str, np.ndarray | str] = {}
        bad: list[str] = []
        with closing(self._connect()) as con:
            for s in range(0, len(keys), 500):
                chunk = keys[s : s + 500]
                marks = ",".join("?" * len(chunk))
                rows = con.execute(f"SELECT k, h, v, c FROM forecasts WHERE k IN ({marks})", chunk)
                for k, h, v, c in rows:
                    value = _decode_row(k, h, v, c)
                    if value is None:
                        bad.append(k)
                    else:
                        out[k] = value
            if bad:
                with con:
                    con.executemany("DELETE FROM forecasts WHERE k = ?", [(k,) for k in bad])
        if bad:
            if not self.n_bad_rows_:
                warnings.warn(
                    f"darts forecast cache {self.path}: {len(bad)} row(s) failed their "
                    "checksum; deleted, their forecasts are recomputed",
                    CacheCorruptWarning,
                    stacklevel=4,
                )
            self.n_bad_rows_ += len(bad)
        return out

    def put_many(self, items: dict[str, np.ndarray | str]) -> None:
        """Store arrays of shape (H, 2), or failure reasons (str)."""
        if not items:
            return
        rows = []
        for k, v in items.items():
            if isinstance(v, str):
                h, blob = -1, v.encode()
            else:
                h, blob = int(v.shape[0]), np.ascontiguousarray(v, dtype=np.float64).tobytes()
            rows.append((k, h, blob, _row_digest(k, h, blob)))

        def put() -> None:
            with closing(self._connect()) as con, con:
                con.executemany("INSERT OR REPLACE INTO forecasts VALUES (?, ?, ?, ?)", rows)

        self._guard(put)

    def __len__(self) -> int:
        def count() -> int:
            with closing(self._connect()) as con:
                return int(con.execute("SELECT COUNT(*) FROM forecasts").fetchone()[0])

        return self._guard(count)


def _row_digest(key: str, h: int, blob: bytes) -> str:
    """SHA-256 of one cache row (key, shape, value)."""
    d = hashlib.sha256(key.encode())
    d.update(str(h).encode() + b"\0")
    d.update(blob)
    return d.hexdigest()


def _decode_row(key: Any, h: Any, blob: Any, digest: Any) -> np.ndarray | str | None:
    """A row's value, or None if it fails its checksum or does not decode."""
    if not (isinstance(key, str) and isinstance(h, int) and isinstance(blob, bytes)):
        return None
    if digest != _row_digest(key, h, blob):
        return None
    try:
        if h < 0:
            return blob.decode()
        return np.frombuffer(blob, dtype=np.float64).reshape(h, 2).copy()
    except (ValueError, UnicodeDecodeError):
        return None


def _fit_one(
    model: str, model_params: dict[str, Any], series: np.ndarray, horizon: int
) -> tuple[np.ndarray | None, str | None]:
    """Fit ``model`` on one (T, 2) series and forecast ``horizon`` steps (worker)."""
    import logging

    import darts.models
    from darts import TimeSeries
    from threadpoolctl import threadpool_limits

    logging.getLogger("darts").setLevel(logging.CRITICAL)  # failures are counted instead
    try:
        cls = getattr(darts.models, model)
        # one BLAS thread per fit: the fits are tiny, and multi-threaded BLAS on a busy
        # machine made each VARIMA fit 10x slower; parallelism comes from n_jobs instead
        with warnings.catch_warnings(), threadpool_limits(1):
            warnings.simplefilter("ignore")
            m = cls(**model_params)
            m.fit(TimeSeries.from_values(series.astype(np.float64)))
            pred = m.predict(horizon).values()
        pred = np.asarray(pred, dtype=float).reshape(horizon, 2)
        if not np.isfinite(pred).all():
            return None, "non-finite forecast"
        return pred, None
    except Exception as exc:  # counted fallback, with its reason
        first = (str(exc).splitlines() or [""])[0]  # an empty message has no line
        name = type(exc).__name__
        return None, f"{name}: {first[:100]}" if first else name


class DartsPredictor(Predictor):
    """Any darts forecasting model per pedestrian (default: the paper's VARIMA).

    Each sensed agent's trailing run of finite positions, cut to the last ``fit_window``
    samples, is one bivariate series; the model named ``model`` (a class of
    ``darts.models``) is built with ``model_params``, fitted on it, and forecasts
    ``query.horizon`` samples at the query's spacing.

    Counted fallbacks to constant velocity (window ``fallback_window``), reported in
    ``Forecast.info``: ``n_short_history`` (fewer than ``min_history`` samples, or fewer
    than the model needs), ``n_degenerate`` (the series does not move: the VARIMA
    regression is singular), ``n_fit_failed`` (the fit raised or returned non-finite
    values; ``fit_errors`` is a list of short messages, one per distinct reason, with
    its count when above one). ``n_cached`` / ``n_fitted`` count cache hits and fits;
    ``n_cache_reset`` counts unreadable cache files moved aside and ``n_cache_bad_rows``
    cache rows that failed their checksum and were recomputed (see :class:`ForecastCache`).

    Parameters
    ----------
    model : str
        Name of a darts forecasting model class (``VARIMA``, ``ARIMA``, ``NaiveDrift``,
        ``LinearRegressionModel``, ...). Models needing a univariate series are not
        supported.
    model_params : dict or None
        Its constructor arguments; None means the paper's ``{"p": 10, "d": 1,
        "trend": "c"}`` for VARIMA and ``{}`` otherwise.
    fit_window : int
        Number of most recent samples each model is fitted on (paper: 50).
    min_history : int or None
        Minimum trailing finite samples to fit; None asks the model
        (``min_train_series_length`` + d, and at least 3p + d + 2 samples for a VAR(p):
        33 for the default VARIMA; with fewer the fit is singular).
    n_jobs : int
        Parallel fits (joblib/loky); 1 fits in-process.
    cache : bool
        Use the persistent forecast cache.
    cache_path : str or None
        SQLite file of the cache; default ``$CONFORMAL_CONTROL_CACHE/forecasts/darts.sqlite``
        (else ``~/.cache/conformal-control/...``).
    fallback_window : int
        Window (sample intervals) of the constant-velocity fallback.
    """

    def __init__(
        self,
        model: str = "VARIMA",
        model_params: dict[str, Any] | None = None,
        fit_window: int = 50,
        min_history: int | None = None,
        n_jobs: int = 1,
        cache: bool = True,
        cache_path: str | None = None,
        fallback_window: int = 5,
    ) -> None:
        self.model = model
        self.model_params = model_params
        self.fit_window = fit_window
        self.min_history = min_history
        self.n_jobs = n_jobs
        self.cache = cache
        self.cache_path = cache_path
        self.fallback_window = fallback_window

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        # contract queries have 10 samples: VARIMA falls back (counted); NaiveDrift fits.
        return [
            {"cache": False},
            {"model": "NaiveDrift", "model_params": {}, "min_history": 2, "cache": False},
        ]

    # ------------------------------------------------------------------ helpers
    def _params(self) -> dict[str, Any]:
        if self.model_params is not None:
            return dict(self.model_params)
        return dict(DEFAULT_MODEL_PARAMS) if self.model == "VARIMA" else {}

    def _min_history(self, params: dict[str, Any]) -> int:
        if self.min_history is not None:
            return int(self.min_history)
        import darts.models

        try:
            m = getattr(darts.models, self.model)(**params)
            # darts checks the length after differencing d times
            d = int(params.get("d") or 0)
            need = int(m.min_train_series_length) + d
            if "p" in params:  # VAR(p) on 2 series: >= 2p + 1 regressors per equation
                need = max(need, 3 * int(params["p"]) + d + 2)
            return need
        except Exception:  # pragma: no cover - a bad model surfaces at fit time
            return 2

    def _validate(self) -> None:
        import darts.models

        if not isinstance(self.model, str) or not hasattr(darts.models, self.model):
            raise ValueError(f"unknown darts model {self.model!r} (a class of darts.models)")
        for name in ("fit_window", "fallback_window", "n_jobs"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or (v < 1 and name != "n_jobs") or v == 0:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")

    def _key(self, series: np.ndarray, params: dict[str, Any], horizon: int) -> str:
        import darts

        h = hashlib.sha256()
        meta = json.dumps(
            [self.model, params, horizon, darts.__version__, series.shape],
            sort_keys=True,
            default=str,
        )
        h.update(meta.encode())
        h.update(np.ascontiguousarray(series, dtype=np.float64).tobytes())
        return h.hexdigest()

    def _store(self) -> ForecastCache:
        path = self.cache_path or cache_dir("forecasts") / "darts.sqlite"
        return ForecastCache(path)

    # ------------------------------------------------------------------ predict
    def predict(self, query: PredictionQuery) -> Forecast:
        self._validate()
        params = self._params()
        hist = np.asarray(query.history, dtype=float)
        n, t, _ = hist.shape
        horizon = int(query.horizon)
        fallback = ConstantVelocityPredictor(window=self.fallback_window).predict(query)
        positions = np.array(fallback.positions, dtype=float)
        info: dict[str, Any] = {
            "n_short_history": 0,
            "n_degenerate": 0,
            "n_fit_failed": 0,
            "n_cached": 0,
            "n_fitted": 0,
        }
        if n == 0:
            return Forecast(positions, info=info)
        run = trailing_valid(hist)
        need = max(self._min_history(params), 2)
        todo: dict[int, tuple[str, np.ndarray]] = {}
        for i in range(n):
            length = min(int(run[i]), int(self.fit_window))
            if length < need:
                info["n_short_history"] += 1
                continue
            series = hist[i, t - length :]
            if (
                np.ptp(series, axis=0).min() < 1e-9
                or np.ptp(np.diff(series, axis=0), axis=0).min() < 1e-9
            ):
                info["n_degenerate"] += 1
                continue
            todo[i] = (self._key(series, params, horizon), series)
        store = self._store() if self.cache else None
        hits = store.get_many([k for k, _ in todo.values()]) if store is not None else {}
        jobs = [(i, k, s) for i, (k, s) in todo.items() if k not in hits]
        errors: dict[str, int] = {}

        def fail(reason: str) -> None:
            info["n_fit_failed"] += 1
            errors[reason] = errors.get(reason, 0) + 1

        for i, (k, _) in todo.items():
            if k in hits:
                info["n_cached"] += 1
                hit = hits[k]
                if isinstance(hit, str):
                    fail(hit)  # a cached failure is not retried
                else:
                    positions[i] = hit
        results = self._run(jobs, params, horizon)
        fresh: dict[str, np.ndarray | str] = {}
        for (i, k, _), (pred, err) in zip(jobs, results, strict=True):
            info["n_fitted"] += 1
            if pred is None:
                fail(err or "unknown")
                fresh[k] = err or "unknown"
                continue
            positions[i] = pred
            fresh[k] = pred
        if store is not None:
            store.put_many(fresh)
            info["n_cache_reset"] = store.n_reset_
            info["n_cache_bad_rows"] = store.n_bad_rows_
        if errors:  # short messages, one per distinct reason (the controller keeps lists)
            info["fit_errors"] = [
                reason if c == 1 else f"{reason} ({c} fits)" for reason, c in errors.items()
            ]
        return Forecast(positions, info=info)

    def _run(
        self, jobs: list[tuple[int, str, np.ndarray]], params: dict[str, Any], horizon: int
    ) -> list[tuple[np.ndarray | None, str | None]]:
        if not jobs:
            return []
        # progress only shows when the fits of one call take more than a few seconds
        # (evaluation batches); within an episode the frames' progress covers them
        with progress(len(jobs), f"darts {self.model}", "fits", delay=3.0) as bar:
            if self.n_jobs == 1 or len(jobs) == 1:
                out = []
                for _, _, s in jobs:
                    out.append(_fit_one(self.model, params, s, horizon))
                    bar.update()
                return out
            from joblib import Parallel, delayed

            out = []
            for res in Parallel(n_jobs=self.n_jobs, backend="loky", return_as="generator")(
                delayed(_fit_one)(self.model, params, s, horizon) for _, _, s in jobs
            ):
                out.append(res)
                bar.update()
            return out
