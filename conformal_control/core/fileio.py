"""Files written safely (atomically, with normal permissions, errors naming the path) and
read safely (a size cap, no FIFO or device, a gzip file's decompressed size capped).

Every metrics, config, trajectory and table file is written to a unique temporary name in
its own folder and renamed over the target (:func:`os.replace`, atomic on POSIX and
Windows): a reader, a crash or a full disk never leaves a half-written or empty file under
the real name, only the previous file (or none) and a ``.<name>.<random>.tmp`` that the
failed writer removes. The temporary file is created with mode ``0o666`` less the umask,
like any file ``open(..., "w")`` creates (``tempfile.mkstemp`` would make it ``0600``).

An :class:`OSError` while writing (no space left, permission denied, read-only folder)
becomes an :class:`~conformal_control.core.exceptions.OutputNotWritableError` whose message
names the file and the reason.

Every reader of a file a user names (``--config``, ``--robots-file``, recorded predictions,
data files) goes through :func:`read_limited`: a FIFO, a device or a folder is refused
before it is opened (reading ``/dev/zero`` ran until memory ran out; a FIFO hung), the
file's bytes are capped (the cap is stated in the error), and a gzip file is decompressed
with a cap on its decompressed size (a 204 KB gzip file held gigabytes of zeros), a corrupt
one being a one-line error.

It imports nothing from the package but :mod:`conformal_control.core.exceptions` (layer 1).
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

from .exceptions import ConformalControlError, DataFormatError, OutputNotWritableError

__all__ = [
    "TMP_PREFIX",
    "TMP_SUFFIX",
    "atomic_write",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "is_temp_name",
    "read_limited",
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
    :class:`~conformal_control.core.exceptions.OutputNotWritableError` naming ``path``.
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


def _size_text(n: int) -> str:
    return f"{n / 2**20:g} MiB" if n >= 2**20 else f"{n / 2**10:g} KiB"


def read_limited(
    path: str | os.PathLike[str], cap: int, *, what: str = "file", gzip_ok: bool = False
) -> bytes:
    """The bytes of the regular file ``path``, at most ``cap`` of them.

    Parameters
    ----------
    path : str or os.PathLike
        The file (a link to a regular file is followed).
    cap : int
        The most bytes read; with ``gzip_ok``, the most bytes decompressed.
    what : str
        What the file is, for the messages (``"--config file"``).
    gzip_ok : bool
        Decompress a gzip file (recognised by its magic bytes).

    Returns
    -------
    bytes
        The file's (decompressed) content.

    Raises
    ------
    FileNotFoundError
        No such file.
    DataFormatError
        Not a regular file (a folder, a FIFO, a device), larger than ``cap`` (the message
        states the cap), or a corrupt gzip file; one line naming the file.
    """
    import stat
    import zlib

    p = os.fspath(path)

    def refuse_special(mode: int) -> None:
        if stat.S_ISREG(mode):
            return
        kind = (
            "a folder"
            if stat.S_ISDIR(mode)
            else "a FIFO"
            if stat.S_ISFIFO(mode)
            else "a device"
            if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "not a regular file"
        )
        raise DataFormatError(f"{what} {p} is {kind}, not a file that can be read")

    try:
        refuse_special(os.stat(p).st_mode)  # before opening: opening a device may act
        # without blocking (a FIFO swapped in meanwhile is seen by fstat, not waited on)
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {p}") from None
    except OSError as exc:
        if isinstance(exc, ConformalControlError):
            raise
        raise DataFormatError(f"{what} {p} cannot be read: {exc.strerror or exc}") from None
    too_big = DataFormatError(f"{what} {p} is larger than {_size_text(cap)}, the most read")
    try:
        with os.fdopen(fd, "rb") as fh:
            refuse_special(os.fstat(fh.fileno()).st_mode)
            head = fh.read(2)
            if gzip_ok and head == b"\x1f\x8b":
                import gzip

                fh.seek(0)
                with gzip.GzipFile(fileobj=fh) as gz:
                    data = gz.read(cap + 1)
                if len(data) > cap:
                    raise DataFormatError(
                        f"{what} {p} decompresses to more than {_size_text(cap)}, the most read"
                    )
                return data
            data = head + fh.read(cap + 1 - len(head))
    except (zlib.error, EOFError) as exc:
        raise DataFormatError(f"{what} {p} is not a valid gzip file ({exc})") from None
    except OSError as exc:
        if isinstance(exc, ConformalControlError):
            raise
        if exc.__class__.__name__ == "BadGzipFile":
            raise DataFormatError(f"{what} {p} is not a valid gzip file ({exc})") from None
        raise DataFormatError(f"{what} {p} cannot be read: {exc.strerror or exc}") from None
    if len(data) > cap:
        raise too_big
    return data
