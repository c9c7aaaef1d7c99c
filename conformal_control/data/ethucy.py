"""ETH/UCY in the Social-GAN / Trajectron++ text form (``frame ped_id x y``, metres).

The data folder holds one sub-folder per *test scene* (``eth``, ``hotel``, ``univ``,
``zara1``, ``zara2``), each with ``train/``, ``val/`` and ``test/`` folders: the standard
leave-one-scene-out split (``<scene>/test`` is that scene, ``<scene>/train`` the other
four). Samples are 0.4 s apart (2.5 fps); the frame numbers step by 10 (6 for ETH).

To replay a scene at a control rate, :func:`read_ethucy` can interpolate every track to
``fps`` frames per second the way the TrajNet loader does
(:func:`conformal_control.data.trajnet.upsample`: a cubic spline through the samples,
linear for runs of fewer than 4 samples), separately on each run of consecutive samples
so that a track's gaps stay gaps (NaN in a scene) instead of being bridged by the spline.
Frame numbers then count frames at ``fps`` from sample 0 (sample index x fps / 2.5).
:func:`ethucy_recording` finds the full recording of one scene (its ``test/`` files).

**The clock of biwi_eth.** These files are the Social-LSTM / Social-GAN copies, read by the
trajectory-prediction literature as one row every 0.4 s. For ETH's ``seq_eth``
(``biwi_eth.txt``) that is not the recording's clock: the original annotation
(``seq_eth/obsmat.txt``) samples the video every 6 frames at 2.5 samples per second (0.4 s per
6 frames, per the dataset's own ``info.txt``), while the copy steps its frame numbers by 10 for
consecutive samples, so one of its rows is 10 x 0.4 / 6 = 0.667 s apart. Read at 0.4 s, its
pedestrians walk at a median 2.45 m/s (90th percentile 3.06 m/s) against 0.52-1.27 m/s on the
five other recordings; at 0.667 s per row, 1.47 m/s, an ordinary walking speed.
:data:`ETHUCY_ORIGINAL_RATE` holds the rows per second of each recording on its original
clock (``rate`` of :func:`read_ethucy`); the scene form ``ethucy:<recording>:corrected`` uses
it, the plain form keeps the literature's 2.5 rows per second.
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path

import numpy as np

from ..core.exceptions import DataFormatError
from .paths import ethucy_root, missing
from .tracks import Tracks, check_frames, file_agent_ids, read_rows

__all__ = [
    "ETHUCY_FPS",
    "ETHUCY_ORIGINAL_RATE",
    "ETHUCY_RECORDINGS",
    "ETHUCY_SCENES",
    "ethucy_files",
    "ethucy_recording",
    "read_ethucy",
]

ETHUCY_FPS = 2.5
#: Rows per second of each recording on its original clock, where it is not
#: :data:`ETHUCY_FPS` (see the module docstring: biwi_eth's rows are 0.667 s apart).
ETHUCY_ORIGINAL_RATE: dict[str, float] = {"biwi_eth": 1.5}
ETHUCY_SCENES = ("eth", "hotel", "univ", "zara1", "zara2")
SPLITS = ("train", "val", "test")
#: The full recordings: ``<scene>/test/<stem>.txt`` (univ has two).
ETHUCY_RECORDINGS: dict[str, str] = {
    "biwi_eth": "eth",
    "biwi_hotel": "hotel",
    "students001": "univ",
    "students003": "univ",
    "crowds_zara01": "zara1",
    "crowds_zara02": "zara2",
}


def _runs(frames: np.ndarray) -> list[slice]:
    """Slices of consecutive frame numbers (step 1) in an increasing array."""
    breaks = np.flatnonzero(np.diff(frames) != 1) + 1
    bounds = [0, *breaks.tolist(), len(frames)]
    return [slice(a, b) for a, b in itertools.pairwise(bounds)]


def _interpolate(
    tracks: dict[int, tuple[np.ndarray, np.ndarray]], factor: int
) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], int]:
    from .trajnet import upsample

    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    n_gaps = 0
    for pid, (f, xy) in tracks.items():
        fs, xys = [], []
        runs = _runs(f)
        n_gaps += len(runs) - 1
        for run in runs:
            full, pos = upsample(f[run] * factor, xy[run])
            fs.append(full)
            xys.append(pos)
        out[pid] = (np.concatenate(fs), np.concatenate(xys))
    return out, n_gaps


def _parse(path: Path) -> tuple[np.ndarray, list[int]]:
    """The rows of an ETH/UCY file (n, 4) and their line numbers."""
    return read_rows(path, "ETH/UCY file", "frame ped_id x y")


def read_ethucy(
    path: str | os.PathLike[str], fps: float | None = None, rate: float = ETHUCY_FPS
) -> Tracks:
    """Read one file; frames are renumbered to sample indices (frame / frame step).

    Parameters
    ----------
    path : path
        A ``frame ped_id x y`` file (metres).
    fps : float, optional
        Interpolate every track to this frame rate (a whole multiple of ``rate``, e.g. 30;
        see the module docstring); frame numbers are then frames at ``fps``. Default: keep
        the samples (frame numbers are sample indices).
    rate : float
        Rows per second of the file (2.5; 1.5 for biwi_eth on its original clock, see
        :data:`ETHUCY_ORIGINAL_RATE`).

    Raises
    ------
    ValueError
        For a malformed row, a file without rows, or an ``fps`` that is not a whole
        multiple of 2.5.
    """
    factor = 1
    if not (isinstance(rate, (int, float)) and np.isfinite(rate) and rate > 0):
        raise ValueError(f"rate must be a number of rows per second > 0, got {rate!r}")
    if fps is not None:
        ratio = float(fps) / float(rate)
        factor = round(ratio)
        if not (np.isfinite(ratio) and factor >= 1 and abs(ratio - factor) < 1e-9):
            raise ValueError(f"fps must be a whole multiple of {rate:g} (e.g. 30), got {fps!r}")
    path = Path(path)
    if not path.is_file():
        raise missing(path, "ETH/UCY file")
    arr, lines = _parse(path)
    raw = arr[:, 0]
    uniq = np.unique(raw)
    steps = np.diff(uniq)
    # the file's step is its most common gap between consecutive frames (ties: the
    # smaller): one misplaced row must not change it (it did when the smallest gap was
    # taken, making every pedestrian slower); such a row is an error, named below
    if steps.size:
        values, counts = np.unique(steps, return_counts=True)
        step = float(values[np.argmax(counts)])
    else:
        step = 1.0
    if step != round(step) or step < 1:
        raise DataFormatError(
            f"{path}: frames are {step:g} apart, expected a whole number of video frames"
        )
    # ``rate`` rows per second, ``step`` video frames apart: the video runs at rate x step
    frames = check_frames(raw, float(rate) * step, path, lines, step=int(step))
    ids = file_agent_ids(arr[:, 1], path, lines)
    index = (frames - int(frames.min())) // int(step) + int(frames.min()) // int(step)
    tracks: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    n_dup = 0
    for pid in np.unique(ids):
        sel = np.flatnonzero(ids == pid)
        order = sel[np.argsort(index[sel], kind="stable")]
        f = index[order]
        xy = arr[order, 2:4]
        same = np.flatnonzero(np.diff(f) == 0)
        if same.size:
            differ = ~np.all(xy[same] == xy[same + 1], axis=1)
            if differ.any():
                i = int(same[np.argmax(differ)])
                raise DataFormatError(
                    f"{path}:{lines[order[i + 1]]}: pedestrian {int(pid)} has a second, "
                    f"different position for frame {int(raw[order[i]]):d} (first at line "
                    f"{lines[order[i]]})"
                )
            n_dup += same.size  # exact repeats of a row: counted, kept once
            keep = np.concatenate([[True], np.diff(f) > 0])
            f, xy = f[keep], xy[keep]
        tracks[int(pid)] = (f, xy)
    meta: dict[str, object] = {
        "frame_step": step,
        "format": "ethucy",
        "n_rows": len(arr),
        "n_duplicate_rows": n_dup,
        "rate": float(rate),
    }
    if fps is None:
        return Tracks(float(rate), tracks, source=str(path), meta=meta)
    tracks, n_gaps = _interpolate(tracks, factor)
    meta.update(
        {
            "interpolation": "cubic spline per run of consecutive samples",
            "samples_per_frame": 1.0 / factor,
            "n_track_gaps": n_gaps,
        }
    )
    return Tracks(float(fps), tracks, source=str(path), meta=meta)


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


def ethucy_recording(stem: str, data_root: str | os.PathLike[str] | None = None) -> Path:
    """Path of a full recording (``biwi_eth``, ``students001``, ...; see ETHUCY_RECORDINGS)."""
    if stem not in ETHUCY_RECORDINGS:
        raise ValueError(
            f"unknown ETH/UCY recording {stem!r}; one of {', '.join(ETHUCY_RECORDINGS)}"
        )
    path = ethucy_root(data_root) / ETHUCY_RECORDINGS[stem] / "test" / f"{stem}.txt"
    if not path.is_file():
        raise missing(path, f"ETH/UCY recording {stem}")
    return path
