"""A scene: replayed agents, the ego's task, geometry, units and default parameters.

Positions are stored sparsely (:class:`SparseTracks`: each agent over its own span of
frames, plus an index of the agents present at each frame), so a scene's memory grows with
its observations, not with frames x agents: a 100,000-frame recording of 9,000 passers-by
takes about 55 MB instead of 13.4 GiB. ``Scene.positions`` still gives the dense
``(F, M, 2)`` array (the array a scene was built from, or one assembled on request); the
episode's hot paths (the replay world, the compiled engine, the measuring code) read
:attr:`Scene.tracks` and never assemble it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.exceptions import InputError
from .tracks import Tracks
from .units import SI, UnitSystem

__all__ = ["Scene", "SparseTracks", "scene_from_tracks"]


class SparseTracks:
    """Agent positions stored per agent, over the frames between its first and last sample.

    Agent ``j`` (a column of the dense array) is stored from frame ``start[j]`` for
    ``length[j]`` frames at rows ``offset[j] : offset[j] + length[j]`` of ``xy`` (NaN inside
    its span where it was not seen; ``length[j] == 0`` for an agent with no sample at all).
    ``frame_ptr`` / ``frame_cols`` index the agents present at each frame (finite x), in
    column order: those of frame ``f`` are ``frame_cols[frame_ptr[f] : frame_ptr[f + 1]]``.
    Memory is 16 bytes per stored sample and 8 per present sample (+ 8 per frame), whatever
    the number of agents.

    Parameters
    ----------
    n_frames : int
        Frames of the scene (F).
    start, length : ndarray of shape (M,)
        Each agent's first frame index and span in frames.
    xy : ndarray of shape (sum(length), 2)
        The spans' positions, agent after agent (m; NaN where absent).
    """

    __slots__ = ("frame_cols", "frame_ptr", "length", "n_frames", "offset", "start", "xy")

    def __init__(
        self, n_frames: int, start: np.ndarray, length: np.ndarray, xy: np.ndarray
    ) -> None:
        self.n_frames = int(n_frames)
        self.start = np.ascontiguousarray(start, dtype=np.int64)
        self.length = np.ascontiguousarray(length, dtype=np.int64)
        self.xy = np.ascontiguousarray(xy, dtype=np.float64).reshape(-1, 2)
        if self.start.shape != self.length.shape or self.start.ndim != 1:
            raise ValueError("start and length must be arrays of one value per agent")
        if self.n_frames < 0 or np.any(self.length < 0):
            raise ValueError("frame counts must be >= 0")
        if np.any((self.length > 0) & ((self.start < 0) | (self.start + self.length > n_frames))):
            raise ValueError(f"an agent's span lies outside the scene's {n_frames} frames")
        self.offset = np.zeros(self.start.size, dtype=np.int64)
        if self.start.size > 1:
            np.cumsum(self.length[:-1], out=self.offset[1:])
        total = int(self.length.sum())
        if self.xy.shape[0] != total:
            raise ValueError(f"xy has {self.xy.shape[0]} rows, the spans {total}")
        # the index of the agents present at each frame (a counting sort of the present
        # samples by frame, column order kept within a frame), in 32-bit temporaries: a
        # long scene's index costs about as much as its samples, not several times more
        small = np.int32 if max(self.n_frames, self.start.size) < 2**31 - 1 else np.int64
        present = np.isfinite(self.xy[:, 0])
        frames = np.arange(total, dtype=small)
        frames -= np.repeat((self.offset - self.start).astype(small), self.length)
        frames = frames[present]
        cols = np.repeat(np.arange(self.start.size, dtype=small), self.length)[present]
        order = np.argsort(frames, kind="stable")
        self.frame_cols = np.ascontiguousarray(cols[order])
        del cols, order
        self.frame_ptr = np.zeros(self.n_frames + 1, dtype=np.int64)
        np.cumsum(np.bincount(frames, minlength=self.n_frames), out=self.frame_ptr[1:])

    # ------------------------------------------------------------------ builders
    @classmethod
    def from_dense(cls, positions: np.ndarray) -> SparseTracks:
        """The sparse form of a dense ``(F, M, 2)`` array (exactly: :meth:`dense` gives it
        back, NaN and inf included)."""
        pos = np.asarray(positions, dtype=np.float64)
        if pos.ndim != 3 or pos.shape[2] != 2:
            raise ValueError(f"positions must be (F, M, 2), got {pos.shape}")
        n_frames, n_agents = pos.shape[:2]
        seen = np.asarray(~np.isnan(pos).all(axis=2))  # (F, M)
        has = seen.any(axis=0)
        first = np.where(has, np.argmax(seen, axis=0), 0)
        last = np.where(has, n_frames - 1 - np.argmax(seen[::-1], axis=0), -1)
        length = np.where(has, last - first + 1, 0).astype(np.int64)
        rows = np.repeat(first, length) + (
            np.arange(int(length.sum())) - np.repeat(np.cumsum(length) - length, length)
        )
        cols = np.repeat(np.arange(n_agents), length)
        return cls(n_frames, first, length, pos[rows, cols])

    @classmethod
    def from_tracks(cls, tracks: Tracks, first: int, last: int) -> tuple[np.ndarray, SparseTracks]:
        """``(ids, sparse)`` for frames ``first..last`` (inclusive): the agents and values of
        :meth:`Tracks.dense(first, last) <conformal_control.data.tracks.Tracks.dense>`,
        without the dense array."""
        n_frames = last - first + 1
        if n_frames <= 0:
            raise ValueError(f"empty frame window [{first}, {last}]")
        keep = [i for i, (f, _) in sorted(tracks.tracks.items()) if f[-1] >= first and f[0] <= last]
        starts = np.zeros(len(keep), dtype=np.int64)
        lengths = np.zeros(len(keep), dtype=np.int64)
        for col, i in enumerate(keep):  # the spans first, then one array filled in place
            f = tracks.tracks[i][0]
            fs = f[(f >= first) & (f <= last)]
            if fs.size:
                lo, hi = int(fs.min()) - first, int(fs.max()) - first
                starts[col], lengths[col] = lo, hi - lo + 1
        xy_all = np.full((int(lengths.sum()), 2), np.nan)
        row = 0
        for col, i in enumerate(keep):
            n = int(lengths[col])
            if n:
                f, xy = tracks.tracks[i]
                sel = (f >= first) & (f <= last)
                xy_all[row + (f[sel] - first - starts[col])] = xy[sel]
                row += n
        return np.array(keep, dtype=np.int64), cls(n_frames, starts, lengths, xy_all)

    # ------------------------------------------------------------------ reading
    @property
    def n_agents(self) -> int:
        return int(self.start.size)

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays held."""
        return sum(
            int(getattr(self, n).nbytes)
            for n in ("start", "length", "offset", "xy", "frame_ptr", "frame_cols")
        )

    def present(self, f: int) -> tuple[np.ndarray, np.ndarray]:
        """``(cols, xy)``: the agents present (finite x) at frame ``f``, in column order,
        and their positions ``(k, 2)``."""
        cols = self.frame_cols[self.frame_ptr[f] : self.frame_ptr[f + 1]]
        return cols, self.xy[self.offset[cols] + (f - self.start[cols])]

    def window(self, lo: int, hi: int, cols: np.ndarray) -> np.ndarray:
        """Positions of agents ``cols`` over frames ``lo..hi-1`` as ``(len(cols), hi - lo,
        2)``, NaN outside their spans and outside the scene (the replay sensor's window)."""
        cols = np.asarray(cols, dtype=np.int64)
        out = np.full((cols.size, max(hi - lo, 0), 2), np.nan)
        if not cols.size or hi <= lo:
            return out
        frames = np.arange(lo, hi)
        k = frames[None, :] - self.start[cols, None]  # (n, L) index into each span
        ok = (k >= 0) & (k < self.length[cols, None])
        rows = self.offset[cols, None] + k
        out[ok] = self.xy[rows[ok]]
        return out

    def overlapping(self, lo: int, hi: int) -> np.ndarray:
        """Columns whose span meets frames ``lo..hi-1`` (the others are NaN there)."""
        end = self.start + self.length
        return np.flatnonzero((self.length > 0) & (self.start < hi) & (end > lo))

    def dense(
        self, lo: int = 0, hi: int | None = None, cols: np.ndarray | None = None
    ) -> np.ndarray:
        """The dense array ``(hi - lo, len(cols), 2)`` (default: every frame and agent)."""
        hi = self.n_frames if hi is None else hi
        sel = np.arange(self.n_agents) if cols is None else np.asarray(cols, dtype=np.int64)
        out: np.ndarray = self.window(lo, hi, sel).transpose(1, 0, 2).copy()
        return out

    def clip(self, lo: int, hi: int) -> SparseTracks:
        """The same agents and frames with only the samples of frames ``lo..hi-1`` (NaN
        elsewhere): what an episode that reads only those frames needs."""
        lo, hi = max(int(lo), 0), min(int(hi), self.n_frames)
        start = np.maximum(self.start, lo)
        length = np.maximum(np.minimum(self.start + self.length, hi) - start, 0)
        rows = np.repeat(self.offset + (start - self.start), length) + (
            np.arange(int(length.sum())) - np.repeat(np.cumsum(length) - length, length)
        )
        return SparseTracks(self.n_frames, np.where(length > 0, start, 0), length, self.xy[rows])

    def has_inf(self) -> bool:
        return bool(np.isinf(self.xy).any())

    def __reduce__(self) -> tuple[Any, ...]:
        return (SparseTracks, (self.n_frames, self.start, self.length, self.xy))


class _Positions:
    """``Scene.positions``: set with a dense ``(F, M, 2)`` array or a :class:`SparseTracks`;
    read, the dense array (the one given, or assembled from the sparse tracks on every read:
    hot paths read :attr:`Scene.tracks` instead)."""

    def __get__(self, obj: Any, objtype: Any = None) -> np.ndarray:
        if obj is None:  # no class-level default: the dataclass field is required
            raise AttributeError("positions")
        dense = obj.__dict__["_dense"]
        if dense is not None:
            return dense  # type: ignore[no-any-return]
        out: np.ndarray = obj.__dict__["_sparse"].dense()
        return out

    def __set__(self, obj: Any, value: np.ndarray | SparseTracks) -> None:
        if isinstance(value, SparseTracks):
            obj.__dict__["_dense"], obj.__dict__["_sparse"] = None, value
        else:
            obj.__dict__["_dense"], obj.__dict__["_sparse"] = value, None


@dataclass
class Scene:
    """Everything an episode needs about the world.

    Attributes
    ----------
    name : str
        Scene name (also a cache key for predictors).
    fps : float
        Frame rate of the replayed data.
    first_frame : int
        Video frame number of ``positions[0]``.
    start_index : int
        Index into ``positions`` of the frame the robot starts at (frames before it are
        history the predictor may use).
    positions : ndarray of shape (F, M, 2) or SparseTracks
        Agent positions in metres, NaN where an agent is absent: a dense array, or the
        sparse tracks (memory proportional to the observations). Read, the dense array
        (assembled on every read for a sparse scene: use :attr:`tracks`, and
        :meth:`replace` rather than ``dataclasses.replace``, which reads it).
    agent_ids : ndarray of shape (M,)
    start : ndarray of shape (2,)
        Robot start position (m).
    goals : ndarray of shape (G, 2)
        Goals visited in order (m).
    v_max : float
        Robot speed bound (m/s).
    units : UnitSystem
        Units in which parameters for this scene are typed (SDD: px and frames).
    defaults : dict
        Default parameters, in ``units``.
    extent : (width, height) in metres, optional
        Size of the scene (the reference image) for plots.
    image : Path, optional
        Reference image (pixel coordinates x m_per_px = metres).
    robot_radius, agent_radius, goal_radius : float
        In metres.
    meta : dict
        Provenance (source file, counts).
    """

    name: str
    fps: float
    first_frame: int
    start_index: int
    agent_ids: np.ndarray
    start: np.ndarray
    goals: np.ndarray
    v_max: float
    # required (no default: the descriptor has none); after the plain fields for mypy, which
    # takes a descriptor for a default
    positions: _Positions = _Positions()
    units: UnitSystem = SI
    defaults: dict[str, Any] = field(default_factory=dict)
    extent: tuple[float, float] | None = None
    image: Path | None = None
    robot_radius: float = 0.5
    agent_radius: float = 0.5
    goal_radius: float = 0.5
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def tracks(self) -> SparseTracks:
        """The positions as :class:`SparseTracks` (built once from a dense array, which
        must then not be modified in place: build a new scene instead)."""
        d = self.__dict__
        sparse = d["_sparse"]
        if sparse is None:
            cached = d.get("_tracks_of")
            if cached is not None and cached[0] is d["_dense"]:
                return cached[1]  # type: ignore[no-any-return]
            sparse = SparseTracks.from_dense(d["_dense"])
            d["_tracks_of"] = (d["_dense"], sparse)
        return sparse  # type: ignore[no-any-return]

    def replace(self, **changes: Any) -> Scene:
        """``dataclasses.replace`` that keeps the positions' storage (a sparse scene stays
        sparse; ``dataclasses.replace`` reads ``positions`` and so assembles the dense
        array)."""
        if "positions" not in changes:
            d = self.__dict__
            changes["positions"] = d["_dense"] if d["_dense"] is not None else d["_sparse"]
        out: Scene = dataclasses.replace(self, **changes)
        return out

    def nbytes(self) -> int:
        """Bytes of the positions held (dense array or sparse tracks)."""
        d = self.__dict__
        return int(d["_dense"].nbytes) if d["_dense"] is not None else int(d["_sparse"].nbytes)

    @property
    def n_frames(self) -> int:
        d = self.__dict__
        return int(d["_dense"].shape[0]) if d["_dense"] is not None else int(d["_sparse"].n_frames)

    @property
    def n_agents(self) -> int:
        d = self.__dict__
        return int(d["_dense"].shape[1]) if d["_dense"] is not None else int(d["_sparse"].n_agents)

    @property
    def start_frame(self) -> int:
        return self.first_frame + self.start_index

    @property
    def collision_distance(self) -> float:
        return self.robot_radius + self.agent_radius

    def validate(self) -> None:
        """Raise ValueError with a clear message if the scene is unusable."""
        p = self.__dict__["_dense"]
        if p is not None:
            if p.ndim != 3 or p.shape[2] != 2:
                raise ValueError(f"scene {self.name}: positions must be (F, M, 2), got {p.shape}")
            if np.isinf(p).any():
                raise ValueError(f"scene {self.name}: positions contain inf")
        elif self.__dict__["_sparse"].has_inf():
            raise ValueError(f"scene {self.name}: positions contain inf")
        if not 0 <= self.start_index < self.n_frames - 1:
            raise ValueError(
                f"scene {self.name}: start frame {self.start_frame} leaves no data to replay "
                f"(data frames {self.first_frame}..{self.first_frame + self.n_frames - 1})"
            )
        if self.goals.ndim != 2 or self.goals.shape[0] == 0 or self.goals.shape[1] != 2:
            raise ValueError(f"scene {self.name}: at least one goal (x, y) is needed")
        for name in ("fps", "v_max", "robot_radius", "agent_radius", "goal_radius"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"scene {self.name}: {name} must be > 0, got {value!r}")
        if not (np.all(np.isfinite(self.start)) and np.all(np.isfinite(self.goals))):
            raise ValueError(f"scene {self.name}: start and goals must be finite")


def scene_from_tracks(
    tracks: Tracks,
    *,
    name: str,
    start: np.ndarray,
    goals: np.ndarray,
    start_frame: int,
    v_max: float,
    history_frames: int = 120,
    last_frame: int | None = None,
    **kwargs: Any,
) -> Scene:
    """Build a :class:`Scene` from tracks, keeping ``history_frames`` before the start.

    Parameters
    ----------
    tracks : Tracks
        The recording (metres).
    name : str
        The scene's name.
    start : ndarray of shape (2,)
        Robot start position (m).
    goals : ndarray of shape (G, 2)
        Goals visited in order (m).
    start_frame : int
        The frame the robot starts at.
    v_max : float
        Robot speed bound (m/s).
    history_frames : int
        Frames kept before ``start_frame`` (the predictor's history).
    last_frame : int, optional
        The last frame kept (default: the recording's last).
    **kwargs
        Further fields of :class:`Scene` (``units``, ``defaults``, ``image``, ...).
    """
    if len(tracks) == 0:
        raise ValueError(f"{tracks.source or name}: no agent tracks; nothing to replay")
    lo, hi = tracks.frame_range()
    if last_frame is not None:
        hi = min(hi, int(last_frame))
    if start_frame >= hi:
        raise InputError(
            f"scene {name}: start frame {start_frame} is at or after the last data frame {hi} "
            f"(the data covers frames {lo}..{hi})"
        )
    # a start a little before the first sample is fine (the history window is empty at
    # first, e.g. TrajNet samples from frame 60 and the paper's start frame 50); a start
    # further back would replay frames that are not in the data at all
    if start_frame < min(lo, 0) or start_frame < lo - int(history_frames):
        raise InputError(
            f"scene {name}: start frame {start_frame} is before the data (it covers frames "
            f"{lo}..{hi}; the start may precede frame {lo} by at most the "
            f"{int(history_frames)}-frame history window)"
        )
    first = int(start_frame) - int(history_frames)
    ids, pos = SparseTracks.from_tracks(tracks, first, hi)
    return Scene(
        name=name,
        fps=tracks.fps,
        first_frame=first,
        start_index=int(start_frame) - first,
        positions=pos,
        agent_ids=ids,
        start=np.asarray(start, dtype=float),
        goals=np.asarray(goals, dtype=float).reshape(-1, 2),
        v_max=float(v_max),
        meta={"source": tracks.source, **tracks.meta},
        **kwargs,
    )
