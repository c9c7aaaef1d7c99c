"""Training learned predictors and caching their weights (the library's side of
``conformal-control train-predictor`` and of a run whose trainable predictor has no
weights), and evaluating a predictor with a progress report.

A *trainable* predictor class declares ``trainable=True`` (its capabilities), accepts a
``weights`` constructor argument (a folder written by its ``save``), takes ``obs`` and
``horizon`` (the training windows' lengths), and implements ``fit(history, future, dt) ->
self`` on windows of (N, obs, 2) / (N, horizon, 2) and ``save(folder)``.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

from ..core.base import Plugin, param_names
from ..core.spec import RunSpec

__all__ = [
    "MIN_SCENE_WINDOWS",
    "cached_weights",
    "evaluate_with_progress",
    "scene_windows",
    "train",
    "trainable_defaults",
    "weights_for_scene",
    "with_weights",
]

#: fewest windows of a scene's own tracks a learned predictor is trained on
MIN_SCENE_WINDOWS = 64


def trainable_defaults(
    cls: type[Plugin], params: dict[str, Any], seed: int, obs: int, horizon: int
) -> None:
    """Fill in ``params`` (in place) the training settings a trainable predictor takes and
    the caller left out: the windows' lengths ``obs`` and ``horizon`` (the trainable
    protocol's arguments) and the seed, if the class declares it takes one
    (``run_values={"random_state": "seed"}``).

    Parameters
    ----------
    cls : type
        The predictor class (``capabilities.trainable``).
    params : dict
        Its constructor arguments (modified).
    seed : int
        The training's seed.
    obs : int
        Observed samples per window.
    horizon : int
        Predicted samples per window.
    """
    from ..core.spec import RunContext

    for key, value in RunContext(seed=seed).arguments(cls).items():
        params.setdefault(key, value)
    names = param_names(cls)
    for key, value in (("obs", obs), ("horizon", horizon)):
        if key in names:
            params.setdefault(key, value)


def _fit_and_save(
    name: str,
    win: Any,
    out: str | Path,
    params: dict[str, Any],
    seed: int,
    obs: int,
    horizon: int,
    dataset: str,
    command: list[str] | None = None,
) -> Path:
    """Fit predictor ``name`` on windows ``win`` and save it (with ``training.json``)."""
    from ..core import registry

    p = {k: v for k, v in params.items() if k != "weights"}
    trainable_defaults(registry.get("predictor", name), p, seed, obs, horizon)
    model = registry.create("predictor", name, **p)
    t0 = time.perf_counter()
    model.fit(win.history, win.future, win.dt)
    out = Path(out)
    model.save(out)
    info = {
        "predictor": name,
        "params": model.get_params(),
        "dataset": dataset,
        "training_source": win.source,
        "training_files": win.meta.get("files"),
        "n_windows": len(win),
        "obs": obs,
        "horizon": horizon,
        "seed": seed,
        "fit_s": round(time.perf_counter() - t0, 2),
        "command": command,
    }
    from ..core.fileio import atomic_write_json

    atomic_write_json(out / "training.json", info, default=str)
    return out


def train(
    name: str,
    dataset: str,
    data_root: str | None,
    out: str | Path,
    params: dict[str, Any],
    seed: int = 0,
    obs: int = 8,
    horizon: int = 12,
    command: list[str] | None = None,
) -> Path:
    """Train predictor ``name`` on the training windows of ``dataset`` and save it to ``out``.

    Parameters
    ----------
    name : str
        A registered trainable predictor (an ``InputError`` lists them otherwise).
    dataset : str
        ``ethucy:<scene>`` (trains on ``<scene>/train``) or an SDD scene (trains on all
        of ETH/UCY); see :func:`~conformal_control.predictors.evaluation.training_windows`.
    data_root : str, optional
        The data folder; None: ``$CONFORMAL_CONTROL_DATA``, else the per-user data folder.
    out : str or Path
        The folder the model and its ``training.json`` are written to.
    params : dict
        The predictor's constructor arguments (``weights`` ignored).
    seed : int
        Its ``random_state`` (the training's seed) when it takes one.
    obs : int
        Observed samples per training window (0.4 s apart).
    horizon : int
        Predicted samples per training window (0.4 s apart).
    command : list of str, optional
        The command line recorded in ``training.json``.

    Returns
    -------
    Path
        ``out``.
    """
    from ..core import registry
    from ..core.exceptions import InputError
    from ..core.progress import note
    from .evaluation import training_windows

    cls = registry.get("predictor", name)
    if not cls.capabilities.trainable:
        trainable = [n for n in registry.names("predictor") if _is_trainable(n)]
        raise InputError(
            f"predictor {name!r} is not trainable; the trainable ones are "
            f"{', '.join(trainable) or 'none'}"
        )
    registry.check_params("predictor", name, cls, {k: v for k, v in params.items()})
    win = training_windows(dataset, data_root, obs, horizon)
    if len(win) == 0:
        raise InputError(f"no training windows of {obs + horizon} samples in {dataset}")
    note(f"training {name} on {len(win)} windows of {win.source} -> {out}")
    return _fit_and_save(name, win, out, params, seed, obs, horizon, dataset, command)


def _is_trainable(name: str) -> bool:
    from ..core import registry

    try:
        return bool(registry.get("predictor", name).capabilities.trainable)
    except ImportError:
        return False


def _weights_folder(name: str, tag: str, params: dict[str, Any], extra: dict[str, Any]) -> Path:
    from ..core import registry
    from .cache import cache_dir

    # key on every constructor parameter (defaults included), so changed defaults retrain
    full = registry.create("predictor", name, **params).get_params()
    full.pop("weights", None)
    key = json.dumps({"n": name, "d": tag, "p": full, **extra}, sort_keys=True, default=str)
    digest = hashlib.sha256(key.encode()).hexdigest()[:12]
    return cache_dir("weights") / f"{name}-{tag.replace(':', '_')}-{digest}"


def cached_weights(
    name: str,
    dataset: str,
    data_root: str | None,
    params: dict[str, Any],
    seed: int,
    obs: int,
    horizon: int,
) -> Path:
    """Weights for a trainable predictor, trained on first use and cached.

    ``ethucy:<scene>`` trains on ``<scene>/train`` (leave one scene out); any SDD dataset
    trains on all of ETH/UCY (one cached model for every SDD scene).

    Parameters
    ----------
    name : str
        A registered trainable predictor.
    dataset : str
        The data set the weights are for (``ethucy:<scene>`` or an SDD scene).
    data_root : str, optional
        The data folder; None: ``$CONFORMAL_CONTROL_DATA``, else the per-user data folder.
    params : dict
        The predictor's constructor arguments (``weights`` ignored).
    seed : int
        Its ``random_state`` (the training's seed) when it takes one.
    obs : int
        Observed samples per training window (0.4 s apart).
    horizon : int
        Predicted samples per training window (0.4 s apart).

    Returns
    -------
    Path
        The cache folder (under ``$CONFORMAL_CONTROL_CACHE/weights``, else
        ``~/.cache/conformal-control/weights``), keyed on every constructor parameter.
    """
    if dataset.partition(":")[0] != "ethucy":
        dataset = "sdd:any"  # every SDD scene trains on all of ETH/UCY: one cached model
    folder = _weights_folder(name, dataset, params, {"s": seed, "o": obs, "h": horizon})
    if _cached_weights_ok(folder):
        return folder
    from ..core.progress import note
    from .evaluation import training_windows

    win = training_windows(dataset, data_root, obs, horizon)
    if len(win) == 0:
        from ..core.exceptions import InputError

        raise InputError(f"no training windows of {obs + horizon} samples for {dataset}")
    what = "all of ETH/UCY" if dataset == "sdd:any" else win.source
    note(
        f"training {name} on {len(win)} windows of {what} for {dataset} (first use, "
        f"cached) -> {folder}"
    )
    # trained into a private folder and renamed into place: a crash, a full disk or a
    # concurrent run never leaves a half-written cache entry under the real name
    tmp = folder.with_name(f".{folder.name}.{os.getpid()}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        _fit_and_save(name, win, tmp, params, seed, obs, horizon, dataset)
        if folder.exists():  # a stale or corrupt entry (checked above)
            shutil.rmtree(folder, ignore_errors=True)
        try:
            os.rename(tmp, folder)
        except OSError:
            if not _cached_weights_ok(folder):  # not another process's complete entry
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return folder


def _cached_weights_ok(folder: Path) -> bool:
    """Whether a cached weights folder is complete and every model file matches its
    SHA-256 in ``config.json``; a folder that exists but fails is reported (a
    :class:`~conformal_control.core.exceptions.CacheWarning`) and will be trained again.

    Entries without checksums (written by older versions) count as stale.
    """
    import warnings

    from ..core.exceptions import CacheWarning
    from .learned import verify_model_files

    if not folder.exists():
        return False
    try:
        cfg = json.loads((folder / "config.json").read_text())
        if not (folder / "training.json").is_file():
            raise ValueError("training.json is missing")
        if not isinstance(cfg, dict) or not isinstance(cfg.get("sha256"), dict):
            raise ValueError("written by an older version, without checksums")
        verify_model_files(folder, cfg)
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        warnings.warn(
            f"cached weights {folder} are not usable ({exc}); training again",
            CacheWarning,
            stacklevel=3,
        )
        return False
    return True


def scene_windows(scene: Any, obs: int = 8, horizon: int = 12) -> Any:
    """Training windows from a scene's own pedestrians *before* the robot's start frame.

    Every run of ``obs + horizon`` samples 0.4 s apart (each phase of the frame grid) of
    the positions up to the start frame; nothing after the start is used, so the run
    never trains on what it will be scored on.
    """
    import numpy as np

    from ..core.exceptions import InputError
    from ..data.tracks import Tracks
    from .evaluation import STANDARD_DT, Windows, windows_from_tracks

    step_f = scene.fps * STANDARD_DT
    step = round(step_f)
    if step < 1 or abs(step - step_f) > 1e-6:
        raise InputError(
            f"scene {scene.name} at {scene.fps:g} fps has no whole number of frames per "
            f"{STANDARD_DT} s, so learned predictors cannot be trained on it; pass "
            "--predictor-param weights=FOLDER from `conformal-control train-predictor`"
        )
    pos = scene.tracks.dense(0, scene.start_index + 1)
    hists, futs = [], []
    for phase in range(step):
        sub = pos[phase::step]
        tracks = {}
        for j in range(sub.shape[1]):
            ok = np.isfinite(sub[:, j]).all(axis=1)
            if ok.any():
                tracks[j] = (np.flatnonzero(ok), sub[ok, j])
        h, f = windows_from_tracks(Tracks(1.0 / STANDARD_DT, tracks), obs, horizon)
        hists.append(h)
        futs.append(f)
    history = np.concatenate(hists) if hists else np.zeros((0, obs, 2))
    future = np.concatenate(futs) if futs else np.zeros((0, horizon, 2))
    seconds = scene.start_index / scene.fps
    return Windows(
        history,
        future,
        STANDARD_DT,
        f"{scene.name}'s own pedestrian tracks in the {seconds:g} s before the start frame",
        {"scene": scene.name, "start_frame": scene.start_frame, "seconds": seconds},
    )


def weights_for_scene(
    name: str,
    scene: Any,
    data_root: str | None,
    params: dict[str, Any],
    seed: int,
    obs: int = 8,
    horizon: int = 12,
) -> Path:
    """Weights a learned predictor uses on ``scene`` when none are given.

    SDD scenes: trained on all of ETH/UCY (:func:`cached_weights`). Any other scene (the
    built-in one, your own): trained on that scene's own pedestrian tracks before the
    start frame (:func:`scene_windows`), so no downloaded data is needed; too few
    windows is an error asking for ``weights=FOLDER``. Both are cached.

    Parameters
    ----------
    name : str
        A registered trainable predictor.
    scene : Scene
        The scene the run replays.
    data_root : str, optional
        The data folder; None: ``$CONFORMAL_CONTROL_DATA``, else the per-user data folder.
    params : dict
        The predictor's constructor arguments (``weights`` ignored).
    seed : int
        Its ``random_state`` (the training's seed) when it takes one.
    obs : int
        Observed samples per training window (0.4 s apart).
    horizon : int
        Predicted samples per training window (0.4 s apart).

    Returns
    -------
    Path
        The cached weights' folder.
    """
    from ..core.exceptions import InputError
    from ..core.progress import note

    if "sdd_scene" in scene.meta:
        from ..data.paths import DataNotFoundError

        try:
            return cached_weights(name, "sdd:any", data_root, params, seed, obs, horizon)
        except DataNotFoundError as exc:
            raise DataNotFoundError(
                f"{name} without weights is trained on all of ETH/UCY for SDD scenes, but "
                f"{str(exc).rstrip('.')}; or pass --predictor-param weights=DIR from "
                "`conformal-control train-predictor`"
            ) from None
    win = scene_windows(scene, obs, horizon)
    if len(win) < MIN_SCENE_WINDOWS:
        raise InputError(
            f"scene {scene.name} has only {len(win)} windows of {obs + horizon} samples of its "
            f"own pedestrians before the start frame (at least {MIN_SCENE_WINDOWS} are needed "
            f"to train {name}); train it with `conformal-control train-predictor {name} "
            "--dataset ethucy:zara1 --out DIR` and pass --predictor-param weights=DIR"
        )
    tag = f"scene-{scene.name}-{win.fingerprint()}"
    folder = _weights_folder(name, tag, params, {"s": seed, "o": obs, "h": horizon})
    if not (folder / "training.json").is_file():
        note(
            f"training {name} on {len(win)} windows of {win.source} (no ETH/UCY data needed; "
            f"first use, cached) -> {folder}"
        )
        _fit_and_save(name, win, folder, params, seed, obs, horizon, f"scene:{scene.name}")
    return folder


def evaluate_with_progress(predictor: Any, win: Any, desc: str, chunk: int = 256) -> dict[str, Any]:
    """:func:`~conformal_control.predictors.evaluation.evaluate_predictor` in chunks of
    windows with a progress report; ADE/FDE weighted by chunk size, counters summed
    (predictions are per window, so the figures equal one call on all windows).

    Parameters
    ----------
    predictor : Predictor
        The predictor evaluated.
    win : Windows
        The evaluation windows.
    desc : str
        What the progress report calls the evaluation.
    chunk : int
        Windows per call.
    """
    import numpy as np

    from ..core.progress import progress
    from .evaluation import Windows, evaluate_predictor

    n = len(win)
    if n <= chunk:
        return evaluate_predictor(predictor, win)
    ade = fde = 0.0
    info: dict[str, Any] = {}
    with progress(n, desc, "windows") as bar:
        for s in range(0, n, chunk):
            e = min(n, s + chunk)
            part = Windows(win.history[s:e], win.future[s:e], win.dt, win.source, win.meta)
            r = evaluate_predictor(predictor, part)
            ade += r["ade"] * r["n"]
            fde += r["fde"] * r["n"]
            for k, v in (r["info"] or {}).items():
                if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
                    info[k] = info.get(k, 0) + v
                elif isinstance(v, dict):
                    merged = info.setdefault(k, {})
                    for reason, c in v.items():
                        merged[reason] = merged.get(reason, 0) + c
            bar.update(e - s)
    return {"ade": ade / n, "fde": fde / n, "n": n, "info": info}


def with_weights(run: RunSpec, scene: Any, data_root: str | None) -> RunSpec:
    """``run`` with weights for a trainable predictor given by name without them: its
    training settings filled in and the weights trained on the scene's data (or found in
    the cache, :func:`weights_for_scene`); any other run unchanged.

    Parameters
    ----------
    run : RunSpec
        The run.
    scene : Scene
        Its scene (trained on its own tracks when its data has no split of its own).
    data_root : str, optional
        The data folder.
    """
    name, pp = run.role("predictor")
    if not isinstance(name, str):
        return run
    from ..core import registry

    cls = registry.get("predictor", name)
    if not cls.capabilities.trainable or pp.get("weights") is not None:
        return run
    pp = dict(pp)
    trainable_defaults(cls, pp, run.seed, 8, 12)
    train_params = {k: v for k, v in pp.items() if k != "weights"}
    pp["weights"] = str(weights_for_scene(name, scene, data_root, train_params, run.seed))
    return RunSpec.from_settings(None, base=run, predictor=name, predictor_params=pp)
