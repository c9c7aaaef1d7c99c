"""Replay environment: recorded agents, a simulated robot, a periodic sensor."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.base import CompiledForm, Environment, first_test_instance
from ..core.jit import kernel
from ..data.scene import Scene, SparseTracks
from ..families.cbf.controller import ConformalCBFController, ControlState
from ..families.cbf.loss import CBFTruth
from ..families.cbf.pyhypot import c_hypot
from ..families.cbf.roles import Dynamics
from ..predictors.base import PredictionQuery

__all__ = ["FrameLog", "ReplayCursor", "ReplayEnvironment", "nearest_distance", "sparse_window"]


def _nearest_distance_numpy(xy: np.ndarray, x: float, y: float) -> float:
    """:func:`nearest_distance`'s numpy form (the frame log's former expression)."""
    d = np.hypot(xy[:, 0] - x, xy[:, 1] - y)
    return float(d.min()) if d.size else math.nan


@kernel(cache=True, nogil=True, python=_nearest_distance_numpy)
def nearest_distance(xy: np.ndarray, x: float, y: float) -> float:
    """The smallest distance (m) from ``(x, y)`` to the rows of ``xy`` (k, 2), NaN when
    there is none or any distance is NaN (as ``numpy.min``): numpy's ``hypot`` (the C
    library's, :func:`~conformal_control.families.cbf.pyhypot.c_hypot`) per row, without
    numpy's per-call work (the replay logs it every frame).

    Parameters
    ----------
    xy : ndarray of shape (k, 2)
        The agents' positions (m).
    x, y : float
        The robot's position (m).
    """
    best = math.nan
    for i in range(xy.shape[0]):
        d = c_hypot(xy[i, 0] - x, xy[i, 1] - y)
        if d != d:
            return math.nan
        if i == 0 or d < best:
            best = d
    return best


def _sparse_window_numpy(
    xy: np.ndarray,
    start: np.ndarray,
    length: np.ndarray,
    offset: np.ndarray,
    lo: int,
    hi: int,
    cols: np.ndarray,
) -> np.ndarray:
    """:meth:`SparseTracks.window`'s numpy form on the tracks' arrays."""
    out = np.full((cols.size, max(hi - lo, 0), 2), np.nan)
    if not cols.size or hi <= lo:
        return out
    k = np.arange(lo, hi)[None, :] - start[cols, None]
    ok = (k >= 0) & (k < length[cols, None])
    out[ok] = xy[(offset[cols, None] + k)[ok]]
    return out


@kernel(cache=True, nogil=True, python=_sparse_window_numpy)
def sparse_window(
    xy: np.ndarray,
    start: np.ndarray,
    length: np.ndarray,
    offset: np.ndarray,
    lo: int,
    hi: int,
    cols: np.ndarray,
) -> np.ndarray:
    """:meth:`~conformal_control.data.scene.SparseTracks.window` compiled (the same copies,
    without numpy's per-call work: the replay sensor reads one window per interval and the
    truth one more): positions of agents ``cols`` over frames ``lo..hi-1`` as
    ``(len(cols), hi - lo, 2)``, NaN outside their spans.

    Parameters
    ----------
    xy, start, length, offset : ndarrays
        The tracks' arrays (:class:`~conformal_control.data.scene.SparseTracks`).
    lo, hi : int
        The frames ``lo..hi-1`` (any integers).
    cols : ndarray of int64
        The agents' columns.
    """
    n = cols.size
    span = max(hi - lo, 0)
    out = np.full((n, span, 2), np.nan)
    for a in range(n):
        c = cols[a]
        first = start[c]
        size = length[c]
        row = offset[c]
        for t in range(span):
            k = lo + t - first
            if 0 <= k < size:
                out[a, t, 0] = xy[row + k, 0]
                out[a, t, 1] = xy[row + k, 1]
    return out


@dataclass(frozen=True)
class ReplayCursor(CompiledForm):
    """Where a replay environment is: what the compiled engine reads of it and puts back
    (:meth:`ReplayEnvironment.compiled_state`, :meth:`ReplayEnvironment.from_compiled`),
    so that its own :meth:`~ReplayEnvironment.sense` and :meth:`~ReplayEnvironment.reveal`
    run on the engine's state. A field left at None is left as it is.

    Attributes
    ----------
    x : ndarray or None
        The robot's state (the plant's ``state_dim`` numbers).
    frame : int or None
        The current frame (index into the scene).
    t : float or None
        Time since the start (s).
    k_start : int or None
        The frame the current interval started at.
    sensed : ndarray or None
        The columns of the agents sensed at that start (int64).
    step : int or None
        Control instants run in the interval.
    """

    kernel = "replay"
    x: np.ndarray | None = None
    frame: int | None = None
    t: float | None = None
    k_start: int | None = None
    sensed: np.ndarray | None = None
    step: int | None = None


@dataclass
class FrameLog:
    """Per-frame record of the robot (one row per replayed video frame)."""

    frame: list[int]
    t: list[float]
    state: list[np.ndarray]
    d_min: list[float]

    def arrays(self) -> dict[str, np.ndarray]:
        st = np.array([s[:4] for s in self.state]).reshape(-1, 4)
        return {
            "frame": np.array(self.frame, dtype=np.int64),
            "t": np.array(self.t, dtype=float),
            "x": st[:, 0],
            "y": st[:, 1],
            "vx": st[:, 2],
            "vy": st[:, 3],
            "d_min": np.array(self.d_min, dtype=float),
        }


def _heading(scene: Scene) -> float:
    """The robot's initial heading (rad): ``scene.meta["start_heading"]`` if given, else
    toward the first goal (used by plants with a heading, the unicycle)."""
    given = scene.meta.get("start_heading")
    if given is not None:
        return float(given)
    d = np.asarray(scene.goals[0], dtype=float) - np.asarray(scene.start, dtype=float)
    return float(math.atan2(d[1], d[0])) if np.any(d) else 0.0


class ReplayEnvironment(Environment[PredictionQuery, ControlState, np.ndarray, CBFTruth]):
    """Pedestrians replayed from a :class:`Scene`; the robot driven through ``dynamics``.

    Timing: the scene's frames are the prediction samples; each frame is split into
    ``substeps`` control instants. An interval (between two sampling times) spans
    ``tau_frames`` frames. At a sampling time the sensor returns the agents within
    ``sensing_radius`` (centre distance) of the robot with their last ``history_frames``
    positions; agents appearing during the interval are unknown until the next sampling
    time. At the end of an interval the sensor reveals the true trajectories of the agents
    sensed at its start (NaN where they vanished).

    The episode ends when the last goal is reached (within the scene's goal radius,
    checked at every control instant), when the data runs out, or after ``max_frames``
    frames.

    Parameters
    ----------
    scene : Scene
    dynamics : Dynamics
        Plant; its command is what the decision family returns (the QP velocity).
    tau_frames : int
        Frames per interval (>= 1).
    substeps : int
        Control instants per frame (>= 1).
    sensing_radius : float
        Sensor range in metres (> 0).
    history_frames : int
        Length of the histories handed to the predictor (>= 1).
    max_frames : int, optional
        Limit on the number of frames simulated.
    """

    def __init__(
        self,
        scene: Scene,
        dynamics: Dynamics,
        *,
        tau_frames: int,
        substeps: int = 4,
        sensing_radius: float = 10.0,
        history_frames: int = 120,
        max_frames: int | None = None,
    ) -> None:
        self.scene = scene
        self.dynamics = dynamics
        self.tau_frames = tau_frames
        self.substeps = substeps
        self.sensing_radius = sensing_radius
        self.history_frames = history_frames
        self.max_frames = max_frames

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        from ..data.synthetic import crossing_scene
        from ..families.cbf.dynamics import VelocityTrackingDoubleIntegrator

        dynamics = VelocityTrackingDoubleIntegrator(K_acc=10.0)
        return [
            {
                "scene": crossing_scene(duration=4.0),
                "dynamics": dynamics,
                "tau_frames": 4,
                "substeps": 2,
                "max_frames": 24,
            }
        ]

    @classmethod
    def _unit_test_family(cls) -> ConformalCBFController:
        return first_test_instance(ConformalCBFController)

    # ------------------------------------------------------------------ episode
    def reset(self) -> None:
        for name in ("tau_frames", "substeps", "history_frames"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if not (math.isfinite(self.sensing_radius) and self.sensing_radius > 0):
            raise ValueError(f"sensing_radius must be > 0, got {self.sensing_radius!r}")
        if self.max_frames is not None and self.max_frames < 1:
            raise ValueError(f"max_frames must be >= 1, got {self.max_frames!r}")
        self.scene.validate()
        sc = self.scene
        self._dt_frame = 1.0 / sc.fps
        self._dt = self._dt_frame / self.substeps
        self._fi = sc.start_index
        last = sc.n_frames - 1
        if self.max_frames is not None:
            last = min(last, sc.start_index + int(self.max_frames))
        self._last = last
        self._x = self.dynamics.initial_state(sc.start, _heading(sc))
        self._t = 0.0
        self._step = 0
        self._goal = 0
        self._done = False
        self.t_goal_: float | None = None
        self._sensed = np.zeros(0, dtype=np.int64)
        self._k_start = self._fi
        self.n_sensed_: list[int] = []
        self.log = FrameLog([], [], [], [])
        self.steps_t: list[float] = []
        self.steps_x: list[np.ndarray] = []
        self.steps_cmd: list[np.ndarray] = []
        self._goals_xy = [(float(g[0]), float(g[1])) for g in np.asarray(sc.goals)]
        self._positions = self._init_positions()
        self._index_present()
        self._log_frame()

    def _index_present(self) -> None:
        """The agents present at each frame of the episode, in one gather (the recording's
        :meth:`SparseTracks.present` per frame, as views): ``_present`` reads slices."""
        self._pres: tuple[int, int, np.ndarray, np.ndarray, np.ndarray] | None = None
        src = self._positions
        if type(src) is not SparseTracks:
            return
        f0, f1 = self.scene.start_index, self._last
        ptr = src.frame_ptr[f0 : f1 + 2]
        cols = src.frame_cols[ptr[0] : ptr[-1]]
        frames = np.repeat(np.arange(f0, f1 + 1), np.diff(ptr))
        xy = src.xy[src.offset[cols] + (frames - src.start[cols])]
        self._pres = (f0, f1, ptr - ptr[0], cols, xy)

    def _init_positions(self) -> np.ndarray | SparseTracks:
        """Agent positions the sensor, the frame log and the truth read.

        The recording itself here, as the scene stores it (:class:`SparseTracks`). A
        subclass may return a dense ``(F, M, 2)`` buffer that it fills as the episode runs
        (e.g. a crowd simulated online); called by ``reset`` once the episode's timing and
        the robot's start state are set.
        """
        return self.scene.tracks

    def _present(self, f: int) -> tuple[np.ndarray, np.ndarray]:
        """The agents present (finite x) at frame ``f``, in column order, and their
        positions ``(k, 2)``."""
        pres = self._pres
        if pres is not None and pres[0] <= f <= pres[1]:
            a, b = pres[2][f - pres[0]], pres[2][f - pres[0] + 1]
            return pres[3][a:b], pres[4][a:b]
        src = self._positions
        if isinstance(src, SparseTracks):
            return src.present(f)
        pos = src[f]
        cols = np.flatnonzero(np.isfinite(pos[:, 0]))
        return cols, pos[cols]

    @property
    def done(self) -> bool:
        return self._done

    @property
    def goal_reached(self) -> bool:
        return self.t_goal_ is not None

    def _log_frame(self) -> None:
        _, xy = self._present(self._fi)
        x = self._x
        self.log.frame.append(self.scene.first_frame + self._fi)
        self.log.t.append(self._t)
        self.log.state.append(x.copy())
        self.log.d_min.append(nearest_distance(xy, float(x[0]), float(x[1])))

    # ------------------------------------------------------------------ sensor
    def _window(self, lo: int, hi: int, idx: np.ndarray) -> np.ndarray:
        """positions[lo:hi, idx] as (N, hi - lo, 2), NaN outside the data."""
        src = self._positions
        if type(src) is SparseTracks:  # compiled (the same copies)
            cols = np.asarray(idx, dtype=np.int64)
            out: np.ndarray = sparse_window(src.xy, src.start, src.length, src.offset, lo, hi, cols)
            return out
        if isinstance(src, SparseTracks):
            return src.window(lo, hi, idx)
        n = hi - lo
        out = np.full((idx.size, n, 2), np.nan)
        a, b = max(lo, 0), min(hi, self.scene.n_frames)
        if b > a and idx.size:
            out[:, a - lo : b - lo] = src[a:b, idx].transpose(1, 0, 2)
        return out

    def sense(self) -> PredictionQuery:
        sc, fi = self.scene, self._fi
        cols, xy = self._present(fi)
        idx = cols[np.hypot(*(xy - self._x[:2]).T) <= self.sensing_radius]
        self._sensed = idx
        self._k_start = fi
        self._step = 0
        self.n_sensed_.append(int(idx.size))
        history = self._window(fi - self.history_frames + 1, fi + 1, idx)
        return PredictionQuery(
            ids=sc.agent_ids[idx],
            history=history,
            dt=self._dt_frame,
            horizon=self.tau_frames,
            t=self._t,
            frame=sc.first_frame + fi,
            scene=sc.name,
            truth_provider=lambda horizon: self._window(fi + 1, fi + 1 + horizon, idx),
        )

    def compiled_state(self) -> ReplayCursor:
        """Where the environment is (its own arrays, not copies: read them only)."""
        return ReplayCursor(self._x, self._fi, self._t, self._k_start, self._sensed, self._step)

    def from_compiled(self, cursor: ReplayCursor) -> None:
        """Put the environment where ``cursor`` says (its fields that are not None): the
        compiled engine moves the robot, the clock and the interval, then calls
        :meth:`sense` or :meth:`reveal`.

        Parameters
        ----------
        cursor : ReplayCursor
            The state to take.
        """
        if cursor.x is not None:
            self._x = cursor.x
        if cursor.frame is not None:
            self._fi = cursor.frame
        if cursor.t is not None:
            self._t = cursor.t
        if cursor.k_start is not None:
            self._k_start = cursor.k_start
        if cursor.sensed is not None:
            self._sensed = cursor.sensed
        if cursor.step is not None:
            self._step = cursor.step

    def control_instants(self) -> int:
        frames = min(self.tau_frames, self._last - self._fi)
        return max(frames, 0) * self.substeps

    def state(self) -> ControlState:
        return ControlState(
            x=self._x.copy(), t=self._t, step=self._step, goal=self.scene.goals[self._goal].copy()
        )

    # ------------------------------------------------------------------ plant
    def apply(self, decision: np.ndarray) -> None:
        if self._done:
            raise RuntimeError("apply() called on a finished episode")
        self._x = self.dynamics.step(self._x, decision, self._dt)
        self._t += self._dt
        self._step += 1
        self.steps_t.append(self._t)
        self.steps_x.append(self._x.copy())
        self.steps_cmd.append(np.asarray(decision, dtype=float).copy())
        sc = self.scene
        x, y = float(self._x[0]), float(self._x[1])
        goals = self._goals_xy  # the goals as floats (reset)
        while self._goal < len(goals):
            gx, gy = goals[self._goal]  # the distance to the goal in floats (as numpy's)
            if not math.hypot(x - gx, y - gy) <= sc.goal_radius:
                break  # (a NaN distance stops too, as before)
            self._goal += 1
        if self._goal >= len(goals):
            self._goal = len(goals) - 1
            self.t_goal_ = self._t
            self._done = True
        if self._step % self.substeps == 0:
            self._fi += 1
            if self._fi >= self._last:
                self._done = True
            if not self._done:
                self._log_frame()

    def reveal(self) -> CBFTruth:
        n_frames = -(-self._step // self.substeps)  # ceil
        samples = self._window(self._k_start, self._k_start + n_frames + 1, self._sensed)
        return CBFTruth(samples=samples, dt=self._dt_frame, substeps=self.substeps)
