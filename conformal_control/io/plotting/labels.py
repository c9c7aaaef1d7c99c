"""Point labels placed without overlap: :func:`place_labels`.

A greedy search in display coordinates (pixels), written here rather than taken from a
library because the figures need a guarantee the libraries do not give: ``adjustText``
moves labels iteratively and may leave overlaps, ``textalloc`` prints to stdout and draws
what it could not place on top of the rest. Here every label either gets a place where it
overlaps no other label and no marker and stays inside the axes, or is reported as not
placed (the caller lists it instead).

Each label is tried at growing distances from its point, in 16 directions (those pointing
away from the neighbouring points first); a position that also clears the lines of the
plot (error bars, fronts) and whose leader line crosses no other is preferred. A label set
away from its point is joined to it by a thin leader line that crosses no other label.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.figure import Figure

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.text import Text

__all__ = ["PlacedLabels", "place_labels"]

#: directions tried (degrees); sorted per label by closeness to "away from the neighbours"
_ANGLES = tuple(22.5 * k for k in range(16))


@dataclass
class PlacedLabels:
    """What :func:`place_labels` drew.

    Attributes
    ----------
    texts : list of Text or None
        One per point: its label, or None if no free place was found.
    leaders : list
        The leader lines drawn (``Line2D``).
    unplaced : list of int
        Indices of the points left without a label.
    """

    texts: list[Text | None] = field(default_factory=list)
    leaders: list[Any] = field(default_factory=list)
    unplaced: list[int] = field(default_factory=list)


def _overlaps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Which boxes ``b`` (K, 4: x0, y0, x1, y1) overlap box ``a`` (4,)."""
    if b.size == 0:
        return np.zeros(0, dtype=bool)
    hit: np.ndarray = (b[:, 0] < a[2]) & (b[:, 2] > a[0]) & (b[:, 1] < a[3]) & (b[:, 3] > a[1])
    return hit


def _crosses(box: np.ndarray, segs: np.ndarray) -> bool:
    """Whether any segment (K, 4: x0, y0, x1, y1) meets the box (Liang-Barsky clipping)."""
    if segs.size == 0:
        return False
    x0, y0, x1, y1 = box
    p0 = segs[:, :2]
    d = segs[:, 2:] - p0
    t_lo = np.zeros(len(segs))
    t_hi = np.ones(len(segs))
    ok = np.ones(len(segs), dtype=bool)
    for axis, lo, hi in ((0, x0, x1), (1, y0, y1)):
        dd, pp = d[:, axis], p0[:, axis]
        flat = np.abs(dd) < 1e-12
        ok &= ~flat | ((pp >= lo) & (pp <= hi))
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (lo - pp) / dd, (hi - pp) / dd
        t_lo = np.maximum(t_lo, np.where(flat, -np.inf, np.minimum(ta, tb)))
        t_hi = np.minimum(t_hi, np.where(flat, np.inf, np.maximum(ta, tb)))
    return bool(np.any(ok & (t_lo <= t_hi)))


def _segments_cross(a: np.ndarray, segs: np.ndarray) -> bool:
    """Whether segment ``a`` (4,) properly crosses any of ``segs`` (K, 4)."""
    if segs.size == 0:
        return False
    p, r = a[:2], a[2:] - a[:2]
    q, s = segs[:, :2], segs[:, 2:] - segs[:, :2]
    den = r[0] * s[:, 1] - r[1] * s[:, 0]
    qp = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qp[:, 0] * s[:, 1] - qp[:, 1] * s[:, 0]) / den
        u = (qp[:, 0] * r[1] - qp[:, 1] * r[0]) / den
    e = 1e-6
    hit = (np.abs(den) > 1e-12) & (t > e) & (t < 1 - e) & (u > e) & (u < 1 - e)
    return bool(np.any(hit))


def _leader(cx: float, cy: float, w: float, h: float, pad: float, p: np.ndarray) -> np.ndarray:
    """The segment from the nearest point of a label's box to its point."""
    ex = min(max(p[0], cx - w / 2 + pad), cx + w / 2 - pad)
    ey = min(max(p[1], cy - h / 2 + pad), cy + h / 2 - pad)
    return np.array([ex, ey, p[0], p[1]])


def _line_segments(ax: Axes) -> np.ndarray:
    """Every straight piece of the lines drawn in ``ax`` (lines and line collections such
    as error bars), in display coordinates."""
    from matplotlib.collections import LineCollection

    pieces = []
    for line in ax.lines:
        xy = line.get_transform().transform(np.asarray(line.get_xydata(), dtype=float))
        if len(xy) > 1 and line.get_linestyle() not in ("None", "", " "):
            pieces.append(np.hstack([xy[:-1], xy[1:]]))
    for coll in ax.collections:
        if isinstance(coll, LineCollection):
            tr = coll.get_transform()
            for seg in coll.get_segments():
                xy = tr.transform(np.asarray(seg, dtype=float))
                if len(xy) > 1:
                    pieces.append(np.hstack([xy[:-1], xy[1:]]))
    if not pieces:
        return np.zeros((0, 4))
    segs = np.vstack(pieces)
    out: np.ndarray = segs[np.isfinite(segs).all(axis=1)]
    return out


def place_labels(
    ax: Axes,
    x: Sequence[float] | np.ndarray,
    y: Sequence[float] | np.ndarray,
    texts: Sequence[str],
    *,
    fontsize: float = 8.0,
    colors: Sequence[Any] | None = None,
    weights: Sequence[str] | None = None,
    marker_px: float = 12.0,
    pad_px: float = 2.0,
    max_distance: float = 0.5,
) -> PlacedLabels:
    """Label the points ``(x[i], y[i])`` of ``ax`` with ``texts[i]`` so that no two labels
    overlap, no label covers a point, and every label stays inside the axes.

    Call it once the axes are otherwise complete (limits, legend, layout): the search runs
    on the figure as it would be drawn now, and the labels never change the layout. Labels
    are placed in the given order, so put the ones that matter most first. A label that had
    to move away from its point is joined to it by a thin leader line.

    Parameters
    ----------
    ax : Axes
    x, y : sequence of float
        The points, in data coordinates (non-finite points get no label).
    texts : sequence of str
        One label per point.
    fontsize : float
        Label size (points).
    colors, weights : sequence, optional
        Per-label text colour and font weight (e.g. ``"bold"`` for the points that
        matter).
    marker_px : float
        Side (pixels) of the square around each point that no label may cover.
    pad_px : float
        Free margin (pixels) around every label.
    max_distance : float
        Farthest a label may go from its point, as a fraction of the axes' diagonal.

    Returns
    -------
    PlacedLabels
        The texts (None where no place was found), the leader lines, the unplaced indices.

    Raises
    ------
    ValueError
        If ``x``, ``y`` and ``texts`` differ in length.
    """
    xs = np.asarray(x, dtype=float)
    ys = np.asarray(y, dtype=float)
    if not (len(xs) == len(ys) == len(texts)):
        raise ValueError(
            f"place_labels needs one text per point, got {len(xs)} x, {len(ys)} y and "
            f"{len(texts)} texts"
        )
    parent: Any = ax.get_figure()
    while parent is not None and not isinstance(parent, Figure):  # a SubFigure: its root
        parent = getattr(parent, "figure", None)
    if parent is None:
        raise ValueError("place_labels needs axes that belong to a figure")
    fig: Figure = parent
    if not hasattr(fig.canvas, "get_renderer"):  # a bare Figure(): measure with Agg
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig)
    fig.draw_without_rendering()  # the final layout: axes position and limits
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]  # checked above
    frame = ax.get_window_extent(renderer)
    limits = np.array([frame.x0, frame.y0, frame.x1, frame.y1])
    pts = ax.transData.transform(np.column_stack([xs, ys]))
    half = marker_px / 2
    valid = np.isfinite(pts).all(axis=1)
    markers = np.column_stack([pts - half, pts + half])[valid]
    segs = _line_segments(ax)
    reach = max_distance * math.hypot(frame.width, frame.height)
    step = max(fontsize * 0.6, 4.0)
    near = half + 1.0 + step  # farther than this from its point, a label gets a leader

    out = PlacedLabels()
    boxes = np.zeros((0, 4))
    leaders = np.zeros((0, 4))
    for i, text in enumerate(texts):
        if not valid[i]:
            out.texts.append(None)
            out.unplaced.append(i)
            continue
        kw: dict[str, Any] = {"fontsize": fontsize}
        if colors is not None:
            kw["color"] = colors[i]
        if weights is not None:
            kw["fontweight"] = weights[i]
        t = ax.text(0, 0, text, ha="center", va="center", **kw)
        t.set_in_layout(False)
        ext = t.get_window_extent(renderer)
        w, h = ext.width + 2 * pad_px, ext.height + 2 * pad_px
        close = np.hypot(*(pts[valid] - pts[i]).T) < 8 * marker_px
        away = pts[i] - pts[valid][close].mean(axis=0)
        pref = math.degrees(math.atan2(away[1], away[0])) if np.hypot(*away) > 1 else 0.0
        angles = sorted(_ANGLES, key=lambda a: abs((a - pref + 180) % 360 - 180))
        best: tuple[float, float, float] | None = None
        # 0: clear of the plot's lines, leaders crossing nothing; 1: leaders crossing no
        # label; 2 (last resort): anywhere in the axes free of labels and markers
        for level in (0, 1, 2):
            r = half + 1.0
            while best is None and r <= (reach if level < 2 else 2 * reach):
                for deg in angles:
                    cx = pts[i, 0] + math.cos(math.radians(deg)) * (w / 2 + r)
                    cy = pts[i, 1] + math.sin(math.radians(deg)) * (h / 2 + r)
                    box = np.array([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2])
                    if (box[:2] < limits[:2]).any() or (box[2:] > limits[2:]).any():
                        continue
                    if _overlaps(box, boxes).any() or _overlaps(box, markers).any():
                        continue
                    if level == 0 and _crosses(box, segs):
                        continue
                    if r > near:  # its leader line crosses no label (no other leader)
                        lead = _leader(cx, cy, w, h, pad_px, pts[i])
                        if level == 0 and _segments_cross(lead, leaders):
                            continue
                        if level < 2 and any(_crosses(b, lead[None]) for b in boxes):
                            continue
                    best = (cx, cy, r)
                    break
                r += max(step, 0.1 * r)
            if best is not None:
                break
        if best is None:
            t.remove()
            out.texts.append(None)
            out.unplaced.append(i)
            continue
        cx, cy, r = best
        tx, ty = ax.transData.inverted().transform((cx, cy))
        t.set_position((float(tx), float(ty)))
        boxes = np.vstack([boxes, [cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2]])
        out.texts.append(t)
        if r > near:
            lead = _leader(cx, cy, w, h, pad_px, pts[i])
            end = ax.transData.inverted().transform(lead.reshape(2, 2))
            (line,) = ax.plot(
                end[:, 0],
                end[:, 1],
                "-",
                color="0.55",
                lw=0.6,
                zorder=1.5,
                scalex=False,
                scaley=False,
            )
            line.set_in_layout(False)
            out.leaders.append(line)
            leaders = np.vstack([leaders, lead])
            segs = np.vstack([segs, lead])
    return out
