"""Precomputed predictions read from a CSV file (``frame,track_id,step,x,y``).

Published predictors are often available only as their predictions on a dataset (e.g. the
Trajectron++ predictions on the ETH/UCY test scenes that other projects ship). A
:class:`RecordedPredictor` replays them in closed loop:

* the file has a header with the columns ``frame``, ``track_id``, ``step``, ``x`` and ``y``
  (in any order, other columns ignored; plain or gzip-compressed). A row is the position
  (metres, the scene's coordinates) that the forecast issued at ``frame`` predicts for
  agent ``track_id`` ``step`` steps ahead (``step`` = 1, 2, ...);
* times: CSV frame ``f`` is the time ``f * step_s / frames_per_step`` (ETH/UCY files step
  by 10 frames per 0.4 s sample: ``step_s=0.4``, ``frames_per_step=10``); the scene's
  frame ``F`` is ``F * dt`` (the query's spacing), the same clock when the scene's frames
  count from the same origin, as the ETH/UCY loader's do;
* at a sampling time t the most recent forecast issued at or before t is used: its points
  at t_f + step * step_s later than t, anchored at the agent's current position at t, are
  interpolated linearly at the requested times t + dt, ..., t + horizon dt (a requested
  time equal to a point's returns the CSV's value exactly); beyond the forecast's last
  step the last segment's velocity is held (``n_extrapolated``).

Counted fallbacks (``Forecast.info``): an agent without a forecast at that issue time (or
no forecast issued yet) is predicted by ``fallback_predictor`` (constant velocity by default;
``n_missing``); missing steps of a forecast are skipped (``n_missing_steps``); an agent
whose current position is not finite gets NaN (``n_nonfinite_current``). A file with a
missing column, a non-numeric or non-finite value, a step < 1 or above :data:`MAX_STEP`, a
frame or track id beyond 2^53, or a duplicated (frame, track_id, step) is refused with a
one-line error naming the file and the line (never echoing the file's contents: a path
given by mistake, or by a replayed configuration, may name any file). The file is read
through :func:`~conformal_control.core.fileio.read_limited`: a regular file of at most
:data:`MAX_FILE_BYTES` (decompressed, for a gzip file; a corrupt gzip file is a one-line
error), never a FIFO or a device. Each issue frame's forecasts are an array of its own
agents by its own longest step, so memory follows the file's rows.
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.base import CompiledForm
from ..core.exceptions import DataFormatError
from ..core.fileio import read_limited
from .base import Forecast, PredictionQuery, Predictor
from .shift import resolve_predictor

__all__ = [
    "COLUMNS",
    "MAX_FILE_BYTES",
    "MAX_STEP",
    "RecordedForm",
    "RecordedPredictions",
    "RecordedPredictor",
    "read_predictions",
]

#: The columns a predictions file must have.
COLUMNS = ("frame", "track_id", "step", "x", "y")
#: The largest predictions file read (bytes, decompressed): the published Trajectron++
#: files are about 2 MB each.
MAX_FILE_BYTES = 128 << 20
#: The longest forecast (steps ahead) a file may hold: 12 for the published files.
MAX_STEP = 1000
#: Frame numbers and track ids are read as doubles: beyond 2^53 they are no longer exact.
_MAX_EXACT = float(2**53)


@dataclass(frozen=True)
class RecordedPredictions:
    """The forecasts of one file, indexed by issue frame.

    Attributes
    ----------
    path : str
    frames : ndarray of shape (F,)
        Issue frames, increasing.
    ids : list of ndarray
        Per issue frame, the agents' ids (sorted).
    points : list of ndarray
        Per issue frame, positions of shape (n, S, 2) at steps 1..S (NaN where the file has
        no row).
    n_rows : int
    """

    path: str
    frames: np.ndarray
    ids: list[np.ndarray]
    points: list[np.ndarray]
    n_rows: int


def read_predictions(path: str | os.PathLike[str]) -> RecordedPredictions:
    """Read and index a predictions file (see the module docstring).

    Parameters
    ----------
    path : str or os.PathLike
        A CSV file ``frame,track_id,step,x,y`` (plain or gzip-compressed).

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        A malformed, oversized or unreadable file (a
        :class:`~conformal_control.core.exceptions.DataFormatError`; the message names the file,
        and the line where it applies).
    """
    p = Path(path)
    raw = read_limited(p, MAX_FILE_BYTES, what="predictions file", gzip_ok=True)
    text = raw.decode("utf-8", "replace")
    header, _, body = text.partition("\n")
    names = [h.strip() for h in header.strip().split(",")]
    absent = [c for c in COLUMNS if c not in names]
    if absent:
        raise DataFormatError(
            f"{p}: missing column(s) {', '.join(absent)}: its first line must be a header "
            f"naming the columns {','.join(COLUMNS)} (is it a predictions file?)"
        )
    cols = [names.index(c) for c in COLUMNS]
    lines = body.splitlines()
    data = np.empty((len(lines), len(COLUMNS)))
    n = 0
    for lineno, line in enumerate(lines, start=2):
        if not line.strip():
            continue
        parts = line.split(",")
        try:
            row = [float(parts[c]) for c in cols]
        except (IndexError, ValueError):
            raise DataFormatError(
                f"{p}:{lineno}: expected numbers in columns {','.join(COLUMNS)}"
            ) from None
        if not all(math.isfinite(v) for v in row):
            raise DataFormatError(f"{p}:{lineno}: non-finite value")
        data[n] = row
        n += 1
    data = data[:n]
    if n == 0:
        raise DataFormatError(f"{p}: no prediction rows")
    ints = data[:, :3]
    bad = np.flatnonzero((ints != np.round(ints)).any(axis=1) | (data[:, 2] < 1))
    if bad.size:
        raise DataFormatError(
            f"{p}: row {int(bad[0]) + 1}: frame and track_id must be integers and step an "
            f"integer >= 1, got {data[bad[0], :3].tolist()}"
        )
    big = np.flatnonzero((np.abs(data[:, :2]) > _MAX_EXACT).any(axis=1))
    if big.size:
        raise DataFormatError(
            f"{p}: row {int(big[0]) + 1}: frame and track_id must lie within +-2^53 (they "
            f"are not exact beyond), got {data[big[0], :2].tolist()}"
        )
    long = np.flatnonzero(data[:, 2] > MAX_STEP)
    if long.size:
        raise DataFormatError(
            f"{p}: row {int(long[0]) + 1}: step {data[long[0], 2]:.0f} is beyond {MAX_STEP}, "
            "the longest forecast read"
        )
    frame, tid, step = (data[:, i].astype(np.int64) for i in range(3))
    order = np.lexsort((step, tid, frame))
    frame, tid, step, xy = frame[order], tid[order], step[order], data[order, 3:5]
    dup = (np.diff(frame) == 0) & (np.diff(tid) == 0) & (np.diff(step) == 0)
    if dup.any():
        i = int(np.flatnonzero(dup)[0])
        raise DataFormatError(
            f"{p}: duplicated prediction for frame {frame[i]}, track_id {tid[i]}, step {step[i]}"
        )
    frames, starts = np.unique(frame, return_index=True)
    bounds = [*starts.tolist(), frame.size]
    ids_out: list[np.ndarray] = []
    pts_out: list[np.ndarray] = []
    for a, b in itertools.pairwise(bounds):
        agents, where = np.unique(tid[a:b], return_inverse=True)
        # this issue frame's own longest step: memory follows the rows (one far step
        # in one forecast used to widen every frame's array)
        pts = np.full((agents.size, int(step[a:b].max()), 2), np.nan)
        pts[where, step[a:b] - 1] = xy[a:b]
        ids_out.append(agents)
        pts_out.append(pts)
    return RecordedPredictions(str(p), frames, ids_out, pts_out, n)


#: (path, size, mtime) -> predictions: every episode builds its own predictor, the file is
#: read once per process
_CACHE: dict[tuple[str, int, int], RecordedPredictions] = {}


def _cached(path: Path) -> RecordedPredictions:
    try:
        st = path.stat()
    except OSError:
        raise FileNotFoundError(f"predictions file not found: {path}") from None
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    hit = _CACHE.get(key)
    if hit is None:
        hit = read_predictions(path)
        if len(_CACHE) >= 8:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = hit
    return hit


def _source(
    path: Any, step_s: float, frames_per_step: float, data_root: str | None, scene: str
) -> tuple[Path, float, float]:
    """The file, step length and CSV frames per step a :class:`RecordedPredictor` with
    these parameters uses for ``scene`` (one-line ``ValueError`` for a scene the mapping
    does not cover or a malformed entry)."""
    spec: Any = path
    step, per_step = float(step_s), float(frames_per_step)
    if isinstance(spec, Mapping):
        if scene not in spec:
            raise ValueError(
                f"no recorded predictions for scene {scene!r}; the files cover "
                f"{', '.join(map(str, spec)) or 'no scene'}"
            )
        spec = spec[scene]
        if isinstance(spec, Mapping):
            unknown = sorted(set(spec) - {"file", "step_s", "frames_per_step"})
            if unknown or "file" not in spec:
                raise ValueError(
                    f"path[{scene!r}] must be a file or a dict with 'file' (and optionally "
                    f"'step_s', 'frames_per_step'), got {dict(spec)!r}"
                )
            step = float(spec.get("step_s", step))
            per_step = float(spec.get("frames_per_step", per_step))
            spec = spec["file"]
    p = Path(str(spec)).expanduser()
    if not p.is_absolute() and not p.exists():
        from ..data.paths import PART_MARKERS, data_part, resolve_data_root

        part, *rest = p.parts
        if part in PART_MARKERS and rest:  # external/...: wherever that part is
            p = data_part(part, data_root).joinpath(*rest)
        else:
            p = resolve_data_root(data_root) / p
    return p, step, per_step


@dataclass(frozen=True)
class RecordedForm(CompiledForm):
    """:class:`RecordedPredictor` as the compiled engine runs it: its parameters, validated,
    and its fallback predictor, built (the engine compiles the recorded forecasts when it
    compiles the fallback too, and calls the predictor itself otherwise).

    Attributes
    ----------
    path : str or dict
        The predictions file, or a dict scene name -> file (see :class:`RecordedPredictor`).
    step_s : float
        Time between two prediction steps (s).
    frames_per_step : float
        CSV frame numbers per step.
    data_root : str or None
        Folder relative paths are resolved against.
    fallback : Predictor
        The predictor of agents without a recorded forecast (reset).
    """

    kernel = "recorded"
    path: Any
    step_s: float
    frames_per_step: float
    data_root: str | None
    fallback: Predictor

    def source(self, scene: str) -> tuple[RecordedPredictions, float, float]:
        """The indexed predictions, step length (s) and CSV frames per step the predictor
        uses on ``scene``, read as it reads them (its errors: a scene the mapping does
        not cover, a missing or malformed file).

        Parameters
        ----------
        scene : str
            The scene's name (a query's ``scene``).
        """
        p, step_s, per_step = _source(
            self.path, self.step_s, self.frames_per_step, self.data_root, scene
        )
        return _cached(p), step_s, per_step


# compiled: the engine replays the forecasts compiled (its RecordedForm; not inherited)
class RecordedPredictor(Predictor, compiled="recorded", batchable=True):
    """Precomputed predictions replayed from a CSV ``frame,track_id,step,x,y`` (gzip too).

    See :mod:`conformal_control.predictors.recorded` for the file, the clock and the
    interpolation. Relative paths are resolved against ``data_root`` (default: the data
    folder, ``$CONFORMAL_CONTROL_DATA`` or ``./data``) when they do not exist as given.

    Parameters
    ----------
    path : str or dict
        The predictions file, or a dict scene name -> file (the scene name of the query,
        e.g. ``biwi_eth``; a scene without an entry is an error). A dict's value may be a
        dict ``{"file": ..., "step_s": ..., "frames_per_step": ...}`` (a scene whose clock
        differs).
    step_s : float
        Time between two prediction steps, in seconds (> 0; 0.4 for ETH/UCY).
    frames_per_step : float
        CSV frame numbers per step (> 0; 10 for the ETH/UCY files): CSV frame f is at
        ``f * step_s / frames_per_step`` seconds.
    fallback_predictor : str
        Registered predictor for agents without a recorded forecast (counted).
    data_root : str, optional
        Folder that relative paths are resolved against.
    """

    def __init__(
        self,
        path: str | Mapping[str, str] = "",
        step_s: float = 0.4,
        frames_per_step: float = 10.0,
        fallback_predictor: str = "constant_velocity",
        data_root: str | None = None,
    ) -> None:
        self.path = path
        self.step_s = step_s
        self.frames_per_step = frames_per_step
        self.fallback_predictor = fallback_predictor
        self.data_root = data_root

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        from importlib import resources

        file = str(resources.files("conformal_control.predictors") / "unit_test_recorded.csv")
        return [{"path": file, "step_s": 0.4, "frames_per_step": 1.0}]

    def reset(self) -> None:
        for name in ("step_s", "frames_per_step"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        if not isinstance(self.path, (str, os.PathLike, Mapping)) or not self.path:
            raise ValueError(
                f"path must be a predictions file or a dict scene -> file, got {self.path!r}"
            )
        self.fallback_ = resolve_predictor(self.fallback_predictor, None, "RecordedPredictor")
        self.fallback_.reset()
        self.counts_: dict[str, int] = {}

    def _source(self, scene: str) -> tuple[Path, float, float]:
        """The file, step length and CSV frames per step used for ``scene``."""
        return _source(self.path, self.step_s, self.frames_per_step, self.data_root, scene)

    def compiled_state(self) -> RecordedForm:
        """This predictor as the compiled engine runs it (validated; reset if it was not)."""
        if not hasattr(self, "fallback_"):
            self.reset()
        return RecordedForm(
            self.path,
            float(self.step_s),
            float(self.frames_per_step),
            self.data_root,
            self.fallback_,
        )

    def predictions(self, scene: str) -> RecordedPredictions:
        """The indexed predictions used for ``scene``."""
        return _cached(self._source(scene)[0])

    def predict(self, query: PredictionQuery) -> Forecast:
        if not hasattr(self, "fallback_"):
            self.reset()
        n, H = query.n_agents, int(query.horizon)
        info = {"n_missing": 0, "n_missing_steps": 0, "n_extrapolated": 0}
        out = np.full((n, H, 2), np.nan)
        if n == 0:
            return Forecast(out, info=info)
        path, step_s, per_step = self._source(query.scene)
        rec = _cached(path)
        hist = np.asarray(query.history, dtype=float)
        cur = hist[:, -1]
        ok_cur = np.isfinite(cur).all(axis=1)
        dt = float(query.dt)
        t_q = int(query.frame) * dt
        f_s = step_s / per_step
        # the latest forecast issued at or before t_q (a tolerance for the clocks' rounding)
        k = int(np.searchsorted(rec.frames * f_s, t_q + 1e-9, side="right")) - 1
        times = t_q + dt * np.arange(1, H + 1)
        need_fallback = np.ones(n, dtype=bool)
        if k >= 0:
            t_f = float(rec.frames[k]) * f_s
            ids, pts = rec.ids[k], rec.points[k]
            qids = np.asarray(query.ids).astype(np.int64)
            pos = np.searchsorted(ids, qids)
            found = (pos < ids.size) & (ids[np.minimum(pos, ids.size - 1)] == qids)
            knots_t = t_f + step_s * np.arange(1, pts.shape[1] + 1)
            # a requested time within 1e-9 s of a knot is that knot (exact CSV values)
            near = np.abs(times[:, None] - knots_t[None, :]) < 1e-9
            times_snapped = np.where(near.any(axis=1), knots_t[np.argmax(near, axis=1)], times)
            for i in np.flatnonzero(found & ok_cur).tolist():
                row = pts[pos[i]]
                have = np.isfinite(row).all(axis=1) & (knots_t > t_q + 1e-9)
                info["n_missing_steps"] += int((~np.isfinite(row).all(axis=1)).sum())
                if not have.any():
                    continue
                kt = np.concatenate([[t_q], knots_t[have]])
                kp = np.concatenate([cur[i][None], row[have]], axis=0)
                for ax in range(2):
                    out[i, :, ax] = np.interp(times_snapped, kt, kp[:, ax])
                beyond = times_snapped > kt[-1] + 1e-9
                if beyond.any():
                    if kt.size >= 2:
                        v = (kp[-1] - kp[-2]) / (kt[-1] - kt[-2])
                    else:
                        v = np.zeros(2)
                    out[i, beyond] = kp[-1] + (times_snapped[beyond] - kt[-1])[:, None] * v
                    info["n_extrapolated"] += 1
                need_fallback[i] = False
        need_fallback &= ok_cur
        if need_fallback.any():
            rows = np.flatnonzero(need_fallback)
            sub = PredictionQuery(
                ids=np.asarray(query.ids)[rows],
                history=hist[rows],
                dt=query.dt,
                horizon=H,
                t=query.t,
                frame=query.frame,
                scene=query.scene,
            )
            fc = self.fallback_.predict(sub)
            out[rows] = np.asarray(fc.positions, dtype=float)[:, :H]
            info["n_missing"] += int(rows.size)
        info["n_nonfinite_current"] = int((~ok_cur).sum())
        return Forecast(out, info=info)
