"""Figures of the paper reproduction: paths per row, lambda/loss per row, l_avg against epsilon."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .run import plot_scene, pyplot

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ...data.scene import Scene

__all__ = ["plot_lambda_loss_rows", "plot_lavg_vs_epsilon", "plot_paths_grid"]


def _fmt(v: Any, spec: str) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return format(v, spec)


def _save(fig: Any, path: str | Path, dpi: int) -> None:
    """Save as a palette PNG (256 colours): a third of the size, for docs and reports.

    The figure is rendered once and its pixels are quantised in memory (no full-colour
    PNG encoded, read back and encoded again).
    """
    plt = pyplot()
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - Pillow comes with matplotlib
        fig.savefig(path, dpi=dpi)
        plt.close(fig)
        return
    fig.set_dpi(dpi)
    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba())
    plt.close(fig)
    im = Image.fromarray(rgba[..., :3])
    im.quantize(colors=256, method=Image.Quantize.FASTOCTREE).save(path)


def _grid(
    plt: Any,
    nrows: int,
    cols: int,
    panel: tuple[float, float],
    margins: tuple[float, float, float, float],
    gaps: tuple[float, float],
) -> tuple[Figure, np.ndarray]:
    """A figure of ``nrows`` x ``cols`` panels of ``panel`` inches, laid out in inches.

    ``margins`` (left, right, top, bottom) and ``gaps`` (between columns, between rows)
    leave room for the tick labels, axis labels and titles; a fixed layout instead of
    ``tight_layout``, which measures every text of every panel (most of a grid's drawing
    time).
    """
    (w, h), (left, right, top, bottom), (wgap, hgap) = panel, margins, gaps
    fig_w = left + right + cols * w + (cols - 1) * wgap
    fig_h = top + bottom + nrows * h + (nrows - 1) * hgap
    fig, axes = plt.subplots(
        nrows,
        cols,
        figsize=(fig_w, fig_h),
        squeeze=False,
        gridspec_kw={
            "left": left / fig_w,
            "right": 1 - right / fig_w,
            "top": 1 - top / fig_h,
            "bottom": bottom / fig_h,
            "wspace": wgap / w,
            "hspace": hgap / h,
        },
    )
    return fig, axes


def plot_paths_grid(
    scene: Scene,
    runs: Sequence[dict[str, Any]],
    path: str | Path,
    *,
    title: str = "",
    dpi: int = 100,
    margin: float = 10.0,
    panel_width: float = 4.2,
) -> Figure:
    """One panel per row: the robot's path over the scene's reference image.

    Every panel shows the same band of the scene: the full width, and the height the
    paths, start and goals span plus ``margin`` metres on each side. Panels are laid out
    three per line, each ``panel_width`` inches (420 px at the default dpi) wide, with
    both axes labelled in metres. Returns the (saved and closed) figure.

    Parameters
    ----------
    scene : Scene
        Gives the image, the replayed pedestrians and start/goal.
    runs : list of dict
        ``label``, ``trajectory`` (dict of arrays: frame, x, y, d_min) and ``metrics``.
    path : path
        Where the figure is saved.
    title : str
        The figure's title.
    dpi : int
        Resolution of the saved figure.
    margin : float
        Metres shown beyond the paths, start and goals, above and below.
    panel_width : float
        Width of a panel (inches).
    """
    plt = pyplot()
    n = len(runs)
    ys = [scene.start[1], *scene.goals[:, 1]]
    for run in runs:
        tr = run.get("trajectory")
        if tr is not None and len(tr["y"]):
            ys += [float(np.nanmin(tr["y"])), float(np.nanmax(tr["y"]))]
    width = scene.extent[0] if scene.extent else float(np.nanmax(np.abs(ys))) * 2
    height = scene.extent[1] if scene.extent else max(ys) + margin
    y_lo, y_hi = max(0.0, min(ys) - margin), min(height, max(ys) + margin)
    aspect = (y_hi - y_lo) / max(width, 1e-9)
    cols = min(3, max(1, n))
    nrows = math.ceil(n / cols)
    fig: Figure
    # room for: the y tick and axis labels (left), two title lines (above each panel) and
    # the x tick and axis labels (below); the suptitle on top
    fig, axes = _grid(
        plt,
        nrows,
        cols,
        (panel_width, panel_width * aspect),
        (0.6, 0.15, 0.45 + (0.35 if title else 0.0), 0.5),
        (0.6, 0.9),
    )
    for ax, run in zip(axes.flat, runs, strict=False):
        tr = run.get("trajectory")
        if tr is None or len(tr["frame"]) == 0:
            ax.set_title(f"{run['label']}: failed", fontsize=8, y=1.0)
            ax.axis("off")
            continue
        plot_scene(ax, scene, tr, legend=False)
        ax.set_xlim(0, width)
        ax.set_ylim(y_hi, y_lo)
        m = run.get("metrics") or {}
        tg = _fmt(m.get("t_goal"), ".2f") + " s" if m.get("t_goal") is not None else "not reached"
        ax.set_title(
            f"{run['label']}\nt_goal {tg} | coll {m.get('n_collide', '-')} | "
            f"d_min {_fmt(m.get('d_min'), '.2f')} m",
            fontsize=8,
            y=1.0,  # placed, not measured against the axes' decorations
        )
        ax.tick_params(labelsize=7)
        ax.set_xlabel("x (m)", fontsize=8)
        ax.set_ylabel("y (m)", fontsize=8)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    if title:
        fig.suptitle(title, fontsize=10, y=1 - 0.12 / fig.get_figheight())
    _save(fig, path, dpi)
    return fig


def plot_lambda_loss_rows(
    runs: Sequence[dict[str, Any]],
    path: str | Path,
    *,
    lam_unit: str = "1/frame",
    title: str = "",
    dpi: int = 100,
    panel_size: tuple[float, float] = (4.4, 3.2),
) -> Figure:
    """One panel per row: lambda_k (left axis) and l_k with its running mean (right axis).

    ``runs``: dicts with ``label``, ``learn``, ``epsilon`` and ``intervals`` (dict of
    arrays ``t``, ``lambda``, ``loss``). Three panels per line, each ``panel_size``
    inches; every axis is labelled with its unit. Returns the (saved and closed) figure.

    Parameters
    ----------
    runs : sequence of dict
        The rows, as above.
    path : path
        Where the figure is saved.
    lam_unit : str
        The unit lambda is shown in.
    title : str
        The figure's title.
    dpi : int
        Resolution of the saved figure.
    panel_size : (float, float)
        Width and height of a panel (inches).
    """
    plt = pyplot()
    n = len(runs)
    cols = min(3, max(1, n))
    nrows = math.ceil(n / cols)
    fig: Figure
    # room for: the left axis's tick and axis labels, the right (twin) axis's on the
    # other side, a title line above each panel and the x labels below; the suptitle
    fig, axes = _grid(
        plt,
        nrows,
        cols,
        (panel_size[0] - 1.35, panel_size[1] - 0.75),
        (0.7, 0.65, 0.3 + (0.35 if title else 0.0), 0.45),
        (1.35, 0.75),
    )
    for ax, run in zip(axes.flat, runs, strict=False):
        iv = run.get("intervals")
        ax.set_title(run["label"], fontsize=8, y=1.0)
        ax.tick_params(labelsize=7)
        ax.set_xlabel("t (s)", fontsize=8)
        ax.set_ylabel(f"lambda ({lam_unit})", fontsize=8, color="tab:purple")
        if iv is None or len(iv["t"]) == 0:
            ax.text(0.5, 0.5, "no data", ha="center", transform=ax.transAxes)
            continue
        ok = np.isfinite(iv["loss"])
        t, lam, loss = iv["t"][ok], iv["lambda"][ok], iv["loss"][ok]
        ax.step(t, lam, where="post", color="tab:purple", lw=1.0)
        ax.grid(alpha=0.3)
        ax2 = ax.twinx()
        ax2.plot(t, loss, ".", color="tab:gray", ms=2)
        if loss.size:
            ax2.plot(t, np.cumsum(loss) / np.arange(1, loss.size + 1), color="black", lw=1.0)
        eps = run.get("epsilon")
        if run.get("learn") and eps is not None:
            ax2.axhline(eps, color="red", ls="--", lw=0.8)
        ax2.set_ylim(-0.5, 0.5)
        ax2.tick_params(labelsize=7)
        ax2.set_ylabel("loss l_k (dots), running mean (dimensionless)", fontsize=7)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    if title:
        fig.suptitle(
            title + "  (red dashed: epsilon)", fontsize=10, y=1 - 0.12 / fig.get_figheight()
        )
    _save(fig, path, dpi)
    return fig


def plot_lavg_vs_epsilon(
    points: Sequence[dict[str, Any]], path: str | Path, *, title: str = "", dpi: int = 100
) -> Figure:
    """l_avg against epsilon: ours per variant, the paper's, and the line l_avg = epsilon.

    ``points``: dicts with ``series`` (legend name), ``epsilon`` and ``l_avg``. Returns
    the (saved and closed) figure.

    Parameters
    ----------
    points : sequence of dict
        The points, as above.
    path : path
        Where the figure is saved.
    title : str
        The figure's title.
    dpi : int
        Resolution of the saved figure.
    """
    plt = pyplot()
    fig: Figure
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    series: dict[str, list[tuple[float, float]]] = {}
    for p in points:
        if p.get("l_avg") is None or p.get("epsilon") is None:
            continue
        series.setdefault(p["series"], []).append((float(p["epsilon"]), float(p["l_avg"])))
    markers = ["o", "s", "^", "D", "v", "P"]
    for i, (name, xy) in enumerate(series.items()):
        arr = np.array(sorted(xy))
        ax.plot(
            arr[:, 0], arr[:, 1], markers[i % len(markers)] + "-", lw=0.8, label=name, alpha=0.8
        )
    ax.plot([-0.5, 0.5], [-0.5, 0.5], color="gray", ls="--", lw=0.8, label="l_avg = epsilon")
    ax.set_xlim(-0.5, 0.5)
    ax.set_ylim(-0.5, 0.5)
    ax.set_xlabel("epsilon (target average loss, dimensionless)")
    ax.set_ylabel("l_avg (achieved average loss, dimensionless)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    _save(fig, path, dpi)
    return fig
