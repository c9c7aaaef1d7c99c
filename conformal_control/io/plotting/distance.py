"""Distance from the robot to the nearest pedestrian over time, with the collision threshold."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes

__all__ = ["distance_window", "plot_distance"]


def plot_distance(
    ax: Axes,
    trajectory: dict[str, np.ndarray],
    collision_distance: float,
    *,
    t_goal: float | None = None,
    color: str = "tab:blue",
    label: str = "distance to nearest pedestrian",
) -> None:
    """``d_min(t)`` (m) per frame, the collision distance ``d_c`` and the frames below it.

    The vertical axis starts at 0 and ends at :func:`distance_window`: isolated spikes (no
    pedestrian near, the nearest one tens of metres away) are clipped so that d_c stays
    readable; the axis label and the legend then say so and give the largest value.

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
    color, label : str
        Colour and legend label of the distance curve (to draw two runs on one axes).
    """
    t = np.asarray(trajectory["t"], dtype=float)
    d = np.asarray(trajectory["d_min"], dtype=float)
    ax.plot(t, d, color=color, lw=1.2, label=label)
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
    top = distance_window(d, collision_distance)
    finite = d[np.isfinite(d)]
    n_above = int((finite > top).sum())
    ax.set_xlabel("t (s)")
    if n_above:
        ax.set_ylabel(f"distance (m), clipped at {top:.3g}")
        ax.plot([], [], " ", label=f"{n_above} frames above {top:.3g} m (max {finite.max():.3g} m)")
    else:
        ax.set_ylabel("distance (m)")
    ax.set_ylim(0, top)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")


def distance_window(d: np.ndarray, collision_distance: float) -> float:
    """Top of the distance axis (m): the data, or a window around d_c if a few spikes dwarf it.

    The window is ``max(4 d_c, 1.5 x the 75th percentile)``: tall enough for the typical
    distances, short enough that d_c and near misses stay visible when the nearest sensed
    pedestrian is occasionally tens of metres away. When the data fit in it the axis ends
    just above the largest value instead.
    """
    finite = np.asarray(d, dtype=float)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return 4.0 * collision_distance
    window = max(4.0 * collision_distance, 1.5 * float(np.percentile(finite, 75)))
    largest = float(finite.max())
    return 1.05 * largest if largest <= window else window
