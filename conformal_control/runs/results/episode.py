"""What one episode produced: :class:`EpisodeResult` (what a run directory is written from)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...core.loop import LoopResult
from ...data.scene import Scene
from .metrics import EpisodeMetrics
from .multi_metrics import RobotContacts

__all__ = ["EpisodeResult", "RobotResult"]


@dataclass
class EpisodeResult:
    """Everything a run produced (what the run directory is written from).

    Attributes
    ----------
    scene : Scene
        The scene as run (with the resolved radii and v_max).
    config : dict
        The full configuration (written as ``config.json``).
    metrics : EpisodeMetrics
        Every metric with its unit (``metrics["t_goal"]`` works; ``metrics.format()``
        prints them).
    intervals : list of dict
        One row per interval (lambda in the scene's units, loss, diagnostics).
    trajectory : dict of arrays
        The robot per video frame (``frame, t, x, y, vx, vy, d_min``; m, s).
    steps : dict of arrays
        The robot per control instant (``t``, state ``x``, command ``cmd``).
    loop : LoopResult
    animation : dict or None
        The compact record ``conformal-control animate`` renders.
    """

    scene: Scene
    config: dict[str, Any]
    metrics: EpisodeMetrics
    intervals: list[dict[str, Any]]
    trajectory: dict[str, np.ndarray]
    steps: dict[str, np.ndarray] = field(default_factory=dict)
    loop: LoopResult | None = None
    animation: dict[str, Any] | None = None

    def plot(self, path: str | Path | None = None) -> Any:
        """The run figure (scene and path, lambda(t), loss(t), distances); saved if ``path``."""
        from ...io.plotting import plot_run  # matplotlib is imported on first use

        fig = plot_run(self)
        if path is not None:
            fig.savefig(path, dpi=110)
        return fig

    def save(self, out: str | Path, *, plot: bool = True) -> Path:
        """Write the run directory (config, metrics, trace, intervals, trajectory, plots)."""
        from .rundir import write_run_dir

        return write_run_dir(self, out, plot=plot)


@dataclass
class RobotResult:
    """One robot of a multi-robot run.

    Attributes
    ----------
    index, id : int
        Its index and the id under which the other robots sense it.
    start, goals : ndarray
        Its task (m).
    metrics : EpisodeMetrics
        As for one robot (``d_min``, ``n_collide``: pedestrians); ``success`` also
        requires no robot-robot collision.
    contacts : RobotContacts
        Its encounters with the other robots.
    intervals : list of dict
    trajectory : dict of arrays
        Per frame while under way: ``frame, t, x, y, vx, vy, d_min, d_min_robot``.
    steps : dict of arrays
    loop : LoopResult
    """

    index: int
    id: int
    start: np.ndarray
    goals: np.ndarray
    metrics: EpisodeMetrics
    contacts: RobotContacts
    intervals: list[dict[str, Any]]
    trajectory: dict[str, np.ndarray]
    steps: dict[str, np.ndarray]
    loop: LoopResult

    def summary(self) -> dict[str, Any]:
        """Its metrics and contacts in one JSON-ready dict."""
        return {
            "robot": self.index,
            "id": self.id,
            **self.metrics.as_dict(),
            **self.contacts.as_dict(),
        }
