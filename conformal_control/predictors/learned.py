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
``_save_model`` / ``_load_model``; training goes through ``conformal-control
train-predictor``. :meth:`WindowPredictor.save` records the SHA-256 of every model file in
``config.json`` and loading verifies them first: a truncated, corrupt or swapped file is
refused before its bytes reach a deserialiser (see :func:`verify_model_files`).
"""

from __future__ import annotations

import hashlib
import json
from abc import abstractmethod
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..core.exceptions import InputError
from ..core.fileio import atomic_write_json
from .base import Forecast, PredictionQuery, Predictor
from .constant_velocity import ConstantVelocityPredictor, trailing_valid
from .evaluation import resample_future, resample_history

__all__ = ["WindowPredictor", "file_sha256", "synthetic_windows", "verify_model_files"]

#: Files of a weights folder that are not the model's (never hashed into ``config.json``).
_NOT_MODEL_FILES = ("config.json", "training.json")


def file_sha256(path: Path) -> str:
    """The SHA-256 (hex) of a file's bytes."""
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def verify_model_files(folder: Path, config: dict[str, Any]) -> None:
    """Check every file listed in ``config["sha256"]`` against its recorded SHA-256.

    Raises
    ------
    InputError
        Naming the first file that is missing or whose content does not match: the folder
        is corrupt (a crash or a full disk while saving) or was modified after saving.
    """
    digests = config.get("sha256")
    if digests is None:
        return  # saved before checksums were recorded: the loaders themselves are safe
    if not isinstance(digests, dict) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in digests.items()
    ):
        raise InputError(f"{folder / 'config.json'}: 'sha256' must map file names to digests")
    for name, want in sorted(digests.items()):
        path = folder / name
        if Path(name).name != name or not path.is_file():
            raise InputError(f"{path}: model file listed in config.json is missing")
        if file_sha256(path) != want:
            raise InputError(
                f"{path}: content does not match its SHA-256 in config.json (the folder is "
                "corrupt or was modified after saving); train the model again"
            )


def synthetic_windows(
    n: int = 256, obs: int = 8, horizon: int = 12, dt: float = 0.4, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Noisy straight and gently turning walks (for tiny test models).

    Each walk starts uniformly in [-5, 5]^2 m, at a speed uniform in [0.3, 1.8] m/s, with
    a heading change per step drawn from N(0, 0.05) rad, plus N(0, 0.01) m of noise.

    Parameters
    ----------
    n : int
        Walks.
    obs : int
        Observed samples per walk.
    horizon : int
        Future samples per walk.
    dt : float
        Time between samples (s).
    seed : int
        Seed of the generator.

    Returns
    -------
    history : ndarray of shape (n, obs, 2)
    future : ndarray of shape (n, horizon, 2)
        Positions (m).
    """
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


class WindowPredictor(Predictor, trainable=True):
    """Learned predictor on fixed windows of ``obs`` past / ``horizon`` future samples."""

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
        """Write weights, normalisation and ``config.json`` into ``folder``.

        ``config.json`` is written last (atomically) and lists the SHA-256 of every other
        file of the folder, which loading verifies.
        """
        self._require_model()
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        self._save_model(folder)
        cfg: dict[str, Any] = {"class": type(self).__name__, "params": self.get_params()}
        cfg["params"]["weights"] = None
        cfg["sha256"] = {
            p.name: file_sha256(p)
            for p in sorted(folder.iterdir())
            if p.is_file() and p.name not in _NOT_MODEL_FILES and not p.name.startswith(".")
        }
        atomic_write_json(folder / "config.json", cfg, default=str)
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
        try:
            cfg = json.loads(cfg_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
            raise InputError(f"{cfg_path}: not valid JSON ({exc})") from None
        if not isinstance(cfg, dict) or not isinstance(cfg.get("params"), dict):
            raise InputError(f"{cfg_path}: not a model config (no 'params' mapping)")
        if cfg.get("class") != type(self).__name__:
            raise ValueError(f"{folder} holds a {cfg.get('class')}, not a {type(self).__name__}")
        saved = cfg["params"]
        for name in ("obs", "horizon", "model_dt"):
            if saved.get(name) != getattr(self, name):
                raise ValueError(
                    f"weights at {folder} were trained with {name}={saved.get(name)}, but this "
                    f"predictor has {name}={getattr(self, name)}"
                )
        verify_model_files(folder, cfg)
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
