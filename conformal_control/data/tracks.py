"""Agent trajectories: the common currency of every loader."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["MAX_AGENT_ID", "Tracks", "agent_ids"]

#: Largest agent id (ids are stored as 64-bit integers; float ids are exact below 2**53).
MAX_AGENT_ID = 2**53


def agent_ids(values: Any, what: str = "ids") -> np.ndarray:
    """Agent ids as an int64 array; whole numbers only, each at most ``2**53`` in size.

    Accepts integer arrays and sequences, and floats that are whole numbers (``3.0``, as
    text files hold them). Raises :class:`~conformal_control.exceptions.InputError` for a
    fractional, non-finite, boolean, non-numeric or too large id, naming it; ``what`` says
    where the ids came from. Uniqueness is the caller's to check (per sample, per frame).
    """
    from ..exceptions import InputError

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
