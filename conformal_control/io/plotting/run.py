"""Plots of runs: the scene with the robot's path, lambda(t), loss(t), distances.

Speed (``conformal-control run`` draws :func:`plot_run` after every run): the reference
image is decoded at about the resolution it is drawn at (:func:`reference_image`; SDD's
are 1.4-2.3 megapixel photographs shown in a panel a few hundred pixels wide), the run
figure has a fixed layout (a layout engine costs a second drawing pass plus its own
solve), and PNGs are written with fast zlib compression (same pixels, a slightly larger
file).
"""

from __future__ import annotations

import math
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from ...data.scene import Scene

__all__ = ["plot_lambda_loss", "plot_run", "plot_scene", "reference_image"]

#: dpi of the saved run figures
SAVE_DPI = 110
#: PNG writer options of the saved figures: zlib level 1 encodes several times faster
#: than Pillow's default (6) for a file about a fifth larger; the pixels are the same.
PNG_OPTIONS = {"compress_level": 1}


def pyplot() -> ModuleType:
    """``matplotlib.pyplot``, on the Agg backend outside Jupyter."""
    import sys

    import matplotlib

    if "ipykernel" not in sys.modules:  # keep Jupyter's inline backend in notebooks
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def reference_image(
    path: str | Path, max_size: tuple[float, float] | None = None
) -> tuple[np.ndarray, tuple[int, int]]:
    """A scene's reference image as an array, reduced to about ``max_size`` pixels.

    Parameters
    ----------
    path : path
        The image (JPEG or PNG).
    max_size : (width, height), optional
        The size in pixels at which the image will be shown. The image is reduced by an
        integer factor (JPEG: while decoding, which is several times faster than decoding
        it whole) to the smallest size that still covers ``max_size`` in both directions,
        so at most twice that: matplotlib then resamples it to the screen with
        antialiasing as it would the full image. None keeps the full resolution.

    Returns
    -------
    image : ndarray
        ``(rows, cols, 3 or 4)`` uint8 (a greyscale image stays ``(rows, cols)``).
    size : (int, int)
        The full-resolution width and height in pixels.
    """
    from PIL import Image

    with Image.open(path) as im:
        full = im.size
        if max_size is not None:
            mw, mh = max(1.0, float(max_size[0])), max(1.0, float(max_size[1]))
            factor = int(min(full[0] / mw, full[1] / mh))  # largest factor still covering
            if factor >= 2:
                if im.format == "JPEG":  # decode at 1/2, 1/4 or 1/8 scale directly
                    im.draft(im.mode, (math.ceil(mw), math.ceil(mh)))
                    factor = int(min(im.size[0] / mw, im.size[1] / mh))
                if factor >= 2:
                    im = im.reduce(factor)
        if im.mode not in ("RGB", "RGBA", "L"):
            im = im.convert("RGBA" if "A" in im.getbands() else "RGB")
        return np.asarray(im), full


def _axes_pixels(ax: Axes, dpi: float | None) -> tuple[float, float]:
    """The size of ``ax`` in pixels at ``dpi`` (default: the larger of the figure's dpi
    and ``savefig.dpi``)."""
    import matplotlib
    from matplotlib.figure import Figure

    fig = ax.get_figure()
    if not isinstance(fig, Figure):  # None (a detached axes) or a SubFigure
        where = "no figure" if fig is None else f"a {type(fig).__name__}"
        raise ValueError(
            "the reference image is sized to its axes, which must be placed directly on a "
            f"Figure, not on {where}"
        )
    if dpi is None:
        saved = matplotlib.rcParams["savefig.dpi"]
        dpi = max(float(fig.dpi), float(saved) if saved != "figure" else 0.0)
    pos = ax.get_position()
    w_in, h_in = fig.get_size_inches()
    return pos.width * w_in * dpi, pos.height * h_in * dpi


def plot_scene(
    ax: Axes,
    scene: Scene,
    trajectory: dict[str, np.ndarray],
    *,
    show_image: bool = True,
    collision_distance: float | None = None,
    image_dpi: float | None = None,
    legend: bool = True,
) -> None:
    """Scene (reference image if any), pedestrian tracks during the run, robot path.

    Frames in which the robot is in collision are marked with red crosses. The reference
    image is drawn at about the resolution of the axes (see :func:`reference_image`):
    ``image_dpi`` is the resolution the figure will be saved at (default: the larger of
    the figure's dpi and ``savefig.dpi``). ``legend=False`` leaves the legend out (a
    grid of panels that share one).

    Parameters
    ----------
    ax : Axes
        Where to draw.
    scene : Scene
        Gives the image, the replayed pedestrians and start/goal.
    trajectory : dict of arrays
        The run's trajectory (``frame``, ``x``, ``y``, ``d_min``).
    show_image : bool
        Draw the scene's reference image.
    collision_distance : float, optional
        Distance (m) below which a frame is marked as a collision (default: the scene's).
    image_dpi : float, optional
        The resolution the figure will be saved at.
    legend : bool
        Draw the legend.
    """
    if show_image and scene.image is not None and Path(scene.image).exists():
        img, (w_px, h_px) = reference_image(scene.image, _axes_pixels(ax, image_dpi))
        w, h = scene.extent or (w_px, h_px)
        ax.imshow(img, extent=(0, w, h, 0), alpha=0.75)
    elif scene.extent is not None:
        ax.set_xlim(0, scene.extent[0])
        ax.set_ylim(scene.extent[1], 0)
    frames = trajectory["frame"] - scene.first_frame
    if frames.size:
        # every track in one line, NaN-separated (one artist instead of one per
        # pedestrian: the drawing and the legend's placement scale with the artists)
        lo, hi = int(frames[0]), int(frames[-1]) + 1
        win = scene.tracks.dense(lo, hi, scene.tracks.overlapping(lo, hi))
        seen = np.isfinite(win[:, :, 0])
        cols = np.flatnonzero(seen.any(axis=0))
        if cols.size:
            tracks = win[:, cols].transpose(1, 0, 2)  # (tracks, frames, 2)
            gap = np.full((cols.size, 1, 2), np.nan)
            path = np.concatenate([tracks, gap], axis=1).reshape(-1, 2)
            ax.plot(path[:, 0], path[:, 1], color="tab:blue", lw=0.7, alpha=0.6)
            last = seen.shape[0] - 1 - np.argmax(seen[::-1][:, cols], axis=0)
            ends = win[last, cols]
            ax.plot(ends[:, 0], ends[:, 1], "o", color="tab:blue", ms=2.5, alpha=0.7, ls="")
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
    if legend:
        ax.legend(loc="best", fontsize=7)


def plot_lambda_loss(
    ax_lam: Axes, ax_loss: Axes, intervals: list[dict[str, Any]], epsilon: float, lam_unit: str
) -> None:
    """lambda_k and l_k per interval, with the target epsilon.

    Parameters
    ----------
    ax_lam, ax_loss : Axes
        Where lambda_k and l_k are drawn.
    intervals : list of dict
        The run's intervals (``t``, ``lambda``, ``loss``).
    epsilon : float
        The target average loss.
    lam_unit : str
        The unit lambda is shown in (axis label).
    """
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

    plt = pyplot()
    # a fixed layout (inches on a 12 x 7.5 in figure): the scene on the left, three
    # stacked panels on the right with room for their tick labels and axis labels
    W, H = 12.0, 7.5
    fig: Figure = plt.figure(figsize=(W, H))
    gs_scene = fig.add_gridspec(1, 1, left=0.8 / W, right=6.4 / W, bottom=0.49 / H, top=6.95 / H)
    gs = fig.add_gridspec(
        3, 1, left=7.3 / W, right=11.94 / W, bottom=0.49 / H, top=6.95 / H, hspace=0.17
    )
    ax_scene = fig.add_subplot(gs_scene[0, 0])
    ax_lam = fig.add_subplot(gs[0, 0])
    ax_loss = fig.add_subplot(gs[1, 0], sharex=ax_lam)
    ax_dist = fig.add_subplot(gs[2, 0], sharex=ax_lam)
    plot_scene(ax_scene, result.scene, result.trajectory, image_dpi=SAVE_DPI)
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
        y=0.985,
    )
    if path is not None:
        fig.savefig(path, dpi=SAVE_DPI, **png_options(path))
        plt.close(fig)
    return fig


def png_options(path: str | Path | object) -> dict[str, Any]:
    """savefig keywords for fast PNG encoding when ``path`` names a PNG file."""
    if isinstance(path, (str, Path)) and str(path).lower().endswith(".png"):
        return {"pil_kwargs": dict(PNG_OPTIONS)}
    return {}
