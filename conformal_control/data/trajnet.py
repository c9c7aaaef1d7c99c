"""TrajNet-processed SDD tracks (``frame track_id x_px y_px``, every 12th frame).

In this form a pedestrian's long track is cut into 20-sample segments with new ids. The
loader can

1. **re-link** segments that continue each other: segment B continues segment A when B
   starts exactly one sample (12 frames) after A ends and B's first position is the
   nearest, within ``max_link_distance`` metres, to A's last position extrapolated at A's
   last velocity (one-to-one assignment per frame with the Hungarian algorithm);
2. **interpolate** every (re-linked) track to the video's 30 fps frame numbers with a
   cubic spline through the samples (not-a-knot; linear for tracks of fewer than 4
   samples). Only frames between a track's first and last sample are filled.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..core.exceptions import DataFormatError
from .paths import missing
from .sdd import SDD_FPS
from .tracks import Tracks, check_frames, file_agent_ids, read_rows

__all__ = ["TRAJNET_STEP", "read_trajnet"]

TRAJNET_STEP = 12  # frames between TrajNet samples (2.5 fps at 30 fps)


def _parse(path: Path, m_per_px: float) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    arr, lines = read_rows(path, "TrajNet file", "frame track_id x_px y_px")
    frames = check_frames(arr[:, 0], SDD_FPS, path, lines, step=TRAJNET_STEP)
    ids = file_agent_ids(arr[:, 1], path, lines)
    segs: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for tid in np.unique(ids):
        sel = np.flatnonzero(ids == tid)
        order = sel[np.argsort(frames[sel], kind="stable")]
        block = arr[order]
        same = np.flatnonzero(np.diff(block[:, 0]) == 0)
        if same.size:
            i = int(same[0])
            raise DataFormatError(
                f"{path}:{lines[int(order[i + 1])]}: track {tid} has a second row for frame "
                f"{int(block[i, 0])} (first at line {lines[int(order[i])]})"
            )
        segs[int(tid)] = (frames[order], block[:, 2:4] * m_per_px)
    return segs


def relink(
    segs: dict[int, tuple[np.ndarray, np.ndarray]], step: int, max_link_distance: float
) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], int]:
    """Join segments that continue each other; returns the tracks and the number of links."""
    from scipy.optimize import linear_sum_assignment  # imported on use: the CLI starts faster

    by_start: dict[int, list[int]] = {}
    by_end: dict[int, list[int]] = {}
    for i, (f, _) in segs.items():
        by_start.setdefault(int(f[0]), []).append(i)
        by_end.setdefault(int(f[-1]), []).append(i)
    nxt: dict[int, int] = {}
    for end_frame, enders in by_end.items():
        starters = by_start.get(end_frame + step, [])
        if not starters:
            continue
        pred = []
        for i in enders:
            f, xy = segs[i]
            v = xy[-1] - xy[-2] if len(xy) > 1 else np.zeros(2)
            pred.append(xy[-1] + v)
        pred_a = np.array(pred)
        start_a = np.array([segs[j][1][0] for j in starters])
        cost = np.linalg.norm(pred_a[:, None, :] - start_a[None, :, :], axis=-1)
        rows, cols = linear_sum_assignment(cost)
        for r, c in zip(rows, cols, strict=True):
            if cost[r, c] <= max_link_distance:
                nxt[enders[r]] = starters[c]
    heads = set(segs) - set(nxt.values())
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for new_id, head in enumerate(sorted(heads)):
        chain = [head]
        while chain[-1] in nxt:
            chain.append(nxt[chain[-1]])
        out[new_id] = (
            np.concatenate([segs[i][0] for i in chain]),
            np.concatenate([segs[i][1] for i in chain]),
        )
    return out, len(nxt)


def upsample(frames: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interpolate a track to every integer frame between its first and last sample."""
    from scipy.interpolate import CubicSpline

    full = np.arange(frames[0], frames[-1] + 1)
    if len(frames) >= 4:
        return full, CubicSpline(frames, xy, axis=0)(full)
    out = np.column_stack([np.interp(full, frames, xy[:, d]) for d in range(2)])
    return full, out


def read_trajnet(
    path: str | os.PathLike[str],
    m_per_px: float,
    *,
    relink_segments: bool = True,
    interpolate: bool = True,
    max_link_distance: float = 1.0,
) -> Tracks:
    """Read a TrajNet pixel file into :class:`Tracks` (metres).

    Parameters
    ----------
    path : path
        ``trajnet_pixels/<scene>_<video>.txt``.
    m_per_px : float
        Metres per pixel of the video.
    relink_segments : bool
        Join 20-sample segments that continue each other (see module docstring).
    interpolate : bool
        Interpolate to 30 fps frame numbers; otherwise keep the 2.5 fps samples (the
        returned ``fps`` is then still 30, with gaps of 11 frames between samples).
    max_link_distance : float
        Largest distance (m) between a segment's extrapolated end and the next one's start.
    """
    path = Path(path)
    if not path.is_file():
        raise missing(path, "TrajNet SDD tracks")
    segs = _parse(path, m_per_px)
    n_links = 0
    if relink_segments:
        segs, n_links = relink(segs, TRAJNET_STEP, max_link_distance)
    if interpolate:
        segs = {i: upsample(f, xy) for i, (f, xy) in segs.items()}
    return Tracks(
        fps=SDD_FPS,
        tracks=segs,
        source=str(path),
        meta={
            "m_per_px": m_per_px,
            "format": "trajnet",
            "n_links": n_links,
            "interpolation": "cubic spline" if interpolate else "none",
        },
    )
