"""What every animation shares: the frame size, the run's animation record, the frames
rendered for a time window, the scene's reference image cropped to the view."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["LEGIBLE_WIDTH_PX", "animation_frames", "frame_size", "load_record", "scene_image"]

#: Narrowest frame (pixels) whose text is legible: the animations' labels are 8 pt, which
#: is 10 px at the default 9.6 in x 80 dpi = 768 px; at 60 dpi they shrink to 7 px.
LEGIBLE_WIDTH_PX = 720


def frame_size(width: float, dpi: int) -> tuple[int, int]:
    """Even pixel sizes (H.264 needs them) of a ``width`` inch frame at ``dpi``; warns
    (:class:`~conformal_control.core.exceptions.SuspiciousValueWarning`) when the frame is too
    narrow for its text to be read (:data:`LEGIBLE_WIDTH_PX`).

    Raises
    ------
    ValueError
        For a non-positive width or dpi.
    """
    import warnings

    from ...core.exceptions import SuspiciousValueWarning

    if not (math.isfinite(width) and width > 0 and dpi > 0):
        raise ValueError(f"width and dpi must be > 0, got width={width!r}, dpi={dpi!r}")
    px_w = 2 * round(width * dpi / 2)
    px_h = 2 * round(width * dpi * 0.45 / 2)
    if px_w < LEGIBLE_WIDTH_PX:
        need = math.ceil(LEGIBLE_WIDTH_PX / width)
        warnings.warn(
            SuspiciousValueWarning(
                f"the animation will be {px_w} x {px_h} px ({width:g} in at {dpi} dpi): its "
                f"8 pt labels are {8 * dpi / 72:.0f} px tall, hard to read below "
                f"{LEGIBLE_WIDTH_PX} px wide; use --dpi {need} or more (or a larger --width)"
            ),
            stacklevel=3,
        )
    return px_w, px_h


def load_record(source: str | Path | Mapping[str, Any]) -> dict[str, Any]:
    """The animation record: a run directory, an ``animation.npz`` or a dict.

    Raises
    ------
    FileNotFoundError
        If the run directory has no ``animation.npz`` (runs made with
        ``record_animation=False`` or by an older version: run them again).
    """
    if isinstance(source, Mapping):
        return dict(source)
    path = Path(source)
    if path.is_dir():
        path = path / "animation.npz"
    if not path.is_file():
        raise FileNotFoundError(
            f"{path} not found: the run directory has no animation record; run it again "
            "with this version of conformal-control (it writes animation.npz by default)"
        )
    with np.load(path, allow_pickle=False) as data:
        rec = {k: data[k] for k in data.files}
    for key, value in rec.items():
        if isinstance(value, np.ndarray) and value.ndim == 0:
            rec[key] = value.item()
    return rec


def animation_frames(
    record: Mapping[str, Any],
    start: float | None = None,
    end: float | None = None,
    fps: float = 10.0,
) -> np.ndarray:
    """Indices of the run's frames rendered for a time window and an output frame rate.

    The animation plays in real time: one output frame every ``scene fps / fps`` run
    frames (at least 1).

    Parameters
    ----------
    record : mapping
        The run's animation record (its frame times ``t`` in s, the scene's ``fps``).
    start, end : float, optional
        The time window (s, on the record's ``t``; default: the whole run).
    fps : float
        Output frames per second.
    """
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be > 0, got {fps!r}")
    t = np.asarray(record["t"], dtype=float)
    if t.size == 0:
        raise ValueError("the run has no frames to animate")
    lo = -math.inf if start is None else start
    hi = math.inf if end is None else end
    if lo > hi:
        raise ValueError(f"--start ({start}) is after --end ({end})")
    idx = np.flatnonzero((t >= lo - 1e-9) & (t <= hi + 1e-9))
    if idx.size == 0:
        raise ValueError(
            f"no frame in the window [{start}, {end}] s; the run spans {t[0]:g}..{t[-1]:g} s"
        )
    stride = max(1, round(float(record["fps"]) / fps))
    return idx[::stride]


def scene_image(
    rec: Mapping[str, Any],
    xlim: tuple[float, float],
    ylim: tuple[float, float],
    px_w: int,
    plt: Any,
) -> tuple[np.ndarray, tuple[float, float, float, float]] | None:
    """The scene's reference image cropped to the view and thinned out to about the
    axes' resolution (drawing the full image at every frame dominates the rendering
    time), with its extent; None without an image.

    Parameters
    ----------
    rec : mapping
        The animation record (``image``: the file, ``extent``: the scene's size in m).
    xlim, ylim : (float, float)
        The view (m; ``ylim`` top-down, the image convention).
    px_w : int
        The frame's width (pixels).
    plt : module
        ``matplotlib.pyplot`` (its ``imread``).
    """
    image = str(rec.get("image") or "")
    ext = np.asarray(rec["extent"], dtype=float)
    if not (image and Path(image).is_file() and np.isfinite(ext).all()):
        return None
    img = plt.imread(image)
    sx, sy = img.shape[1] / ext[0], img.shape[0] / ext[1]
    c0, c1 = max(int(xlim[0] * sx), 0), min(math.ceil(xlim[1] * sx), img.shape[1])
    r0, r1 = max(int(ylim[1] * sy), 0), min(math.ceil(ylim[0] * sy), img.shape[0])
    step = max(1, int((c1 - c0) / (0.6 * px_w)))
    return img[r0:r1:step, c0:c1:step], (c0 / sx, c1 / sx, r1 / sy, r0 / sy)
