"""Result files written safely: atomically, with normal permissions, errors naming the path.

Every metrics, config, trajectory and table file is written to a unique temporary name in
its own folder and renamed over the target (:func:`os.replace`, atomic on POSIX and
Windows): a reader, a crash or a full disk never leaves a half-written or empty file under
the real name, only the previous file (or none) and a ``.<name>.<random>.tmp`` that the
failed writer removes. The temporary file is created with mode ``0o666`` less the umask,
like any file ``open(..., "w")`` creates (``tempfile.mkstemp`` would make it ``0600``).

An :class:`OSError` while writing (no space left, permission denied, read-only folder)
becomes an :class:`~conformal_control.exceptions.OutputNotWritableError` whose message
names the file and the reason.

It imports nothing from the package but :mod:`conformal_control.exceptions` (layer 1).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import secrets
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .exceptions import ConformalControlError, OutputNotWritableError

__all__ = [
    "TMP_PREFIX",
    "TMP_SUFFIX",
    "atomic_write",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "is_temp_name",
    "write_error",
]

TMP_PREFIX = "."
TMP_SUFFIX = ".tmp"


def is_temp_name(name: str, stems: tuple[str, ...] = ()) -> bool:
    """True for a temporary name :func:`atomic_write` makes (of a file in ``stems``, if given)."""
    if not (name.startswith(TMP_PREFIX) and name.endswith(TMP_SUFFIX)):
        return False
    return not stems or name[len(TMP_PREFIX) :].split(".", 1)[0] in stems


def write_error(path: str | os.PathLike[str], exc: OSError) -> OutputNotWritableError:
    """The one-line error for ``exc`` raised while writing ``path``."""
    reason = {
        errno.ENOSPC: "no space left on the device",
        errno.EDQUOT: "disk quota exceeded",
        errno.EFBIG: "the file exceeds the size limit of this process or file system",
        errno.EROFS: "the file system is read-only",
        errno.EACCES: "permission denied",
        errno.EPERM: "permission denied",
    }.get(exc.errno or -1, exc.strerror or str(exc))
    return OutputNotWritableError(f"cannot write {os.fspath(path)}: {reason}")


def _temp_path(path: Path) -> Path:
    return path.with_name(f"{TMP_PREFIX}{path.name}.{secrets.token_hex(6)}{TMP_SUFFIX}")


def atomic_write(path: str | os.PathLike[str], write: Callable[[Path], Any]) -> None:
    """Write ``path`` through ``write(tmp)`` on a unique temporary file, then rename it.

    ``write`` receives the temporary path (already created, empty) and fills it. The file
    replaces ``path`` only when ``write`` returned; on any failure the temporary file is
    removed and ``path`` is left as it was. An :class:`OSError` is re-raised as
    :class:`~conformal_control.exceptions.OutputNotWritableError` naming ``path``.
    """
    path = Path(path)
    tmp = _temp_path(path)
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        os.close(fd)
        write(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, ConformalControlError):
            raise write_error(path, exc) from exc
        raise


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_write`)."""
    atomic_write(path, lambda tmp: tmp.write_bytes(data))


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8, newlines as given) to ``path`` atomically."""
    data = text.encode("utf-8")
    atomic_write(path, lambda tmp: tmp.write_bytes(data))


def atomic_write_json(
    path: str | os.PathLike[str], obj: Any, *, indent: int | None = 2, **kwargs: Any
) -> None:
    """Write ``obj`` as JSON (with a final newline) to ``path`` atomically.

    The text is made before anything touches the disk, so an object that cannot be
    serialised leaves no file behind.

    Parameters
    ----------
    path : str or os.PathLike
        The file written (replaced whole, never left half-written).
    obj : Any
        What :func:`json.dumps` serialises.
    indent : int, optional
        JSON indentation (None: one line).
    **kwargs
        Further arguments of :func:`json.dumps` (e.g. ``default``, ``sort_keys``).
    """
    atomic_write_text(path, json.dumps(obj, indent=indent, **kwargs) + "\n")
