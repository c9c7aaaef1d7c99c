"""A scene: replayed agents, the ego's task, geometry, units and default parameters."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..exceptions import InputError
from .tracks import Tracks
from .units import SI, UnitSystem

__all__ = ["Scene", "scene_from_tracks"]


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
    positions : ndarray of shape (F, M, 2)
        Agent positions in metres, NaN where an agent is absent.
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
    positions: np.ndarray
    agent_ids: np.ndarray
    start: np.ndarray
    goals: np.ndarray
    v_max: float
    units: UnitSystem = SI
    defaults: dict[str, Any] = field(default_factory=dict)
    extent: tuple[float, float] | None = None
    image: Path | None = None
    robot_radius: float = 0.5
    agent_radius: float = 0.5
    goal_radius: float = 0.5
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_agents(self) -> int:
        return int(self.positions.shape[1])

    @property
    def start_frame(self) -> int:
        return self.first_frame + self.start_index

    @property
    def collision_distance(self) -> float:
        return self.robot_radius + self.agent_radius

    def validate(self) -> None:
        """Raise ValueError with a clear message if the scene is unusable."""
        p = self.positions
        if p.ndim != 3 or p.shape[2] != 2:
            raise ValueError(f"scene {self.name}: positions must be (F, M, 2), got {p.shape}")
        if np.isinf(p).any():
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
    """Build a :class:`Scene` from tracks, keeping ``history_frames`` before the start."""
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
    ids, pos = tracks.dense(first, hi)
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
