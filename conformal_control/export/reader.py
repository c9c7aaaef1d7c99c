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

from ..exceptions import DataFormatError

__all__ = ["RobotTrack", "RunRecord", "read_run"]

#: CSV columns read as integers (the rest as floats, an empty cell as NaN).
_INT_COLUMNS = frozenset({"frame", "k", "n_sensed", "n_steps", "robot", "active"})


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

    @property
    def has_scene(self) -> bool:
        """Whether the per-frame scene (``animation.npz``) was read."""
        return self.frame_t is not None


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    """The columns of a CSV file written by the run directory writers."""
    if not path.is_file():
        raise FileNotFoundError(
            f"{path} not found: not a complete run directory (runs kept by benchmarks and "
            "sweeps with only config.json and metrics.json cannot be exported)"
        )
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = next(reader)
        except StopIteration:
            raise DataFormatError(f"{path} is empty (no header line)") from None
        rows = list(reader)
    cols: dict[str, list[str]] = {h: [] for h in header}
    for n, row in enumerate(rows, start=2):
        if len(row) != len(header):
            raise DataFormatError(
                f"{path}, line {n}: {len(row)} cells where the header has {len(header)}"
            )
        for h, cell in zip(header, row, strict=True):
            cols[h].append(cell)
    out: dict[str, np.ndarray] = {}
    for h, cells in cols.items():
        try:
            if h in _INT_COLUMNS:
                out[h] = np.array([int(c) for c in cells], dtype=np.int64)
            else:
                out[h] = np.array([float(c) if c else math.nan for c in cells], dtype=float)
        except ValueError as exc:
            raise DataFormatError(f"{path}, column {h}: {exc}") from None
    return out


def _load_npz(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as data:
        rec: dict[str, Any] = {k: data[k] for k in data.files}
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


def read_run(run_dir: str | Path) -> RunRecord:
    """Read a run directory written by ``conformal-control run`` (with or without
    ``--robots``) or :meth:`EpisodeResult.save`.

    Raises
    ------
    FileNotFoundError
        If the folder, its ``config.json`` or a robot's CSV files are missing.
    DataFormatError
        If a file cannot be parsed.
    """
    path = Path(run_dir)
    if not path.is_dir():
        raise FileNotFoundError(f"run directory {path} does not exist")
    cfg_path = path / "config.json"
    if not cfg_path.is_file():
        raise FileNotFoundError(f"{cfg_path} not found: {path} is not a run directory")
    try:
        config = json.loads(cfg_path.read_text())
    except json.JSONDecodeError as exc:
        raise DataFormatError(f"{cfg_path} is not valid JSON ({exc})") from None
    anim = _load_npz(path / "animation.npz")
    multi = (path / "robots").is_dir()
    scene = config.get("scene", {})
    scene_name = str(scene.get("name", "")) if isinstance(scene, dict) else str(scene)
    lambda_unit = "1/" + str(
        scene.get("units", {}).get("time_name", "s") if isinstance(scene, dict) else "s"
    )
    if multi:
        dirs = sorted(d for d in (path / "robots").iterdir() if d.name.startswith("robot_"))
        if not dirs:
            raise FileNotFoundError(f"{path / 'robots'} holds no robot_<i> folder")
        robots = [
            RobotTrack(
                f"robot_{i}",
                _read_csv(d / "trajectory.csv"),
                _read_csv(d / "intervals.csv"),
            )
            for i, d in enumerate(dirs)
        ]
    else:
        robots = [
            RobotTrack(
                "robot", _read_csv(path / "trajectory.csv"), _read_csv(path / "intervals.csv")
            )
        ]
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
    )
    if anim is None:
        if not multi:  # the goals are in the config (single-robot runs)
            g = scene.get("goals_m") if isinstance(scene, dict) else None
            if g:
                rec.goals = [np.asarray(g, dtype=float).reshape(-1, 2)]
        return rec
    rec.lambda_unit = str(anim.get("lambda_unit", rec.lambda_unit))
    rec.epsilon = float(anim.get("epsilon", rec.epsilon))
    rec.sensing_radius = float(anim.get("sensing_radius", rec.sensing_radius))
    rec.frame_t = np.asarray(anim["t"], dtype=float)
    rec.peds = np.asarray(anim["peds"], dtype=float)
    if multi:
        rec.robots_xy = np.asarray(anim["robots"], dtype=float)
        rec.active = np.asarray(anim["active"], dtype=bool)
        rec.contact = np.asarray(anim["contact_ped"], dtype=bool) | np.asarray(
            anim["contact_robot"], dtype=bool
        )
        rec.starts = np.asarray(anim["starts"], dtype=float)
        rec.goals = [g[np.isfinite(g[:, 0])] for g in np.asarray(anim["goals"], dtype=float)]
        rec.robot_radius = float(anim.get("robot_radius", rec.robot_radius))
        rec.agent_radius = float(anim.get("agent_radius", rec.agent_radius))
        return rec
    rec.robots_xy = np.asarray(anim["robot"], dtype=float)[:, None, :]
    rec.ped_ids = np.asarray(anim["ped_ids"])
    rec.starts = np.asarray(anim["start"], dtype=float).reshape(1, 2)
    rec.goals = [np.asarray(anim["goals"], dtype=float).reshape(-1, 2)]
    rec.goal_radius = float(anim.get("goal_radius", rec.goal_radius))
    track = robots[0]
    track.status = np.asarray(anim["status"], dtype=np.int8)
    track.h_true_min = np.asarray(anim["h_true_min"], dtype=float)
    k_start = np.asarray(anim["k_start"], dtype=np.int64)
    pred = np.asarray(anim["pred"], dtype=float)
    pred_cols = np.asarray(anim["pred_cols"], dtype=np.int64)
    for k in range(k_start.size):
        keep = pred_cols[k] >= 0
        if keep.any() and k_start[k] < rec.frame_t.size:
            rec.predictions.append(
                (float(rec.frame_t[k_start[k]]), pred_cols[k][keep], pred[k][keep])
            )
    return rec
