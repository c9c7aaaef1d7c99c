"""Animation of a finished run (``conformal-control animate``): GIF or MP4, one robot or n.

:func:`render_animation` is the one rendering path: it reads the record, picks the frames,
lets the view draw them (:func:`robot_frames` for one robot,
:func:`~conformal_control.io.plotting.multi_animation.fleet_frames` for several) and writes
them. For one robot, each frame shows the reference image of the scene, the robot with its
trail and its sensing radius, the pedestrians (those sensed at the last sampling time
highlighted, with their predicted trajectories over the interval), the constraint status
of the frame, and a side panel with lambda_k and l_k (with epsilon) and a time cursor.
Frames are drawn with matplotlib and written with imageio as they are drawn: GIF through
Pillow (imageio's streaming ``GIF-PIL`` writer, so memory does not grow with the number of
frames), MP4 through imageio-ffmpeg (which ships its own ffmpeg binary), so no system
binary is needed.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .frames import LEGIBLE_WIDTH_PX, animation_frames, frame_size, load_record, scene_image

__all__ = [
    "LEGIBLE_WIDTH_PX",
    "animation_frames",
    "frame_size",
    "load_record",
    "render_animation",
    "robot_frames",
]

_STATUS_TEXT = {
    0: ("constraints: inactive", "tab:green"),
    1: ("constraints: ACTIVE (QP filters the reference)", "tab:orange"),
    2: ("constraints: INFEASIBLE at lambda_k (fallback)", "tab:red"),
}


def _view(rec: Mapping[str, Any]) -> tuple[tuple[float, float], tuple[float, float]]:
    pts = np.vstack([rec["robot"], np.atleast_2d(rec["start"]), np.atleast_2d(rec["goals"])])
    pad = max(0.6 * float(rec["sensing_radius"]), 5.0)
    x0, y0 = np.nanmin(pts, axis=0) - pad
    x1, y1 = np.nanmax(pts, axis=0) + pad
    ext = np.asarray(rec["extent"], dtype=float)
    if np.isfinite(ext).all():
        x0, y0 = max(x0, 0.0), max(y0, 0.0)
        x1, y1 = min(x1, ext[0]), min(y1, ext[1])
    return (x0, x1), (y1, y0)  # image convention: y down


def robot_frames(
    rec: Mapping[str, Any], frames: np.ndarray, plt: Any, width: float, dpi: int
) -> tuple[Any, Callable[[int], None]]:
    """The one-robot view: the figure and the function drawing run frame ``i`` on it
    (the scene with the robot, its sensing radius, the pedestrians, those sensed with
    their predictions, the constraint status; lambda_k and l_k against epsilon).

    Parameters
    ----------
    rec : mapping
        The run's animation record.
    frames : ndarray
        The run frames rendered (:func:`animation_frames`).
    plt : module
        ``matplotlib.pyplot``.
    width, dpi : float, int
        As :func:`render_animation` takes them.
    """
    from matplotlib.patches import Circle

    t = np.asarray(rec["t"], dtype=float)
    robot = np.asarray(rec["robot"], dtype=float)
    peds = np.asarray(rec["peds"], dtype=float)
    status = np.asarray(rec["status"])
    h_true = np.asarray(rec["h_true_min"], dtype=float)
    k_start = np.asarray(rec["k_start"])
    pred = np.asarray(rec["pred"], dtype=float)
    pred_cols = np.asarray(rec["pred_cols"])
    lam = np.asarray(rec["lam"], dtype=float)
    loss = np.asarray(rec["loss"], dtype=float)
    t_k = t[np.minimum(k_start, t.size - 1)] if k_start.size else np.zeros(0)
    d_c = float(rec["collision_distance"])
    r_sense = float(rec["sensing_radius"])

    px_w, px_h = frame_size(width, dpi)
    fig = plt.figure(figsize=(px_w / dpi, px_h / dpi), dpi=dpi)
    gs = fig.add_gridspec(
        2, 2, width_ratios=[1.7, 1], left=0.06, right=0.98, top=0.93, bottom=0.1, hspace=0.3
    )
    ax = fig.add_subplot(gs[:, 0])
    ax_lam = fig.add_subplot(gs[0, 1])
    ax_loss = fig.add_subplot(gs[1, 1], sharex=ax_lam)

    # static layers
    xlim, ylim = _view(rec)
    background = scene_image(rec, xlim, ylim, px_w, plt)
    if background is not None:
        ax.imshow(background[0], extent=background[1], alpha=0.7)
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.plot(*np.asarray(rec["start"]), "s", color="green", ms=7, label="start")
    goals = np.atleast_2d(rec["goals"])
    ax.plot(goals[:, 0], goals[:, 1], "*", color="red", ms=11, label="goal")
    (trail,) = ax.plot([], [], color="tab:orange", lw=1.5)
    robot_disc = Circle((np.nan, np.nan), d_c / 2, color="tab:orange", zorder=5, label="robot")
    sense = Circle(
        (np.nan, np.nan), r_sense, fill=False, ls="--", lw=0.8, color="tab:orange", alpha=0.8
    )
    ax.add_patch(robot_disc)
    ax.add_patch(sense)
    others = ax.scatter([], [], s=14, color="tab:blue", alpha=0.6, label="pedestrian")
    sensed = ax.scatter([], [], s=22, color="navy", label="sensed")
    n_pred = pred.shape[1] if pred.ndim == 4 else 0
    pred_lines = [
        ax.plot([], [], color="magenta", lw=1.2, alpha=0.9, label="prediction" if i == 0 else None)[
            0
        ]
        for i in range(n_pred)
    ]
    status_txt = ax.text(
        0.01, 0.99, "", transform=ax.transAxes, va="top", fontsize=8, weight="bold"
    )
    barrier_txt = ax.text(0.01, 0.93, "", transform=ax.transAxes, va="top", fontsize=8)
    ax.legend(loc="lower right", fontsize=6, ncol=2)

    ax_lam.step(t_k, lam, where="post", color="tab:purple")
    ax_lam.set_ylabel(f"lambda ({rec.get('lambda_unit', '')})", fontsize=8)
    ax_lam.grid(alpha=0.3)
    ax_loss.plot(t_k, loss, ".-", color="tab:gray", lw=0.8, ms=3, label="l_k")
    eps = float(rec["epsilon"])
    ax_loss.axhline(eps, color="red", ls="--", lw=1.0, label=f"epsilon = {eps:g}")
    ax_loss.set_ylim(-0.5, 0.5)
    ax_loss.set_xlabel("t (s)")
    ax_loss.set_ylabel("loss", fontsize=8)
    ax_loss.grid(alpha=0.3)
    ax_loss.legend(fontsize=7, loc="lower right")
    ax_lam.set_xlim(t[frames[0]], max(t[frames[-1]], t[frames[0]] + 1e-6))
    cursors = [a.axvline(t[frames[0]], color="black", lw=0.8) for a in (ax_lam, ax_loss)]
    lam_txt = ax_lam.text(0.01, 0.95, "", transform=ax_lam.transAxes, va="top", fontsize=8)

    def draw(i: int) -> None:
        x = robot[i]
        collide = False
        p = peds[i]
        ok = np.isfinite(p[:, 0])
        if ok.any():
            collide = bool(np.min(np.hypot(*(p[ok] - x).T)) < d_c)
        k = int(np.searchsorted(k_start, i, side="right") - 1) if k_start.size else -1
        cols = pred_cols[k][pred_cols[k] >= 0] if k >= 0 else np.zeros(0, dtype=int)
        is_sensed = np.zeros(p.shape[0], dtype=bool)
        is_sensed[cols] = True
        others.set_offsets(p[ok & ~is_sensed] if (ok & ~is_sensed).any() else np.zeros((0, 2)))
        sensed.set_offsets(p[ok & is_sensed] if (ok & is_sensed).any() else np.zeros((0, 2)))
        for j, line in enumerate(pred_lines):
            if k >= 0 and pred_cols[k, j] >= 0:
                line.set_data(pred[k, j, :, 0], pred[k, j, :, 1])
            else:
                line.set_data([], [])
        trail.set_data(robot[: i + 1, 0], robot[: i + 1, 1])
        robot_disc.center = (x[0], x[1])
        robot_disc.set_color("red" if collide else "tab:orange")
        sense.center = (x[0], x[1])
        text, color = _STATUS_TEXT.get(int(status[i]), ("", "black"))
        status_txt.set_text(text)
        status_txt.set_color(color)
        h = h_true[i]
        if not np.isfinite(h):
            barrier_txt.set_text("no pedestrian sensed")
            barrier_txt.set_color("black")
        else:
            viol = h < 0
            word = "VIOLATED" if viol else "satisfied"
            barrier_txt.set_text(f"true barrier min h = {h:+.3f}: {word}")
            barrier_txt.set_color("red" if (viol or collide) else "black")
        for c in cursors:
            c.set_xdata([t[i], t[i]])
        if k >= 0 and k < lam.size:
            lam_txt.set_text(f"lambda_k = {lam[k]:+.3f}   l_k = {loss[k]:+.3f}")
        ax.set_title(f"{rec.get('scene', '')}   t = {t[i]:.2f} s", fontsize=10)

    return fig, draw


def render_animation(
    source: str | Path | Mapping[str, Any],
    out: str | Path,
    *,
    start: float | None = None,
    end: float | None = None,
    fps: float = 10.0,
    width: float = 9.6,
    dpi: int = 80,
    trail: float = 3.0,
    progress: bool = True,
) -> int:
    """Render a run to ``out`` (``.gif`` or ``.mp4``) and return the number of frames.

    Parameters
    ----------
    source : path or dict
        Run directory, ``animation.npz`` or a record: ``EpisodeResult.animation`` (one
        robot) or ``MultiResult.animation`` (``kind="multi"``: several robots).
    out : path
        Output file; its suffix picks the format.
    start, end : float, optional
        Time window (s since the start of the run).
    fps : float
        Output frame rate; the animation plays in real time (see :func:`animation_frames`).
    width : float
        Figure width in inches (one robot: height = 0.45 width; several: the scene's
        aspect).
    dpi : int
        Resolution: the frame is ``width * dpi`` pixels wide.
    trail : float
        Several robots: length (s) of the trail drawn behind each.
    progress : bool
        Report the rendering's progress (a bar on a terminal, plain lines in a log).
    """
    import imageio.v2 as imageio

    from ...core.progress import track
    from .multi_animation import fleet_frames
    from .run import pyplot

    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"output must end in .gif or .mp4, got {out.name!r}")
    rec = load_record(source)
    if str(rec.get("kind", "")) == "multi":
        frames = animation_frames(rec, start, end, fps)
        plt = pyplot()
        fig, draw = fleet_frames(rec, frames, plt, width, dpi, trail)
    else:
        frames = animation_frames(rec, start, end, fps)
        plt = pyplot()
        fig, draw = robot_frames(rec, frames, plt, width, dpi)

    if suffix == ".gif":
        # imageio's streaming GIF writer (Pillow underneath): each frame is quantised and
        # written to the file as it comes, so memory stays flat in the number of frames.
        # The default GIF writer keeps every frame until it closes (388 MB at 201 frames,
        # 5.1 GB at 3,824). It encodes "loop forever" as 65,535 loops, and writes whole
        # frames (the same pixels as before, about twice the file size: its sub-rectangle
        # option fails on numpy 2); prefer .mp4 for long runs.
        writer = imageio.get_writer(out, format="GIF-PIL", mode="I", duration=1.0 / fps, loop=0)
    else:
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            plt.close(fig)
            raise ImportError(
                "writing MP4 needs imageio-ffmpeg: pip install imageio-ffmpeg "
                "(or the 'docs' extra), or write a .gif"
            ) from None
        writer = imageio.get_writer(
            out, fps=fps, codec="libx264", macro_block_size=1, pixelformat="yuv420p"
        )
    n_written = 0
    try:
        for i in track(frames, f"rendering {out.name}", "frames", enabled=progress):
            draw(i)
            fig.canvas.draw()
            rgba = np.asarray(fig.canvas.buffer_rgba())
            writer.append_data(np.ascontiguousarray(rgba[..., :3]))
            n_written += 1
    finally:
        writer.close()
        plt.close(fig)
    return n_written
