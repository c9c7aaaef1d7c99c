"""Agent trajectories: the common currency of every loader."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "MAX_AGENT_ID",
    "MAX_FRAME",
    "MAX_FRAME_GAP_S",
    "Tracks",
    "agent_ids",
    "check_frames",
    "file_agent_ids",
]

#: Longest time (s) a recording may go without any row: a longer jump between consecutive
#: frame numbers of a file is a wrong frame number. (Scenes are stored densely over their
#: frame range, so one row at frame 2e9 would ask for billions of frames of memory.)
MAX_FRAME_GAP_S = 600.0
#: Largest frame number a data file may hold.
MAX_FRAME = 2**31 - 1

#: Largest agent id (ids are stored as 64-bit integers; float ids are exact below 2**53).
MAX_AGENT_ID = 2**53


def agent_ids(values: Any, what: str = "ids") -> np.ndarray:
    """Agent ids as an int64 array; whole numbers only, each at most ``2**53`` in size.

    Accepts integer arrays and sequences, and floats that are whole numbers (``3.0``, as
    text files hold them). Raises :class:`~conformal_control.core.exceptions.InputError` for a
    fractional, non-finite, boolean, non-numeric or too large id, naming it; ``what`` says
    where the ids came from. Uniqueness is the caller's to check (per sample, per frame).
    """
    from ..core.exceptions import InputError

    if not isinstance(values, np.ndarray) and any(
        isinstance(v, (bool, np.bool_)) for v in np.ravel(np.asarray(values, dtype=object))
    ):
        raise InputError(f"{what} must be whole numbers, got a boolean")
    arr = np.asarray(values)
    if arr.dtype == bool or arr.dtype.kind not in "iuf":
        if arr.dtype == object and all(
            isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in arr.flat
        ):
            arr = np.array([int(v) for v in arr.flat], dtype=object).reshape(arr.shape)
            big = [int(v) for v in arr.flat if abs(int(v)) > MAX_AGENT_ID]
            if big:
                raise InputError(f"{what}: id {big[0]} is too large (at most 2**53)")
            return arr.astype(np.int64)
        if arr.size == 0:
            return np.zeros(arr.shape, dtype=np.int64)
        raise InputError(f"{what} must be whole numbers, got {arr.dtype} values")
    if arr.dtype.kind == "f":
        bad = ~np.isfinite(arr) | (arr != np.round(arr))
        if bad.any():
            raise InputError(f"{what} must be whole numbers, got {arr[bad].flat[0]!r}")
    big = np.abs(arr.astype(float)) > MAX_AGENT_ID
    if big.any():
        raise InputError(f"{what}: id {arr[big].flat[0]!r} is too large (at most 2**53)")
    out: np.ndarray = arr.astype(np.int64)
    return out


@dataclass
class Tracks:
    """Trajectories of agents at a fixed frame rate, in metres.

    Attributes
    ----------
    fps : float
        Frame rate of the frame numbers.
    tracks : dict
        ``id -> (frames, xy)`` with ``frames`` an increasing int array of shape (n,)
        (video frame numbers; gaps allowed) and ``xy`` of shape (n, 2) in metres.
    source : str
        Where the tracks came from (file path or generator name).
    meta : dict
        Loader-specific facts (e.g. ``m_per_px``, counts of dropped rows).
    """

    fps: float
    tracks: dict[int, tuple[np.ndarray, np.ndarray]]
    source: str = ""
    meta: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.tracks)

    @property
    def ids(self) -> list[int]:
        return sorted(self.tracks)

    def frame_range(self) -> tuple[int, int]:
        """(first, last) frame number over all tracks."""
        if not self.tracks:
            raise ValueError(f"no tracks in {self.source or 'this data'}")
        lo = min(int(f[0]) for f, _ in self.tracks.values())
        hi = max(int(f[-1]) for f, _ in self.tracks.values())
        return lo, hi

    def dense(self, first: int, last: int) -> tuple[np.ndarray, np.ndarray]:
        """Dense array of positions for frames ``first..last`` (inclusive).

        Returns ``(ids, positions)`` with ``positions`` of shape (last - first + 1, M, 2),
        NaN where an agent is absent, for the M agents present at least once in the window.
        """
        n_frames = last - first + 1
        if n_frames <= 0:
            raise ValueError(f"empty frame window [{first}, {last}]")
        keep = [i for i, (f, _) in sorted(self.tracks.items()) if f[-1] >= first and f[0] <= last]
        pos = np.full((n_frames, len(keep), 2), np.nan)
        for col, i in enumerate(keep):
            f, xy = self.tracks[i]
            sel = (f >= first) & (f <= last)
            pos[f[sel] - first, col] = xy[sel]
        return np.array(keep, dtype=np.int64), pos


def _where(path: object, lines: Sequence[int] | np.ndarray | None, row: int) -> str:
    return f"{path}:{int(lines[row])}" if lines is not None else f"{path} (row {row + 1})"


def read_rows(path: str | os.PathLike[str], what: str, fields: str) -> tuple[np.ndarray, list[int]]:
    """The rows of a whitespace-separated data file of four numeric ``fields`` (an array
    (n, 4)) and their line numbers; blank lines skipped, anything else a
    ``DataFormatError`` at ``file:line``.

    Parameters
    ----------
    path : path
        The file (read through :func:`~conformal_control.data.paths.read_data_text`).
    what : str
        What the file is, for the errors (``"ETH/UCY file"``).
    fields : str
        Its columns, for the errors (``"frame ped_id x y"``).
    """
    from ..core.exceptions import DataFormatError
    from .paths import read_data_text

    rows: list[list[float]] = []
    lines: list[int] = []
    for lineno, line in enumerate(read_data_text(path, what).splitlines(), start=1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 4:
            raise DataFormatError(
                f"{path}:{lineno}: expected 4 fields ({fields}), got "
                f"{len(parts)}; the file is malformed or truncated"
            )
        try:
            rows.append([float(p) for p in parts])
        except ValueError as exc:
            raise DataFormatError(f"{path}:{lineno}: non-numeric field ({exc})") from None
        lines.append(lineno)
    if not rows:
        raise DataFormatError(f"{path}: no rows")
    arr = np.array(rows)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        raise DataFormatError(f"{path}:{lines[int(np.argmax(bad))]}: non-finite value")
    return arr, lines


def file_agent_ids(
    values: np.ndarray, path: object, lines: Sequence[int] | np.ndarray | None = None
) -> np.ndarray:
    """The id column of a data file as int64, or a ``DataFormatError`` at ``file:line``."""
    from ..core.exceptions import DataFormatError

    v = np.asarray(values, dtype=float)
    bad = ~np.isfinite(v) | (v != np.round(v)) | (np.abs(v) > MAX_AGENT_ID)
    if bad.any():
        k = int(np.argmax(bad))
        raise DataFormatError(
            f"{_where(path, lines, k)}: agent id {float(values[k]):g} is not a whole number of at "
            "most 2**53 in size"
        )
    out: np.ndarray = v.astype(np.int64)
    return out


def check_frames(
    frames: np.ndarray,
    fps: float,
    path: object,
    lines: Sequence[int] | np.ndarray | None = None,
    *,
    step: int | None = None,
) -> np.ndarray:
    """Check the frame column of a data file; return it as int64.

    Every frame is a whole number in ``[0, MAX_FRAME]``; with ``step``, every frame lies on
    the file's grid ``first + k * step``; consecutive distinct frames are at most
    :data:`MAX_FRAME_GAP_S` seconds apart. Each failure is a one-line
    ``DataFormatError`` naming the file and line.

    Parameters
    ----------
    frames : ndarray
        The frame column.
    fps : float
        The file's frame rate (frames per second).
    path : object
        The file, as named in the errors.
    lines : sequence of int, optional
        The file's line number of each row (default: rows counted from 1).
    step : int, optional
        The file's frame step (every frame on ``first + k * step``).
    """
    from ..core.exceptions import DataFormatError

    f = np.asarray(frames, dtype=float)
    bad = ~np.isfinite(f) | (f != np.round(f)) | (f < 0) | (f > MAX_FRAME)
    if bad.any():
        k = int(np.argmax(bad))
        raise DataFormatError(
            f"{_where(path, lines, k)}: frame {float(frames[k]):g} is not a whole number in "
            f"[0, {MAX_FRAME}]"
        )
    fi = f.astype(np.int64)
    first = int(fi.min()) if fi.size else 0
    if step is not None and step > 1:
        off = (fi - first) % step != 0
        if off.any():
            k = int(np.argmax(off))
            raise DataFormatError(
                f"{_where(path, lines, k)}: frame {int(fi[k])} is off the file's grid of one "
                f"sample every {step} frames (from frame {first}); the row is misplaced"
            )
    uniq = np.unique(fi)
    gaps = np.diff(uniq)
    limit = MAX_FRAME_GAP_S * fps
    if gaps.size and gaps.max() > limit:
        j = int(np.argmax(gaps > limit))
        after = int(uniq[j + 1])
        k = int(np.argmax(fi == after))
        raise DataFormatError(
            f"{_where(path, lines, k)}: frame {after} comes {after - int(uniq[j])} frames "
            f"({(after - int(uniq[j])) / fps:.0f} s) after the file's previous frame "
            f"{int(uniq[j])}, more than the {MAX_FRAME_GAP_S:g} s a recording may skip; the "
            "frame number is probably wrong"
        )
    return fi
