"""Base class of learned predictors trained on 0.4 s windows (the ETH/UCY protocol).

A :class:`WindowPredictor` sees the last ``obs`` positions of each agent at spacing
``model_dt`` and predicts ``horizon`` future positions at the same spacing. The base class
adapts any query to that: it picks every k-th sample of the history (``model_dt`` must be
a whole multiple of the query's ``dt``), interpolates the prediction back to the query's
spacing and holds the last predicted velocity beyond the model's horizon. An agent with
fewer than ``obs`` (but at least ``min_samples``) trailing samples at that spacing has its
history padded backwards at its first observed velocity (counted in
``Forecast.info["n_padded_history"]``); one with fewer falls back to constant velocity
(``n_short_history``).

Subclasses implement ``_fit_arrays`` and ``_predict_offsets`` on displacement arrays and
``save`` / ``_load``; training goes through ``conformal-control train-predictor``.
"""

from __future__ import annotations

import json
from abc import abstractmethod
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .base import Forecast, PredictionQuery, Predictor
from .constant_velocity import ConstantVelocityPredictor, trailing_valid
from .evaluation import resample_future, resample_history

__all__ = ["WindowPredictor", "synthetic_windows"]


def synthetic_windows(
    n: int = 256, obs: int = 8, horizon: int = 12, dt: float = 0.4, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Noisy straight and gently turning walks (for tiny test models)."""
    rng = np.random.default_rng(seed)
    t = obs + horizon
    speed = rng.uniform(0.3, 1.8, n)
    heading = rng.uniform(0, 2 * np.pi, n)
    turn = rng.normal(0, 0.05, n)
    ang = heading[:, None] + turn[:, None] * np.arange(t)
    step = speed[:, None, None] * dt * np.stack([np.cos(ang), np.sin(ang)], axis=-1)
    path = rng.uniform(-5, 5, (n, 1, 2)) + np.cumsum(step, axis=1)
    path += rng.normal(0, 0.01, path.shape)
    return path[:, :obs], path[:, obs:]


class WindowPredictor(Predictor):
    """Learned predictor on fixed windows of ``obs`` past / ``horizon`` future samples."""

    #: Trained by ``conformal-control train-predictor`` (see ``commands/predictors``).
    trainable: ClassVar[bool] = True

    #: Fewest samples (at ``model_dt``) for which a short history is padded backwards at
    #: its first observed velocity instead of falling back to constant velocity.
    min_samples: ClassVar[int] = 2

    obs: int
    horizon: int
    model_dt: float
    weights: str | None

    # ---------------------------------------------------------------- subclass API
    @abstractmethod
    def _fit_arrays(self, disp: np.ndarray, target: np.ndarray) -> None:
        """Fit on past displacements (W, obs-1, 2) -> future offsets (W, horizon, 2)."""

    @abstractmethod
    def _predict_offsets(self, disp: np.ndarray) -> np.ndarray:
        """Future offsets from the last position (N, horizon, 2) for displacements."""

    @abstractmethod
    def _save_model(self, folder: Path) -> None:
        """Write the fitted model's files into ``folder``."""

    @abstractmethod
    def _load_model(self, folder: Path, config: dict[str, Any]) -> None:
        """Read the model written by ``_save_model``."""

    # ---------------------------------------------------------------- training
    def fit(self, history: np.ndarray, future: np.ndarray, dt: float) -> WindowPredictor:
        """Fit on windows (W, >= obs, 2) -> (W, >= horizon, 2) sampled at ``model_dt``."""
        if abs(dt - self.model_dt) > 1e-9:
            raise ValueError(
                f"training windows are {dt} s apart, the model expects {self.model_dt}"
            )
        history = np.asarray(history, dtype=float)[:, -self.obs :]
        future = np.asarray(future, dtype=float)[:, : self.horizon]
        if history.shape[1] != self.obs or future.shape[1] != self.horizon:
            raise ValueError(
                f"need windows of {self.obs} observed and {self.horizon} future samples, got "
                f"{history.shape[1]} and {future.shape[1]}"
            )
        ok = np.isfinite(history).all(axis=(1, 2)) & np.isfinite(future).all(axis=(1, 2))
        if not ok.any():
            raise ValueError("no finite training window")
        history, future = history[ok], future[ok]
        disp = np.diff(history, axis=1)
        target = future - history[:, -1:, :]
        self._fit_arrays(disp, target)
        self.fitted_ = True
        return self

    def save(self, folder: str | Path) -> Path:
        """Write weights, normalisation and ``config.json`` into ``folder``."""
        self._require_model()
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        self._save_model(folder)
        cfg: dict[str, Any] = {"class": type(self).__name__, "params": self.get_params()}
        cfg["params"]["weights"] = None
        (folder / "config.json").write_text(json.dumps(cfg, indent=2, default=str))
        return folder

    def _require_model(self) -> None:
        if getattr(self, "fitted_", False):
            return
        if self.weights is None:
            raise ValueError(
                f"{type(self).__name__} has no weights: pass weights=FOLDER (written by "
                "`conformal-control train-predictor`) or call fit() first"
            )
        folder = Path(self.weights).expanduser()
        cfg_path = folder / "config.json"
        if not cfg_path.is_file():
            raise FileNotFoundError(f"no trained model at {folder} (config.json missing)")
        cfg = json.loads(cfg_path.read_text())
        if cfg.get("class") != type(self).__name__:
            raise ValueError(f"{folder} holds a {cfg.get('class')}, not a {type(self).__name__}")
        saved = cfg["params"]
        for name in ("obs", "horizon", "model_dt"):
            if saved.get(name) != getattr(self, name):
                raise ValueError(
                    f"weights at {folder} were trained with {name}={saved.get(name)}, but this "
                    f"predictor has {name}={getattr(self, name)}"
                )
        self._load_model(folder, cfg)
        self.fitted_ = True

    # ---------------------------------------------------------------- prediction
    def predict(self, query: PredictionQuery) -> Forecast:
        self._require_model()
        hist = np.asarray(query.history, dtype=float)
        n = hist.shape[0]
        horizon = int(query.horizon)
        out = np.array(ConstantVelocityPredictor(window=1).predict(query).positions, dtype=float)
        if n == 0:
            return Forecast(out, info={"n_short_history": 0, "n_padded_history": 0})
        win = resample_history(hist, query.dt, self.model_dt, self.obs)
        run = trailing_valid(win)
        pad = (run >= self.min_samples) & (run < self.obs)
        for i in np.flatnonzero(pad):
            first = self.obs - int(run[i])
            v = win[i, first + 1] - win[i, first]
            back = np.arange(first, 0, -1)[:, None]  # samples before the first observed
            win[i, :first] = win[i, first] - back * v
        ok = np.isfinite(win).all(axis=(1, 2))
        if ok.any():
            w = win[ok]
            offsets = self._predict_offsets(np.diff(w, axis=1))
            pred = w[:, -1:, :] + offsets
            out[ok] = resample_future(pred, w[:, -1], self.model_dt, query.dt, horizon)
        info = {"n_short_history": int((~ok).sum()), "n_padded_history": int(pad.sum())}
        return Forecast(out, info=info)
