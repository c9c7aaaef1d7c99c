"""Parsed recordings kept on disk in numpy's ``.npz`` format, so a scene loads in
milliseconds after its first load.

Parsing a raw SDD annotation file takes a few hundred milliseconds (nexus_4: about 0.3 s, the
largest part of loading the scene); reading the same tracks from an uncompressed ``.npz``
takes a few milliseconds. The cache is keyed by the content of the file (BLAKE2b of its
bytes), the reader's arguments and the source code of the loaders themselves (a change of a
loader, e.g. of how duplicates are treated, reads the file again), so a stale entry is never
served. Entries live under ``$CONFORMAL_CONTROL_CACHE/tracks`` (default
``~/.cache/conformal-control/tracks``), are written to a temporary name and renamed, and an
entry that cannot be read is read from the source file again (and replaced).
``CONFORMAL_CONTROL_TRACK_CACHE=0`` turns the cache off.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..core.fileio import read_limited
from .paths import MAX_DATA_FILE_BYTES
from .tracks import Tracks

__all__ = ["CACHE_ENV_VAR", "SWITCH_ENV_VAR", "cached_tracks", "tracks_cache_dir"]

#: The environment variable naming the package's cache folder.
CACHE_ENV_VAR = "CONFORMAL_CONTROL_CACHE"
#: ``0`` turns this cache off.
SWITCH_ENV_VAR = "CONFORMAL_CONTROL_TRACK_CACHE"
#: Bumped when the file layout below changes.
_LAYOUT = 1
#: The modules whose code decides what a parsed recording is.
_LOADERS = ("sdd.py", "trajnet.py", "ethucy.py", "tracks.py", "track_cache.py")


def tracks_cache_dir() -> Path:
    """``$CONFORMAL_CONTROL_CACHE/tracks``, else ``~/.cache/conformal-control/tracks``."""
    root = os.environ.get(CACHE_ENV_VAR)
    base = Path(root).expanduser() if root else Path.home() / ".cache" / "conformal-control"
    return base / "tracks"


def _loaders_digest() -> bytes:
    h = hashlib.blake2b(digest_size=16)
    here = Path(__file__).resolve().parent
    for name in _LOADERS:
        h.update((here / name).read_bytes())
    return h.digest()


def _key(kind: str, data: bytes, args: dict[str, Any]) -> str:
    h = hashlib.blake2b(digest_size=20)
    h.update(json.dumps([_LAYOUT, kind, args], sort_keys=True).encode())
    h.update(_loaders_digest())
    h.update(data)
    return h.hexdigest()


def _save(path: Path, tracks: Tracks) -> None:
    ids = np.array(sorted(tracks.tracks), dtype=np.int64)
    frames = [np.asarray(tracks.tracks[int(i)][0]) for i in ids]
    xys = [np.asarray(tracks.tracks[int(i)][1], dtype=np.float64) for i in ids]
    lengths = np.array([f.size for f in frames], dtype=np.int64)
    header = json.dumps({"fps": tracks.fps, "source": tracks.source, "meta": tracks.meta})
    if json.loads(header)["meta"] != tracks.meta:  # e.g. tuples or int keys: not kept as is
        raise ValueError("the tracks' meta does not survive JSON")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(
                fh,
                ids=ids,
                lengths=lengths,
                frames=np.concatenate(frames) if frames else np.zeros(0, dtype=np.int64),
                xy=np.concatenate(xys) if xys else np.zeros((0, 2)),
                header=np.array(header),
            )
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _load(path: Path) -> Tracks:
    with np.load(path, allow_pickle=False) as z:
        ids, lengths = z["ids"], z["lengths"]
        frames, xy = z["frames"], z["xy"]
        header = json.loads(str(z["header"]))
    cuts = np.cumsum(lengths)[:-1]
    tracks = {
        int(i): (f, p)
        for i, f, p in zip(ids.tolist(), np.split(frames, cuts), np.split(xy, cuts), strict=True)
    }
    return Tracks(
        fps=float(header["fps"]), tracks=tracks, source=header["source"], meta=header["meta"]
    )


def cached_tracks(
    kind: str, path: str | os.PathLike[str], args: dict[str, Any], read: Callable[[], Tracks]
) -> Tracks:
    """The tracks ``read()`` parses from ``path``, from the cache when it holds them.

    Parameters
    ----------
    kind : str
        The reader's name (part of the key).
    path : path
        The file ``read`` parses (its bytes are part of the key).
    args : dict
        The reader's other arguments (JSON; part of the key).
    read : callable
        Parses the file (called on a miss; its errors propagate unchanged).
    """
    if os.environ.get(SWITCH_ENV_VAR, "1").strip() == "0":
        return read()
    try:
        # capped, no FIFO or device (its errors are the reader's own, one line)
        data = read_limited(path, MAX_DATA_FILE_BYTES, what="data file")
    except OSError:
        return read()  # the reader raises its own clear error
    entry = tracks_cache_dir() / f"{_key(kind, data, args)}.npz"
    if entry.is_file():
        try:
            return _load(entry)
        except (OSError, ValueError, KeyError, json.JSONDecodeError):
            entry.unlink(missing_ok=True)  # unreadable: parse again and replace it
    tracks = read()
    try:
        _save(entry, tracks)
    except (OSError, TypeError, ValueError):
        pass  # a read-only or full cache folder, or meta that is not JSON: not cached
    return tracks
