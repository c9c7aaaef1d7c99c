"""Stanford Drone Dataset: raw ``annotations.txt`` files and the pixel-to-metre scales.

Raw format (no header; the first line is an annotation)::

    track_id xmin ymin xmax ymax frame lost occluded generated "label"

Positions are bounding-box centres in pixels of the full-resolution frame (origin at the
image's top-left corner, x to the right, y down). The loader keeps one label (default
"Pedestrian"), drops rows with ``lost = 1`` (outside the view), and converts pixels to
metres with the video's ``scale`` from ``estimated_scales.yaml`` (metres per pixel).
Frame numbers stay the video's 30 fps frame numbers.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from ..core.exceptions import DataFormatError, InputError
from .paths import missing, read_data_text, sdd_root
from .tracks import Tracks, check_frames, file_agent_ids

__all__ = [
    "SDD_FPS",
    "SDDVideo",
    "load_scales",
    "read_annotations",
    "sdd_video",
]

SDD_FPS = 30.0
_N_FIELDS = 10


@dataclass(frozen=True)
class SDDVideo:
    """Files and geometry of one SDD video."""

    scene: str
    video: int
    root: Path
    m_per_px: float

    @property
    def name(self) -> str:
        return f"{self.scene}_{self.video}"

    @property
    def folder(self) -> Path:
        return self.root / "annotations" / self.scene / f"video{self.video}"

    @property
    def annotations(self) -> Path:
        return self.folder / "annotations.txt"

    @property
    def image(self) -> Path:
        return self.folder / "reference.jpg"

    @property
    def trajnet(self) -> Path:
        return self.root / "trajnet_pixels" / f"{self.scene}_{self.video}.txt"

    def image_size_px(self) -> tuple[int, int] | None:
        """(width, height) of the reference image in pixels, or None if it is missing."""
        if not self.image.exists():
            return None
        import warnings

        from PIL import Image, UnidentifiedImageError  # matplotlib's own dependency

        try:
            with warnings.catch_warnings():  # the size is checked below, against our limit
                warnings.simplefilter("ignore", Image.DecompressionBombWarning)
                with Image.open(self.image) as im:  # reads the header only
                    size = int(im.size[0]), int(im.size[1])
        except Image.DecompressionBombError:
            size = (-1, -1)  # more than twice PIL's own limit: refused below
        except (UnidentifiedImageError, OSError) as exc:
            reason = "not a readable image" if isinstance(exc, UnidentifiedImageError) else exc
            raise DataFormatError(
                f"{self.image}: the scene's reference image cannot be read ({reason}); "
                "fetch it again with `conformal-control fetch-data`"
            ) from None
        if size[0] < 0 or size[0] * size[1] > MAX_IMAGE_PIXELS:
            claims = "claims" if size[0] < 0 else f"claims {size[0]} x {size[1]} pixels,"
            raise DataFormatError(
                f"{self.image}: the scene's reference image {claims} more than the "
                f"{MAX_IMAGE_PIXELS:,} pixels a reference frame may have (a corrupt or "
                "hostile file, a decompression bomb); fetch it again with "
                "`conformal-control fetch-data`"
            )
        return size


#: Most pixels a reference image may have (SDD's are about 3 million): a larger one is
#: refused from its header, before anything is decoded (a decompression bomb).
MAX_IMAGE_PIXELS = 50_000_000


def load_scales(root: Path) -> dict[tuple[str, int], float]:
    """Metres per pixel for every video listed in ``estimated_scales.yaml``."""
    path = root / "estimated_scales.yaml"
    if not path.is_file():
        raise missing(path, "SDD pixel scales (estimated_scales.yaml)")
    try:
        # libyaml's safe loader when PyYAML has it (the same documents, ten times faster)
        text = read_data_text(path, "SDD scales file")
        data = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except yaml.YAMLError as exc:
        raise DataFormatError(f"{path}: not valid YAML ({exc})") from None
    except RecursionError:
        raise DataFormatError(f"{path}: nested too deeply to be a table of scales") from None
    scales: dict[tuple[str, int], float] = {}
    if not isinstance(data, dict):
        raise DataFormatError(f"{path}: expected a mapping scene -> videoN -> scale")
    for scene, videos in data.items():
        if videos is None:
            continue
        if not isinstance(videos, dict):
            raise DataFormatError(
                f"{path}: scene {scene} must map videoN to {{scale: ...}}, got a "
                f"{type(videos).__name__}"
            )
        for video, entry in videos.items():
            number = str(video).removeprefix("video")
            if not number.isdigit():
                raise DataFormatError(f"{path}: {scene}/{video} is not named videoN")
            scale = entry.get("scale") if isinstance(entry, dict) else None
            ok = (
                isinstance(scale, (int, float))
                and not isinstance(scale, bool)
                and math.isfinite(scale)
                and scale > 0
            )
            if not ok:
                raise DataFormatError(
                    f"{path}: {scene}/{video} needs a scale in metres per pixel > 0, got {entry!r}"
                )
            scales[(str(scene), int(number))] = float(scale)  # type: ignore[arg-type]
    return scales


def sdd_video(scene: str, video: int, data_root: str | os.PathLike[str] | None = None) -> SDDVideo:
    """Locate an SDD video and its scale."""
    root = sdd_root(data_root)
    scales = load_scales(root)
    if (scene, video) not in scales:
        videos = sorted(v for s, v in scales if s == scene)
        if videos:
            hint = f"{scene} has videos {', '.join(str(v) for v in videos)}"
        else:
            import difflib

            names = sorted({s for s, _ in scales})
            close = difflib.get_close_matches(scene, names, n=1, cutoff=0.6)
            hint = (f"did you mean {close[0]!r}? " if close else "") + (
                f"SDD scenes: {', '.join(names)}"
            )
        raise InputError(
            f"no SDD video {scene}/video{video} in {root / 'estimated_scales.yaml'}; {hint}"
        )
    return SDDVideo(scene, video, root, scales[(scene, video)])


def read_annotations(
    path: str | os.PathLike[str],
    m_per_px: float,
    label: str = "Pedestrian",
) -> Tracks:
    """Read a raw SDD ``annotations.txt`` into :class:`Tracks` (metres, 30 fps frames).

    Raises
    ------
    DataNotFoundError
        If the file does not exist.
    ValueError
        On a malformed or truncated line (the message gives the line number), duplicate
        (track, frame) rows, or a file without any row of the requested label.
    """
    path = Path(path)
    if not path.is_file():
        raise missing(path, "SDD annotations")
    if not (np.isfinite(m_per_px) and m_per_px > 0):
        raise ValueError(f"m_per_px must be a finite number > 0, got {m_per_px!r}")
    wanted = f'"{label}"'
    numbers: list[list[str]] = []
    tags: list[str] = []
    linenos: list[int] = []
    for lineno, line in enumerate(read_data_text(path, "SDD annotations").splitlines(), start=1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != _N_FIELDS:
            raise DataFormatError(
                f"{path}:{lineno}: expected {_N_FIELDS} space-separated fields "
                f"(track_id xmin ymin xmax ymax frame lost occluded generated label), got "
                f"{len(parts)}; the file is malformed or truncated"
            )
        tag = parts[9]
        if len(tag) < 3 or tag[0] != '"' or tag[-1] != '"':
            raise DataFormatError(
                f"{path}:{lineno}: the label {tag} is not a quoted name such as "
                '"Pedestrian"; the file is malformed or truncated'
            )
        numbers.append(parts[:9])
        tags.append(tag)
        linenos.append(lineno)
    if not numbers:
        raise DataFormatError(f"{path}: no {label} rows (the file is empty); nothing to simulate")
    try:
        num = np.array(numbers, dtype=float)
    except ValueError:
        for parts, lineno in zip(numbers, linenos, strict=True):
            try:
                [float(v) for v in parts]
            except ValueError as exc:
                raise DataFormatError(f"{path}:{lineno}: non-numeric field ({exc})") from None
        raise  # pragma: no cover - some row failed above
    ints = num[:, [0, 5, 6]]
    bad_int = ~(np.isfinite(ints) & (ints == np.rint(ints))).all(axis=1)
    if bad_int.any():
        k = int(np.argmax(bad_int))
        raise DataFormatError(
            f"{path}:{linenos[k]}: track_id, frame and lost must be whole numbers, got "
            f"{' '.join(numbers[k][i] for i in (0, 5, 6))}"
        )
    bad_box = ~np.isfinite(num[:, 1:5]).all(axis=1)
    if bad_box.any():
        k = int(np.argmax(bad_box))
        raise DataFormatError(
            f"{path}:{linenos[k]}: non-finite box coordinate ({' '.join(numbers[k][1:5])}); "
            "SDD boxes are finite pixel coordinates (an absent agent is marked lost=1)"
        )
    # every row, pedestrian or not: a wrong frame number anywhere is an error
    check_frames(num[:, 5], SDD_FPS, path, linenos)
    file_agent_ids(num[:, 0], path, linenos)
    is_label = np.array(tags) == wanted
    lost = num[:, 6] != 0
    n_other = int((~is_label).sum())
    n_lost = int((is_label & lost).sum())
    sel = is_label & ~lost
    if not sel.any():
        raise ValueError(f"{path}: no {label} rows with lost=0; nothing to simulate")
    block = num[sel]
    rows = block  # counted below as n_rows
    arr = np.column_stack(
        [
            block[:, 0],
            block[:, 5],
            0.5 * (block[:, 1] + block[:, 3]),
            0.5 * (block[:, 2] + block[:, 4]),
        ]
    )
    order = np.lexsort((arr[:, 1], arr[:, 0]))
    arr = arr[order]
    tracks: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    ids, starts = np.unique(arr[:, 0].astype(np.int64), return_index=True)
    bounds = [*starts.tolist(), len(arr)]
    for k, tid in enumerate(ids):
        block = arr[bounds[k] : bounds[k + 1]]
        frames = block[:, 1].astype(np.int64)
        if np.any(np.diff(frames) == 0):
            dup = int(frames[np.flatnonzero(np.diff(frames) == 0)[0]])
            raise DataFormatError(f"{path}: track {tid} has two rows for frame {dup}")
        tracks[int(tid)] = (frames, block[:, 2:4] * m_per_px)
    return Tracks(
        fps=SDD_FPS,
        tracks=tracks,
        source=str(path),
        meta={
            "m_per_px": m_per_px,
            "label": label,
            "n_lost_rows": n_lost,
            "n_other_label_rows": n_other,
            "n_rows": len(rows),
        },
    )
