"""Agent trajectories: the common currency of every loader."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Tracks"]


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
