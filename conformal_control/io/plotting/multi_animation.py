"""Animation of a multi-robot run: every robot, the pedestrians, each robot's lambda.

Each frame shows the scene (its reference image if there is one), the pedestrians, every
robot as a disc of its radius in its own colour with its trail and its goal (a star), a
red rim while it is closer than d_c to a pedestrian and a black rim while it touches
another robot, a robot that reached its goal drawn faded; a side panel shows lambda_k of
every robot with a time cursor, and the title counts the collision frames so far. Frames
are drawn with matplotlib and written as they are drawn (imageio: GIF through Pillow's
streaming ``GIF-PIL`` writer, so memory stays flat in the number of frames; MP4 through
imageio-ffmpeg) by :func:`~conformal_control.io.plotting.animation.render_animation`, the
one rendering path of one robot and of n.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from .frames import frame_size, scene_image

__all__ = ["fleet_frames"]


def _view(rec: Mapping[str, Any]) -> tuple[tuple[float, float], tuple[float, float]]:
    goals = np.asarray(rec["goals"], dtype=float).reshape(-1, 2)
    pts = np.vstack([np.asarray(rec["robots"], dtype=float).reshape(-1, 2), goals])
    pad = 3.0
    x0, y0 = np.nanmin(pts, axis=0) - pad
    x1, y1 = np.nanmax(pts, axis=0) + pad
    ext = np.asarray(rec["extent"], dtype=float)
    if np.isfinite(ext).all():
        x0, y0 = max(x0, 0.0), max(y0, 0.0)
        x1, y1 = min(x1, ext[0]), min(y1, ext[1])
    return (x0, x1), (y1, y0)  # image convention: y down


def fleet_frames(
    rec: Mapping[str, Any], frames: np.ndarray, plt: Any, width: float, dpi: int, trail: float
) -> tuple[Any, Callable[[int], None]]:
    """The view of n robots: the figure and the function drawing run frame ``f`` on it
    (every robot in its colour with its trail and goal, rims for contacts, the
    pedestrians; each robot's lambda_k; the collision frames so far in the title).

    Parameters
    ----------
    rec : mapping
        The multi-robot animation record (``kind="multi"``).
    frames : ndarray
        The run frames rendered.
    plt : module
        ``matplotlib.pyplot``.
    width, dpi : float, int
        As :func:`~conformal_control.io.plotting.animation.render_animation` takes them.
    trail : float
        Length (s) of the trail drawn behind each robot.
    """
    from matplotlib.patches import Circle

    t = np.asarray(rec["t"], dtype=float)
    robots = np.asarray(rec["robots"], dtype=float)
    active = np.asarray(rec["active"], dtype=bool)
    c_ped = np.asarray(rec["contact_ped"], dtype=bool)
    c_rob = np.asarray(rec["contact_robot"], dtype=bool)
    peds = np.asarray(rec["peds"], dtype=float)
    goals = np.asarray(rec["goals"], dtype=float)
    lam = np.asarray(rec["lam"], dtype=float)
    k_start = np.asarray(rec["k_start"])
    t_k = t[np.minimum(k_start, t.size - 1)] if k_start.size else np.zeros(0)
    n = robots.shape[1]
    r_robot = float(rec["robot_radius"])
    r_ped = float(rec["agent_radius"])
    fps_run = float(rec["fps"])
    n_trail = max(1, round(trail * fps_run))
    colours = plt.get_cmap("tab10" if n <= 10 else "tab20")(np.arange(n) % (10 if n <= 10 else 20))
    # collision frames so far, counted while under way (each robot-robot pair once)
    ped_so_far = np.cumsum((c_ped & active).sum(axis=1))
    rob_pairs = np.zeros(t.size, dtype=int)
    if n > 1:
        with np.errstate(invalid="ignore"):
            d = np.hypot(
                robots[:, :, None, 0] - robots[:, None, :, 0],
                robots[:, :, None, 1] - robots[:, None, :, 1],
            )
        either = active[:, :, None] | active[:, None, :]
        upper = np.triu(np.ones((n, n), dtype=bool), k=1)
        with np.errstate(invalid="ignore"):
            rob_pairs = ((d < 2 * r_robot) & either & upper).sum(axis=(1, 2))
    rob_so_far = np.cumsum(rob_pairs)

    px_w, _ = frame_size(width, dpi)  # the single-robot animation's width rule and warning
    xlim, ylim = _view(rec)
    aspect = abs(ylim[0] - ylim[1]) / max(abs(xlim[1] - xlim[0]), 1e-9)
    # the scene panel: 0.62 of the width; the height leaves room for the title and labels
    height = min(max(0.62 * width * aspect + 1.3, 0.4 * width), 0.95 * width)
    px_h = 2 * round(height * dpi / 2)
    fig = plt.figure(figsize=(px_w / dpi, px_h / dpi), dpi=dpi)
    top = 1.0 - 0.75 / height
    bottom = 0.55 / height
    gs = fig.add_gridspec(
        1, 2, width_ratios=[2.2, 1], left=0.07, right=0.98, top=top, bottom=bottom, wspace=0.22
    )
    ax = fig.add_subplot(gs[0, 0])
    ax_lam = fig.add_subplot(gs[0, 1])
    fs = 11  # legible at the figure's own size

    background = scene_image(rec, xlim, ylim, px_w, plt)
    if background is not None:
        crop = background[0]
        # the reference image in light grey: context without a photograph's colours
        # (which also keeps a GIF's frames small)
        grey = crop[..., :3].mean(axis=2) if crop.ndim == 3 else crop
        grey = np.round(grey / max(float(grey.max()), 1e-9) * 15) / 15  # 16 levels
        ax.imshow(
            grey,
            extent=background[1],
            cmap="gray",
            vmin=-0.8,
            vmax=1.0,
            interpolation="nearest",
        )
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)", fontsize=fs)
    ax.set_ylabel("y (m)", fontsize=fs)
    ax.tick_params(labelsize=fs - 1)
    for i in range(n):
        g = goals[i][np.isfinite(goals[i, :, 0])]
        ax.plot(g[:, 0], g[:, 1], "*", color=colours[i], ms=12, mec="black", mew=0.5)
    # pedestrians at their size (points for tiny scales)
    pts_per_m = 72.0 * px_w / dpi * 0.62 * 0.91 / max(abs(xlim[1] - xlim[0]), 1e-9)
    size = max((2.0 * r_ped * pts_per_m) ** 2, 12.0)
    others = ax.scatter([], [], s=size, c="0.3", alpha=0.8, zorder=3, label="pedestrians")
    ped_discs: list[Circle] = []  # the red discs drawn on the current frame
    trails = [ax.plot([], [], color=colours[i], lw=1.2, alpha=0.8)[0] for i in range(n)]
    discs = []
    for i in range(n):
        c = Circle((np.nan, np.nan), r_robot, facecolor=colours[i], edgecolor="none", zorder=5)
        ax.add_patch(c)
        discs.append(c)

    labels = [
        ax.text(np.nan, np.nan, str(i), fontsize=fs - 3, ha="center", va="center", zorder=6)
        for i in range(n)
    ]
    for i in range(n):
        ax_lam.step(t_k, lam[:, i], where="post", color=colours[i], lw=1.2)
    ax_lam.set_xlabel("t (s)", fontsize=fs)
    ax_lam.set_ylabel(f"λ_k of each robot ({rec.get('lambda_unit', '')})", fontsize=fs)
    ax_lam.tick_params(labelsize=fs - 1)
    ax_lam.grid(alpha=0.3)
    ax_lam.set_xlim(t[frames[0]], max(t[frames[-1]], t[frames[0]] + 1e-6))
    cursor = ax_lam.axvline(t[frames[0]], color="black", lw=0.8)

    def draw(f: int) -> None:
        p = peds[f]
        ok = np.isfinite(p[:, 0])
        others.set_offsets(p[ok] if ok.any() else np.zeros((0, 2)))
        for c in ped_discs:
            c.remove()
        ped_discs.clear()
        for i in range(n):
            lo = max(0, f - n_trail)
            trails[i].set_data(robots[lo : f + 1, i, 0], robots[lo : f + 1, i, 1])
            disc = discs[i]
            disc.center = (robots[f, i, 0], robots[f, i, 1])
            labels[i].set_position((robots[f, i, 0], robots[f, i, 1] - 2.2 * r_robot))
            disc.set_alpha(1.0 if active[f, i] else 0.35)
            if c_rob[f, i] and active[f, i]:
                disc.set_edgecolor("black")
                disc.set_linewidth(2.0)
            elif c_ped[f, i] and active[f, i]:
                disc.set_edgecolor("red")
                disc.set_linewidth(2.0)
                near = np.hypot(*(p[ok] - robots[f, i]).T) < r_robot + r_ped
                for q in p[ok][near]:
                    pc = Circle(q, r_ped, fill=False, ec="red", lw=1.0, zorder=4)
                    ax.add_patch(pc)
                    ped_discs.append(pc)
            else:
                disc.set_edgecolor("none")
        cursor.set_xdata([t[f], t[f]])
        ax.set_title(
            f"{rec.get('scene', '')}: {n} robots, t = {t[f]:4.1f} s, "
            f"{int(active[f].sum())} under way\ncollision frames so far: robot-pedestrian "
            f"{int(ped_so_far[f])}, robot-robot {int(rob_so_far[f])}",
            fontsize=fs,
        )

    return fig, draw
