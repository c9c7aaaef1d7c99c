"""Read a run directory (single robot or ``--robots``) into arrays for the exporters.

A single-robot run directory holds ``config.json``, ``trajectory.csv`` (one row per video
frame), ``intervals.csv`` (one row per interval; ``trace.csv`` is its scored rows) and,
unless the run was made without it, ``animation.npz`` (pedestrians, predictions, filter
status). A multi-robot one holds ``config.json``, ``robots/robot_<i>/trajectory.csv`` and
``intervals.csv`` per robot and ``animation.npz`` (every robot and pedestrian per frame).
:func:`read_run` reads either into a :class:`RunRecord`: every number as the files hold it
(CSV floats parse back to the same doubles; an empty cell is NaN).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...core.exceptions import DataFormatError

__all__ = ["RobotTrack", "RunRecord", "read_run"]

#: CSV columns read as integers (the rest as floats, an empty cell as NaN).
_INT_COLUMNS = frozenset({"frame", "k", "n_sensed", "n_steps", "robot", "active"})
#: The columns the exporters read from each file.
TRAJECTORY_COLUMNS = ("frame", "t", "x", "y", "vx", "vy", "d_min")
INTERVAL_COLUMNS = ("k", "t", "lambda", "loss", "loss_applied", "max_gap", "n_sensed", "n_steps")
#: The largest file of a run directory read (bytes): a run of a day at 30 frames per
#: second writes about 300 MB of ``trajectory.csv``.
MAX_FILE_BYTES = 1 << 30
#: The largest ``config.json`` read (bytes).
MAX_CONFIG_BYTES = 64 << 20
#: Times beyond this (s since the start of the run, about 31 years) are not a run's: the
#: exporters log integer nanoseconds, which must fit an unsigned 64-bit integer.
MAX_TIME_S = 1e9
_INT64_MAX = (1 << 63) - 1


@dataclass
class RobotTrack:
    """One robot of a run: its per-frame trajectory and its intervals.

    Attributes
    ----------
    name : str
        ``"robot"`` (single-robot run) or ``"robot_<i>"``.
    trajectory : dict of str to ndarray
        The columns of ``trajectory.csv``: ``frame``, ``t`` (s since the start), ``x``, ``y``
        (m), ``vx``, ``vy`` (m/s), ``d_min`` (m, nearest pedestrian; ``d_min_robot`` in
        multi-robot runs).
    intervals : dict of str to ndarray
        The columns of ``intervals.csv``: ``k``, ``t``, ``lambda`` (scene units), ``loss``,
        ``loss_applied``, ``max_gap``, ``n_sensed``, ``n_steps`` (NaN where empty).
    status : ndarray of int8, optional
        Per frame: 0 no constraint active, 1 a constraint active, 2 fallback (single-robot
        runs with ``animation.npz``).
    h_true_min : ndarray, optional
        Per frame: the smallest barrier value with the true positions (NaN if none sensed).
    """

    name: str
    trajectory: dict[str, np.ndarray]
    intervals: dict[str, np.ndarray]
    status: np.ndarray | None = None
    h_true_min: np.ndarray | None = None


@dataclass
class RunRecord:
    """A run directory's contents (see :func:`read_run`).

    Per-frame scene arrays (``frame_t``, ``peds``, ``robots_xy``, ...) come from
    ``animation.npz`` and are None without it; the robots' own CSV data is always there.
    """

    path: Path
    kind: str  # "single" or "multi"
    config: dict[str, Any]
    robots: list[RobotTrack]
    scene: str
    epsilon: float
    lambda_unit: str
    robot_radius: float
    agent_radius: float
    sensing_radius: float
    goal_radius: float
    starts: np.ndarray  # (M, 2)
    goals: list[np.ndarray]  # per robot, (G, 2)
    frame_t: np.ndarray | None = None  # (F,) s since the start
    robots_xy: np.ndarray | None = None  # (F, M, 2)
    active: np.ndarray | None = None  # (F, M) bool, multi-robot runs
    contact: np.ndarray | None = None  # (F, M) bool, multi-robot runs
    peds: np.ndarray | None = None  # (F, P, 2), NaN when absent
    ped_ids: np.ndarray | None = None  # (P,)
    #: predictions of the sensed agents at each interval's start (single-robot runs):
    #: time (s), the columns of ``peds`` predicted, positions (N, H + 1, 2)
    predictions: list[tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)
    #: ``config.json`` as read (the bytes the MCAP file attaches)
    config_bytes: bytes = b""

    @property
    def has_scene(self) -> bool:
        """Whether the per-frame scene (``animation.npz``) was read."""
        return self.frame_t is not None


def _damaged(path: Path, why: str) -> DataFormatError:
    return DataFormatError(f"{path}: {why}; the run directory is damaged (run it again)")


def _read_bytes(path: Path, cap: int) -> bytes:
    """The bytes of a regular file of at most ``cap`` bytes (a device, a FIFO or a larger
    file is refused before it is read)."""
    import os
    import stat

    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise FileNotFoundError(
            f"{path} not found: not a complete run directory (runs kept by benchmarks and "
            "sweeps with only config.json and metrics.json cannot be exported)"
        ) from None
    if not stat.S_ISREG(st.st_mode):
        raise DataFormatError(f"{path} is not a regular file")
    with path.open("rb") as fh:
        data = fh.read(cap + 1)
    if len(data) > cap:
        raise DataFormatError(f"{path} is larger than {cap / 2**20:.0f} MiB, the most read")
    return data


def _column(path: Path, h: str, cells: list[str]) -> np.ndarray:
    """One column as numbers; a bad cell is named by its line, not echoed (a file that is
    not a run's may hold anything)."""
    whole = h in _INT_COLUMNS
    values: list[Any] = []
    for n, c in enumerate(cells, start=2):
        try:
            v: Any = int(c) if whole else (float(c) if c else math.nan)
        except ValueError:
            kind = "a whole number" if whole else "a number"
            raise DataFormatError(f"{path}, line {n}, column {h}: not {kind}") from None
        if whole and not -_INT64_MAX <= v <= _INT64_MAX:
            raise _damaged(path, f"line {n}: {h} {v} is out of the range of a frame number")
        values.append(v)
    return np.array(values, dtype=np.int64 if whole else float)


def _read_csv(path: Path, required: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """The columns of a CSV file written by the run directory writers (``required``: the
    columns that must be there)."""
    import io

    text = _read_bytes(path, MAX_FILE_BYTES).decode("utf-8", "replace")
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = next(reader)
    except StopIteration:
        raise DataFormatError(f"{path} is empty (no header line)") from None
    except csv.Error as exc:
        raise _damaged(path, f"not CSV ({exc})") from None
    missing = [c for c in required if c not in header]
    if missing:
        raise _damaged(path, f"no column {', '.join(missing)}")
    cols: dict[str, list[str]] = {h: [] for h in header}
    try:
        for n, row in enumerate(reader, start=2):
            if len(row) != len(header):
                raise DataFormatError(
                    f"{path}, line {n}: {len(row)} cells where the header has {len(header)}"
                )
            for h, cell in zip(header, row, strict=True):
                cols[h].append(cell)
    except csv.Error as exc:
        raise _damaged(path, f"not CSV ({exc})") from None
    out = {h: _column(path, h, cells) for h, cells in cols.items()}
    if "t" in out:
        _check_times(path, out["t"])
    return out


def _check_times(path: Path, t: np.ndarray) -> None:
    bad = np.flatnonzero(~((t >= 0.0) & (t <= MAX_TIME_S)))
    if bad.size:
        raise _damaged(
            path,
            f"time {float(t[bad[0]])!r} s (data row {int(bad[0]) + 1}) is not in "
            f"[0, {MAX_TIME_S:g}] s since the start of the run",
        )


def _load_npz(path: Path) -> dict[str, Any] | None:
    import zipfile

    if not path.exists():
        return None
    if not path.is_file():
        raise DataFormatError(f"{path} is not a regular file")
    if path.stat().st_size > MAX_FILE_BYTES:
        cap = MAX_FILE_BYTES / 2**20
        raise DataFormatError(f"{path} is larger than {cap:.0f} MiB, the most read")
    try:
        with np.load(path, allow_pickle=False) as data:
            rec: dict[str, Any] = {k: data[k] for k in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise _damaged(path, f"not a readable .npz file ({exc})") from None
    for key, value in rec.items():
        if isinstance(value, np.ndarray) and value.ndim == 0:
            rec[key] = value.item()
    return rec


def _si(config: dict[str, Any], key: str, default: float) -> float:
    params = config.get("params", {})
    si = params.get("si", params) if isinstance(params, dict) else {}
    value = si.get(key, default) if isinstance(si, dict) else default
    try:
        return float(value)
    except (TypeError, ValueError):
        return default


def _robot_dirs(path: Path, config: dict[str, Any]) -> list[Path]:
    """``robots/robot_<i>`` of a multi-robot run, in robot order; every robot the run had
    must be there (a missing one would shift the others' names and positions)."""
    import re

    folder = path / "robots"
    found: dict[int, Path] = {}
    for d in folder.iterdir():
        m = re.fullmatch(r"robot_(\d{1,6})", d.name)
        if m and d.is_dir():
            found[int(m.group(1))] = d
    if not found:
        raise FileNotFoundError(f"{folder} holds no robot_<i> folder")
    n = config.get("n_robots")
    expected = n if isinstance(n, int) and not isinstance(n, bool) and n > 0 else max(found) + 1
    missing = [i for i in range(expected) if i not in found]
    if missing:
        raise DataFormatError(
            f"{folder} has no robot_{missing[0]:02d} of the run's {expected} robots: the run "
            "directory is damaged (run it again)"
        )
    extra = sorted(i for i in found if i >= expected)
    if extra:
        raise DataFormatError(
            f"{folder} holds robot_{extra[0]:02d}, but config.json says the run had "
            f"{expected} robots: the run directory is damaged (run it again)"
        )
    return [found[i] for i in range(expected)]


def _read_config(path: Path) -> tuple[dict[str, Any], bytes]:
    cfg_path = path / "config.json"
    if not cfg_path.is_file():
        raise FileNotFoundError(f"{cfg_path} not found: {path} is not a run directory")
    raw = _read_bytes(cfg_path, MAX_CONFIG_BYTES)
    try:
        config = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{cfg_path} is not valid JSON ({exc})") from None
    except RecursionError:
        raise DataFormatError(f"{cfg_path} is nested too deeply") from None
    if not isinstance(config, dict):
        raise _damaged(cfg_path, f"a JSON {type(config).__name__}, not an object")
    return config, raw


def read_run(run_dir: str | Path) -> RunRecord:
    """Read a run directory written by ``conformal-control run`` (with or without
    ``--robots``) or :meth:`EpisodeResult.save`.

    Every file is checked as it is read: a regular file of at most :data:`MAX_FILE_BYTES`
    (``config.json``: :data:`MAX_CONFIG_BYTES`), the columns the exporters need, at least
    one frame, times in [0, :data:`MAX_TIME_S`] s, frame numbers that fit 64 bits, every
    robot of a multi-robot run, and an ``animation.npz`` whose arrays agree.

    Parameters
    ----------
    run_dir : str or Path
        The run directory.

    Raises
    ------
    FileNotFoundError
        If the folder, its ``config.json`` or a robot's CSV files are missing.
    DataFormatError
        If a file cannot be parsed or does not hold what a run writes (one line, naming
        the file).
    """
    path = Path(run_dir)
    if not path.is_dir():
        raise FileNotFoundError(f"run directory {path} does not exist")
    config, config_bytes = _read_config(path)
    multi = (path / "robots").is_dir()
    scene = config.get("scene", {})
    if not isinstance(scene, (dict, str)):
        raise _damaged(path / "config.json", "its scene is neither an object nor a name")
    scene_name = str(scene.get("name", "")) if isinstance(scene, dict) else scene
    units = scene.get("units", {}) if isinstance(scene, dict) else {}
    time_name = units.get("time_name", "s") if isinstance(units, dict) else "s"
    lambda_unit = "1/" + str(time_name)
    if multi:
        robots = [
            RobotTrack(
                f"robot_{i}",
                _read_csv(d / "trajectory.csv", TRAJECTORY_COLUMNS),
                _read_csv(d / "intervals.csv", INTERVAL_COLUMNS),
            )
            for i, d in enumerate(_robot_dirs(path, config))
        ]
    else:
        robots = [
            RobotTrack(
                "robot",
                _read_csv(path / "trajectory.csv", TRAJECTORY_COLUMNS),
                _read_csv(path / "intervals.csv", INTERVAL_COLUMNS),
            )
        ]
    for r, where in zip(robots, _trajectory_files(path, multi, len(robots)), strict=True):
        if r.trajectory["t"].size == 0:
            raise _damaged(where, "no frame (a header line only)")
    anim = _load_npz(path / "animation.npz")
    starts = np.array(
        [[tr.trajectory["x"][0], tr.trajectory["y"][0]] for tr in robots], dtype=float
    )
    goals = [np.zeros((0, 2)) for _ in robots]
    rec = RunRecord(
        path=path,
        kind="multi" if multi else "single",
        config=config,
        robots=robots,
        scene=scene_name,
        epsilon=_si(config, "epsilon", math.nan),
        lambda_unit=lambda_unit,
        robot_radius=_si(config, "robot_radius", 0.4),
        agent_radius=_si(config, "agent_radius", 0.3),
        sensing_radius=_si(config, "sensing_radius", math.nan),
        goal_radius=_si(config, "goal_radius", 0.5),
        starts=starts,
        goals=goals,
        config_bytes=config_bytes,
    )
    if anim is None:
        if not multi:  # the goals are in the config (single-robot runs)
            g = scene.get("goals_m") if isinstance(scene, dict) else None
            if g:
                try:
                    rec.goals = [np.asarray(g, dtype=float).reshape(-1, 2)]
                except (TypeError, ValueError):
                    raise _damaged(path / "config.json", "its goals are not (x, y) pairs") from None
        return rec
    try:
        _add_scene(rec, anim)
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        if isinstance(exc, DataFormatError):
            raise
        why = f"no array {exc}" if isinstance(exc, KeyError) else str(exc)
        raise _damaged(path / "animation.npz", f"not as a run writes it ({why})") from None
    return rec


def _trajectory_files(path: Path, multi: bool, n: int) -> list[Path]:
    if not multi:
        return [path / "trajectory.csv"]
    return [path / "robots" / f"robot_{i:02d}" / "trajectory.csv" for i in range(n)]


def _add_scene(rec: RunRecord, anim: dict[str, Any]) -> None:
    """The per-frame scene of ``animation.npz``, its arrays checked against each other."""
    where = rec.path / "animation.npz"
    robots = rec.robots
    rec.lambda_unit = str(anim.get("lambda_unit", rec.lambda_unit))
    rec.epsilon = float(anim.get("epsilon", rec.epsilon))
    rec.sensing_radius = float(anim.get("sensing_radius", rec.sensing_radius))
    rec.frame_t = np.asarray(anim["t"], dtype=float).reshape(-1)
    _check_times(where, rec.frame_t)
    n = rec.frame_t.size
    rec.peds = np.asarray(anim["peds"], dtype=float)
    if rec.peds.ndim != 3 or rec.peds.shape[0] != n or rec.peds.shape[2] != 2:
        raise _damaged(where, f"peds has shape {rec.peds.shape}, expected ({n}, P, 2)")
    m = len(robots)
    if rec.kind == "multi":
        rec.robots_xy = np.asarray(anim["robots"], dtype=float)
        rec.active = np.asarray(anim["active"], dtype=bool)
        rec.contact = np.asarray(anim["contact_ped"], dtype=bool) | np.asarray(
            anim["contact_robot"], dtype=bool
        )
        if rec.robots_xy.shape != (n, m, 2) or rec.active.shape != (n, m):
            raise _damaged(
                where,
                f"robots has shape {rec.robots_xy.shape} and active {rec.active.shape}, "
                f"expected ({n}, {m}, 2) and ({n}, {m}) for {m} robots",
            )
        if rec.contact.shape != (n, m):
            raise _damaged(where, f"contacts have shape {rec.contact.shape}, expected ({n}, {m})")
        rec.starts = np.asarray(anim["starts"], dtype=float).reshape(m, 2)
        goals = np.asarray(anim["goals"], dtype=float)
        if goals.ndim != 3 or goals.shape[0] != m or goals.shape[2] != 2:
            raise _damaged(where, f"goals has shape {goals.shape}, expected ({m}, G, 2)")
        rec.goals = [g[np.isfinite(g[:, 0])] for g in goals]
        rec.robot_radius = float(anim.get("robot_radius", rec.robot_radius))
        rec.agent_radius = float(anim.get("agent_radius", rec.agent_radius))
        return
    rec.robots_xy = np.asarray(anim["robot"], dtype=float).reshape(n, 1, 2)
    rec.ped_ids = np.asarray(anim["ped_ids"]).reshape(-1)
    if rec.ped_ids.size != rec.peds.shape[1]:
        raise _damaged(where, f"{rec.ped_ids.size} pedestrian ids for {rec.peds.shape[1]} columns")
    rec.starts = np.asarray(anim["start"], dtype=float).reshape(1, 2)
    rec.goals = [np.asarray(anim["goals"], dtype=float).reshape(-1, 2)]
    rec.goal_radius = float(anim.get("goal_radius", rec.goal_radius))
    track = robots[0]
    track.status = np.asarray(anim["status"], dtype=np.int8).reshape(-1)
    track.h_true_min = np.asarray(anim["h_true_min"], dtype=float).reshape(-1)
    k_start = np.asarray(anim["k_start"], dtype=np.int64).reshape(-1)
    pred = np.asarray(anim["pred"], dtype=float)
    pred_cols = np.asarray(anim["pred_cols"], dtype=np.int64)
    kk = k_start.size
    if pred.ndim != 4 or pred.shape[0] != kk or pred.shape[-1] != 2:
        raise _damaged(where, f"pred has shape {pred.shape}, expected ({kk}, N, H, 2)")
    if pred_cols.shape != pred.shape[:2]:
        raise _damaged(where, f"pred_cols has shape {pred_cols.shape}, expected {pred.shape[:2]}")
    if pred_cols.size and int(pred_cols.max()) >= rec.peds.shape[1]:
        raise _damaged(where, "pred_cols names a pedestrian column it does not have")
    for k in range(kk):
        keep = pred_cols[k] >= 0
        if keep.any() and 0 <= k_start[k] < n:
            rec.predictions.append(
                (float(rec.frame_t[k_start[k]]), pred_cols[k][keep], pred[k][keep])
            )
