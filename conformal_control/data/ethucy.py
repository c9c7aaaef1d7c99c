"""ETH/UCY in the Social-GAN / Trajectron++ text form (``frame ped_id x y``, metres).

The data folder holds one sub-folder per *test scene* (``eth``, ``hotel``, ``univ``,
``zara1``, ``zara2``), each with ``train/``, ``val/`` and ``test/`` folders: the standard
leave-one-scene-out split (``<scene>/test`` is that scene, ``<scene>/train`` the other
four). Samples are 0.4 s apart (2.5 fps); the frame numbers step by 10 (6 for ETH).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .paths import ethucy_root, missing
from .tracks import Tracks

__all__ = ["ETHUCY_FPS", "ETHUCY_SCENES", "ethucy_files", "read_ethucy"]

ETHUCY_FPS = 2.5
ETHUCY_SCENES = ("eth", "hotel", "univ", "zara1", "zara2")
SPLITS = ("train", "val", "test")


def read_ethucy(path: str | os.PathLike[str]) -> Tracks:
    """Read one file; frames are renumbered to sample indices (frame / frame step).

    Raises
    ------
    ValueError
        For a malformed row or a file without rows.
    """
    path = Path(path)
    if not path.is_file():
        raise missing(path, "ETH/UCY file")
    try:
        arr = np.loadtxt(path, ndmin=2)
    except ValueError as exc:
        raise ValueError(f"{path}: malformed row ({exc}); expected 'frame ped_id x y'") from exc
    if arr.size == 0:
        raise ValueError(f"{path}: no rows")
    if arr.shape[1] != 4:
        raise ValueError(f"{path}: expected 4 columns (frame ped_id x y), got {arr.shape[1]}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{path}: non-finite values")
    frames = np.unique(arr[:, 0])
    steps = np.diff(frames)
    step = float(np.min(steps)) if steps.size else 1.0
    index = np.rint(arr[:, 0] / step).astype(np.int64)
    tracks: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for pid in np.unique(arr[:, 1]).astype(int):
        sel = arr[:, 1] == pid
        order = np.argsort(index[sel])
        f = index[sel][order]
        xy = arr[sel][order, 2:4]
        keep = np.concatenate([[True], np.diff(f) > 0])  # drop duplicated frames
        tracks[int(pid)] = (f[keep], xy[keep])
    return Tracks(ETHUCY_FPS, tracks, source=str(path), meta={"frame_step": step})


def ethucy_files(
    scene: str, split: str, data_root: str | os.PathLike[str] | None = None
) -> list[Path]:
    """The files of ``<scene>/<split>`` (sorted), with a clear error if absent."""
    if scene not in ETHUCY_SCENES:
        raise ValueError(f"unknown ETH/UCY scene {scene!r}; one of {', '.join(ETHUCY_SCENES)}")
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; one of {', '.join(SPLITS)}")
    folder = ethucy_root(data_root) / scene / split
    files = sorted(folder.glob("*.txt"))
    if not files:
        raise missing(folder, f"ETH/UCY {scene}/{split} data")
    return files
