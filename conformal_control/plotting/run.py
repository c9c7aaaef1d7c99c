"""Plots of runs: the scene with the robot's path, lambda(t), loss(t), distances."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from ..data.scene import Scene

__all__ = ["plot_lambda_loss", "plot_run", "plot_scene"]


def _mpl() -> ModuleType:
    """``matplotlib.pyplot``, on the Agg backend outside Jupyter."""
    import sys

    import matplotlib

    if "ipykernel" not in sys.modules:  # keep Jupyter's inline backend in notebooks
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def plot_scene(
    ax: Axes,
    scene: Scene,
    trajectory: dict[str, np.ndarray],
    *,
    show_image: bool = True,
    collision_distance: float | None = None,
) -> None:
    """Scene (reference image if any), pedestrian tracks during the run, robot path.

    Frames in which the robot is in collision are marked with red crosses.
    """
    if show_image and scene.image is not None and Path(scene.image).exists():
        img = _mpl().imread(scene.image)
        w, h = scene.extent or (img.shape[1], img.shape[0])
        ax.imshow(img, extent=(0, w, h, 0), alpha=0.75)
    elif scene.extent is not None:
        ax.set_xlim(0, scene.extent[0])
        ax.set_ylim(scene.extent[1], 0)
    frames = trajectory["frame"] - scene.first_frame
    if frames.size:
        win = scene.positions[frames[0] : frames[-1] + 1]
        for j in range(win.shape[1]):
            xy = win[:, j]
            if np.isfinite(xy[:, 0]).any():
                ax.plot(xy[:, 0], xy[:, 1], color="tab:blue", lw=0.7, alpha=0.6)
                last = np.flatnonzero(np.isfinite(xy[:, 0]))[-1]
                ax.plot(*xy[last], "o", color="tab:blue", ms=2.5, alpha=0.7)
    ax.plot(trajectory["x"], trajectory["y"], color="tab:orange", lw=2.0, label="robot")
    ax.plot(*scene.start, "s", color="green", ms=8, label="start")
    ax.plot(scene.goals[:, 0], scene.goals[:, 1], "*", color="red", ms=12, label="goal")
    d_c = collision_distance if collision_distance is not None else scene.collision_distance
    hit = trajectory["d_min"] < d_c
    if hit.any():
        ax.plot(
            trajectory["x"][hit],
            trajectory["y"][hit],
            "x",
            color="red",
            ms=6,
            label=f"collision ({int(hit.sum())} frames)",
        )
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(scene.name)
    ax.legend(loc="best", fontsize=7)


def plot_lambda_loss(
    ax_lam: Axes, ax_loss: Axes, intervals: list[dict[str, Any]], epsilon: float, lam_unit: str
) -> None:
    """lambda_k and l_k per interval, with the target epsilon."""
    scored = [iv for iv in intervals if iv.get("loss") is not None]
    t = np.array([iv["t"] for iv in scored], dtype=float)
    lam = np.array([iv["lambda"] for iv in scored], dtype=float)
    loss = np.array([iv["loss"] for iv in scored], dtype=float)
    ax_lam.step(t, lam, where="post", color="tab:purple")
    ax_lam.set_ylabel(f"lambda ({lam_unit})")
    ax_lam.grid(alpha=0.3)
    ax_loss.plot(t, loss, ".-", color="tab:gray", lw=0.8, label="l_k")
    if loss.size:
        ax_loss.plot(
            t, np.cumsum(loss) / np.arange(1, loss.size + 1), color="black", label="running average"
        )
    ax_loss.axhline(epsilon, color="red", ls="--", label=f"epsilon = {epsilon:g}")
    ax_loss.set_ylim(-0.5, 0.5)
    ax_loss.set_xlabel("t (s)")
    ax_loss.set_ylabel("loss")
    ax_loss.legend(fontsize=7, loc="best")
    ax_loss.grid(alpha=0.3)


def plot_run(result: Any, path: str | Path | None = None) -> Figure:
    """The standard run figure.

    Left: the scene with the robot's path; right, top to bottom: lambda(t), loss(t) with
    epsilon, and the distance to the nearest pedestrian with the collision distance.
    """
    from .distance import plot_distance

    plt = _mpl()
    fig: Figure = plt.figure(figsize=(12, 7.5), constrained_layout=True)
    gs = fig.add_gridspec(3, 2, width_ratios=[1.3, 1])
    ax_scene = fig.add_subplot(gs[:, 0])
    ax_lam = fig.add_subplot(gs[0, 1])
    ax_loss = fig.add_subplot(gs[1, 1], sharex=ax_lam)
    ax_dist = fig.add_subplot(gs[2, 1], sharex=ax_lam)
    plot_scene(ax_scene, result.scene, result.trajectory)
    m = result.metrics
    unit = m["units"]["lambda"]
    plot_lambda_loss(ax_lam, ax_loss, result.intervals, m["epsilon"], unit)
    ax_loss.set_xlabel("")
    plot_distance(ax_dist, result.trajectory, result.scene.collision_distance, t_goal=m["t_goal"])
    tg = f"{m['t_goal']:.2f} s" if m["t_goal"] is not None else "not reached"
    dmin = f"{m['d_min']:.2f} m" if m["d_min"] is not None else "-"
    lavg = f"{m['l_avg']:.3f}" if m["l_avg"] is not None else "-"
    fig.suptitle(
        f"t_goal {tg} | collisions {m['n_collide']} frames | d_min {dmin} | l_avg {lavg} | "
        f"fallback {100 * m['fallback_share']:.1f}%",
        fontsize=10,
    )
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig
