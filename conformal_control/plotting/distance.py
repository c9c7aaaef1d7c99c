"""Distance from the robot to the nearest pedestrian over time, with the collision threshold."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes

__all__ = ["plot_distance"]


def plot_distance(
    ax: Axes,
    trajectory: dict[str, np.ndarray],
    collision_distance: float,
    *,
    t_goal: float | None = None,
) -> None:
    """``d_min(t)`` (m) per frame, the collision distance ``d_c`` and the frames below it.

    Parameters
    ----------
    ax : Axes
    trajectory : dict
        With ``t`` (s) and ``d_min`` (m) per frame (``EpisodeResult.trajectory`` or the
        columns of ``trajectory.csv``).
    collision_distance : float
        d_c = robot radius + pedestrian radius (m); drawn as a dashed red line.
    t_goal : float, optional
        Marks the arrival time with a vertical line.
    """
    t = np.asarray(trajectory["t"], dtype=float)
    d = np.asarray(trajectory["d_min"], dtype=float)
    ax.plot(t, d, color="tab:blue", lw=1.2, label="distance to nearest pedestrian")
    ax.axhline(
        collision_distance, color="red", ls="--", lw=1.0, label=f"d_c = {collision_distance:g} m"
    )
    hit = d < collision_distance
    if hit.any():
        ax.plot(
            t[hit], d[hit], "x", color="red", ms=5, label=f"collision ({int(hit.sum())} frames)"
        )
    if t_goal is not None:
        ax.axvline(t_goal, color="green", ls=":", lw=1.0, label="goal reached")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("distance (m)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
