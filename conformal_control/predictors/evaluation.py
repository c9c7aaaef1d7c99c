"""Predictor evaluation (ADE/FDE) and the windows learned predictors are trained on.

Standard protocol: every run of ``obs + horizon`` consecutive samples of one agent at
2.5 fps (0.4 s) is a window; the predictor sees the first ``obs`` positions (and, as in
Social-GAN / Trajectron++, nothing of the other agents is needed by the predictors here)
and predicts the next ``horizon``. ADE is the mean over windows and steps of the
Euclidean error, FDE the mean error at the last step, both in metres.

Datasets are named ``ethucy:<scene>`` (leave-one-scene-out: evaluated on
``<scene>/test``; learned predictors train on ``<scene>/train``; a recording's name,
``ethucy:crowds_zara01``, stands for its split, see
:func:`~conformal_control.data.catalog.dataset_name`) or an SDD scene,
``sdd:<scene>/video<N>`` or a paper scene name such as ``nexus_4`` (the scene's tracks at
30 fps, taken every 12th frame; learned predictors train on all of ETH/UCY, a different
data set).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..data.ethucy import ETHUCY_FPS, ETHUCY_SCENES, ethucy_files, read_ethucy
from ..data.tracks import Tracks
from .base import PredictionQuery, Predictor

__all__ = [
    "STANDARD_DT",
    "Windows",
    "dataset_windows",
    "evaluate_predictor",
    "resample_future",
    "resample_history",
    "training_windows",
    "windows_from_tracks",
]

STANDARD_DT = 1.0 / ETHUCY_FPS  # 0.4 s


@dataclass
class Windows:
    """Observed histories and true futures, one row per window (metres)."""

    history: np.ndarray  # (W, obs, 2)
    future: np.ndarray  # (W, horizon, 2)
    dt: float
    source: str = ""
    meta: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.history.shape[0])

    def subsample(self, n: int, seed: int = 0) -> Windows:
        """At most ``n`` windows drawn without replacement (seeded), in original order."""
        if n >= len(self):
            return self
        idx = np.sort(np.random.default_rng(seed).choice(len(self), size=n, replace=False))
        meta = {**self.meta, "subsampled_from": len(self), "subsample_seed": seed}
        return Windows(self.history[idx], self.future[idx], self.dt, self.source, meta)

    def fingerprint(self) -> str:
        """Hash of the content (for caches of trained weights)."""
        h = hashlib.sha256()
        for a in (self.history, self.future):
            h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
        h.update(repr(self.dt).encode())
        return h.hexdigest()[:16]


def windows_from_tracks(
    tracks: Tracks, obs: int, horizon: int, step: int = 1, stride: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Cut every run of ``obs + horizon`` samples ``step`` frames apart from each track.

    A track is split where consecutive samples are not ``step`` frames apart or a position
    is not finite; runs shorter than ``obs + horizon`` give no window.

    Parameters
    ----------
    tracks : Tracks
        The tracks (positions in metres).
    obs : int
        Observed samples per window (>= 1).
    horizon : int
        Future samples per window (>= 1).
    step : int
        Frames between consecutive samples of a run.
    stride : int
        Samples between the starts of consecutive windows of a run (1: every window).

    Returns
    -------
    history : ndarray of shape (W, obs, 2)
    future : ndarray of shape (W, horizon, 2)
        The observed and the following positions (m) of each window (W may be 0).
    """
    if obs < 1 or horizon < 1:
        raise ValueError(f"obs and horizon must be >= 1, got {obs}, {horizon}")
    length = obs + horizon
    hist, fut = [], []
    for f, xy in tracks.tracks.values():
        f = np.asarray(f)
        # split into runs of consecutive samples
        breaks = np.flatnonzero(np.diff(f) != step) + 1
        for run_f, run_xy in zip(np.split(f, breaks), np.split(xy, breaks), strict=True):
            del run_f
            ok = np.isfinite(run_xy).all(axis=1)
            if not ok.all() or len(run_xy) < length:
                continue
            for s in range(0, len(run_xy) - length + 1, stride):
                hist.append(run_xy[s : s + obs])
                fut.append(run_xy[s + obs : s + length])
    if not hist:
        return np.zeros((0, obs, 2)), np.zeros((0, horizon, 2))
    return np.asarray(hist, dtype=float), np.asarray(fut, dtype=float)


def _concat(
    parts: list[tuple[np.ndarray, np.ndarray]], obs: int, horizon: int
) -> tuple[np.ndarray, np.ndarray]:
    hs = [h for h, _ in parts if len(h)]
    fs = [f for _, f in parts if len(f)]
    if not hs:
        return np.zeros((0, obs, 2)), np.zeros((0, horizon, 2))
    return np.concatenate(hs), np.concatenate(fs)


def _parse_dataset(dataset: str) -> tuple[str, str]:
    """("ethucy", split) or ("sdd", scene name), aliases resolved by the data catalog."""
    from ..data.catalog import dataset_name

    name = dataset_name(dataset)
    if name.startswith("ethucy:"):
        return "ethucy", name[len("ethucy:") :]
    return "sdd", name


def _ethucy_windows(
    scenes: list[tuple[str, str]],
    data_root: str | os.PathLike[str] | None,
    obs: int,
    horizon: int,
    source: str,
) -> Windows:
    parts = []
    files = []
    for scene, split in scenes:
        for path in ethucy_files(scene, split, data_root):
            parts.append(windows_from_tracks(read_ethucy(path), obs, horizon))
            files.append(str(path))
    h, f = _concat(parts, obs, horizon)
    return Windows(h, f, STANDARD_DT, source, {"files": files})


def _sdd_windows(
    name: str, data_root: str | os.PathLike[str] | None, obs: int, horizon: int
) -> Windows:
    from ..data.catalog import load_scene
    from ..data.trajnet import TRAJNET_STEP

    scene = load_scene(name, data_root)
    step = round(scene.fps * STANDARD_DT)
    if step != TRAJNET_STEP:  # pragma: no cover - SDD is 30 fps
        raise ValueError(f"scene {name} at {scene.fps} fps is not a multiple of 2.5 fps")
    frames = scene.first_frame + np.arange(scene.n_frames)
    sel = frames % step == 0
    sub_frames = frames[sel] // step
    pos = scene.positions[sel]  # the dense array, once
    tracks = {}
    for j in range(pos.shape[1]):
        ok = np.isfinite(pos[:, j]).all(axis=1)
        if ok.any():
            tracks[int(scene.agent_ids[j])] = (sub_frames[ok], pos[ok, j])
    h, f = windows_from_tracks(Tracks(ETHUCY_FPS, tracks, source=scene.name), obs, horizon)
    return Windows(h, f, STANDARD_DT, f"sdd:{scene.name}", {"scene": scene.name})


def dataset_windows(
    dataset: str,
    data_root: str | os.PathLike[str] | None = None,
    obs: int = 8,
    horizon: int = 12,
) -> Windows:
    """Evaluation windows of ``dataset`` (``ethucy:<scene>`` test split, or an SDD scene).

    Parameters
    ----------
    dataset : str
        ``ethucy:<scene>`` (its test split), or ``sdd:<scene>`` / a scene name (its tracks
        at 30 fps taken every 12th frame, 0.4 s).
    data_root : str or path, optional
        The data folder (holding ``ethucy/`` and ``sdd/``); None:
        ``$CONFORMAL_CONTROL_DATA``,
        else the per-user data folder
        (:func:`~conformal_control.data.paths.resolve_data_root`).
    obs : int
        Observed samples per window (0.4 s apart).
    horizon : int
        Predicted samples per window (0.4 s apart).
    """
    kind, name = _parse_dataset(dataset)
    if kind == "ethucy":
        return _ethucy_windows([(name, "test")], data_root, obs, horizon, f"ethucy:{name}")
    return _sdd_windows(name, data_root, obs, horizon)


def training_windows(
    dataset: str,
    data_root: str | os.PathLike[str] | None = None,
    obs: int = 8,
    horizon: int = 12,
) -> Windows:
    """Training windows for ``dataset``: ``<scene>/train`` for ETH/UCY (leave one scene
    out); all five ETH/UCY scenes (``*/test``, i.e. every scene once) for SDD targets.

    Parameters
    ----------
    dataset : str
        The evaluation data set the training is for, named as for
        :func:`dataset_windows`.
    data_root : str or path, optional
        The data folder (holding ``ethucy/`` and ``sdd/``); None:
        ``$CONFORMAL_CONTROL_DATA``,
        else the per-user data folder
        (:func:`~conformal_control.data.paths.resolve_data_root`). Given the SDD folder
        itself, ETH/UCY is read beside it.
    obs : int
        Observed samples per window (0.4 s apart).
    horizon : int
        Predicted samples per window (0.4 s apart).
    """
    kind, name = _parse_dataset(dataset)
    if kind == "ethucy":
        return _ethucy_windows([(name, "train")], data_root, obs, horizon, f"ethucy:{name}/train")
    return _ethucy_windows(
        [(s, "test") for s in ETHUCY_SCENES], data_root, obs, horizon, "ethucy:all"
    )


def evaluate_predictor(
    predictor: Predictor, windows: Windows, batch: int = 4096, scene: str = ""
) -> dict[str, Any]:
    """ADE/FDE (metres) of ``predictor`` over ``windows``, with merged forecast counters.

    Parameters
    ----------
    predictor : Predictor
        The predictor; asked for ``horizon`` samples at the windows' spacing (given the
        true futures only if it declares ``requires_ground_truth``).
    windows : Windows
        Observed histories and true futures (at least one window).
    batch : int
        Windows per prediction query.
    scene : str
        The scene name the queries carry (default: the windows' source).

    Returns
    -------
    dict
        ``ade`` and ``fde`` (m), ``n`` (windows) and ``info`` (the forecasts' counters
        summed, their per-reason counts merged, their messages listed).

    Raises
    ------
    ValueError
        No windows, predictions of the wrong shape, or non-finite predictions.
    """
    n = len(windows)
    if n == 0:
        raise ValueError(f"no evaluation windows in {windows.source or 'the data'}")
    horizon = windows.future.shape[1]
    errs = np.empty((n, horizon))
    info: dict[str, Any] = {}
    for s in range(0, n, batch):
        e = min(n, s + batch)
        query = PredictionQuery(
            ids=np.arange(s, e),
            history=windows.history[s:e].copy(),
            dt=windows.dt,
            horizon=horizon,
            scene=scene or windows.source,
            frame=s,
            ground_truth=windows.future[s:e].copy()
            if predictor.capabilities.requires_ground_truth
            else None,
        )
        fc = predictor.predict(query)
        pos = np.asarray(fc.positions, dtype=float)
        if pos.shape != (e - s, horizon, 2):
            expected = (e - s, horizon, 2)
            raise ValueError(f"predictor returned shape {pos.shape}, expected {expected}")
        errs[s:e] = np.linalg.norm(pos - windows.future[s:e], axis=-1)
        for k, v in fc.info.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                info[k] = info.get(k, 0) + v
            elif isinstance(v, dict):  # e.g. failure reason -> count
                merged = info.setdefault(k, {})
                for reason, c in v.items():
                    merged[reason] = merged.get(reason, 0) + c
            elif isinstance(v, (str, list, tuple)):  # messages, e.g. darts' fit_errors
                kept = info.setdefault(k, [])
                kept.extend([v] if isinstance(v, str) else [str(m) for m in v])
    if not np.isfinite(errs).all():
        raise ValueError("predictor returned non-finite positions for fully observed histories")
    return {
        "ade": float(errs.mean()),
        "fde": float(errs[:, -1].mean()),
        "n": n,
        "info": info,
    }


# ------------------------------------------------------------------------------------
# Frame-rate adaptation for models trained at 0.4 s
# ------------------------------------------------------------------------------------
def resample_history(history: np.ndarray, dt: float, model_dt: float, obs: int) -> np.ndarray:
    """The last ``obs`` samples at spacing ``model_dt`` of histories sampled at ``dt``.

    ``model_dt`` must be a whole multiple of ``dt`` (or equal). Returns (N, obs, 2), NaN
    where the history is missing or too short.

    Parameters
    ----------
    history : ndarray of shape (N, T, 2)
        Histories sampled every ``dt`` seconds, the last sample the current one (m).
    dt : float
        Their spacing (s).
    model_dt : float
        The spacing the model takes (s).
    obs : int
        Samples the model observes.
    """
    k = model_dt / dt
    kr = round(k)
    if kr < 1 or abs(k - kr) > 1e-6:
        raise ValueError(f"model spacing {model_dt} s is not a whole multiple of dt={dt} s")
    n, t, _ = history.shape
    idx = t - 1 - kr * np.arange(obs)[::-1]
    out = np.full((n, obs, 2), np.nan)
    ok = idx >= 0
    out[:, ok] = history[:, idx[ok]]
    return out


def resample_future(
    pred: np.ndarray, last: np.ndarray, model_dt: float, dt: float, horizon: int
) -> np.ndarray:
    """Interpolate predictions at ``model_dt, 2 model_dt, ...`` to ``dt, ..., horizon dt``.

    Linear interpolation through the current position ``last`` (N, 2) and ``pred``
    (N, H, 2); beyond the model's horizon the last predicted velocity is held.

    Parameters
    ----------
    pred : ndarray of shape (N, H, 2)
        The model's predictions at ``model_dt, ..., H model_dt`` seconds (m).
    last : ndarray of shape (N, 2)
        The current positions (m), at time 0.
    model_dt : float
        The model's spacing (s).
    dt : float
        The spacing wanted (s).
    horizon : int
        Samples wanted.

    Returns
    -------
    ndarray of shape (N, horizon, 2)
    """
    n, h, _ = pred.shape
    tm = model_dt * np.arange(h + 1)
    pts = np.concatenate([last[:, None, :], pred], axis=1)
    tq = dt * np.arange(1, horizon + 1)
    out = np.empty((n, horizon, 2))
    inside = tq <= tm[-1] + 1e-12
    for d in range(2):
        for i in range(n):
            out[i, inside, d] = np.interp(tq[inside], tm, pts[i, :, d])
    if (~inside).any():
        vel = (pts[:, -1] - pts[:, -2]) / model_dt
        extra = tq[~inside] - tm[-1]
        out[:, ~inside] = pts[:, -1][:, None, :] + vel[:, None, :] * extra[None, :, None]
    return out
