"""Where an exporter may write: never one of its inputs, never through a link, never a device.

Every exporter (MCAP, Rerun, and any added beside them) writes its file through
:func:`safe_output` (or :func:`safe_output_path` for a library that insists on opening a
path itself). Both first call :func:`check_destination`, which refuses, with a one-line
:class:`~conformal_control.core.exceptions.OutputNotWritableError` naming the path:

* a symbolic link (the link is never followed, whatever it points at);
* anything but a regular file: a device (``/dev/full``, ``/dev/null``), a FIFO, a socket,
  a folder (``--out EXISTING_DIR``);
* one of the inputs: a file given in ``inputs`` (compared after resolving its folder, and
  by inode, so a hard link or a path through a linked folder is caught too), or an
  existing file inside an input *folder* unless its name ends with ``suffix`` (an earlier
  output of the same kind: ``RUN/run.mcap`` may be written again, ``RUN/trajectory.csv``
  or ``RUN/config.json`` never).

Then the file is written to a temporary file created exclusively next to the destination
(``O_CREAT | O_EXCL | O_NOFOLLOW``, a random name ``.NAME.<hex>.partial``: a planted
``run.mcap.partial`` link is never opened), the destination is checked again, and the
temporary file is renamed over it (:func:`os.replace`, which replaces a name and follows
no link). On any error the temporary file is removed: nothing half-written stays behind.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import stat
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import BinaryIO

from ...core.exceptions import ConformalControlError, OutputNotWritableError
from ...core.fileio import write_error

__all__ = ["check_destination", "safe_output", "safe_output_path"]

#: What a path that is not a regular file is, for the message.
_KINDS = (
    (stat.S_ISDIR, "a folder (give a file name, e.g. {path}/run{suffix})"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISSOCK, "a socket"),
)


def _resolved(path: Path) -> Path:
    """``path`` with its folder resolved (links in the folders followed), its last part
    kept as written (a link there is the destination itself, never followed)."""
    return Path(os.path.realpath(path.parent)) / path.name


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.relative_to(folder)
    except ValueError:
        return False
    return True


def check_destination(
    out: str | os.PathLike[str],
    *,
    inputs: Iterable[str | os.PathLike[str]] = (),
    suffix: str | None = None,
) -> Path:
    """Refuse a destination that is a link, not a regular file, or one of the inputs.

    Parameters
    ----------
    out : path
        The file to write.
    inputs : iterable of path
        What the output is made from: files, or folders (every existing file inside one
        is an input, but for names ending with ``suffix``).
    suffix : str, optional
        The output's own suffix (``".mcap"``): an existing file of that suffix inside an
        input folder is an earlier output, and may be replaced.

    Returns
    -------
    Path
        ``out`` as a :class:`~pathlib.Path`.

    Raises
    ------
    OutputNotWritableError
        A one-line message naming ``out`` and why it is refused.
    """
    path = Path(out)
    if path.name in ("", ".", ".."):
        raise OutputNotWritableError(f"cannot write {path}: not a file name")
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise write_error(path, exc) from exc
    if st is not None:
        if stat.S_ISLNK(st.st_mode):
            raise OutputNotWritableError(
                f"cannot write {path}: it is a symbolic link, which an export never follows "
                "(remove it or choose another name)"
            )
        for test, kind in _KINDS:
            if test(st.st_mode):
                what = kind.format(path=path, suffix=suffix or "")
                raise OutputNotWritableError(f"cannot write {path}: it is {what}")
        if not stat.S_ISREG(st.st_mode):
            raise OutputNotWritableError(f"cannot write {path}: not a regular file")
    where = _resolved(path)
    for given in inputs:
        source = Path(given)
        if source.is_dir():
            folder = Path(os.path.realpath(source))
            own = suffix is not None and path.name.endswith(suffix)
            if st is not None and _inside(where, folder) and not own:
                raise OutputNotWritableError(
                    f"cannot write {path}: it is a file of the input folder {source}, "
                    f"which an export never overwrites (choose a new name"
                    + (f" ending in {suffix})" if suffix else ")")
                )
            continue
        same = _resolved(source) == where
        if not same and st is not None:
            with contextlib.suppress(OSError):
                other = os.stat(source)
                same = (other.st_dev, other.st_ino) == (st.st_dev, st.st_ino)
        if same:
            raise OutputNotWritableError(
                f"cannot write {path}: it is one of the inputs ({source}); choose another name"
            )
    return path


def _exclusive(path: Path) -> tuple[Path, int]:
    """A new temporary file beside ``path`` (created exclusively, no link followed)."""
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.partial")
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
    return tmp, os.open(tmp, flags, 0o666)


def _publish(tmp: Path, path: Path, inputs: list[Path], suffix: str | None) -> None:
    check_destination(path, inputs=inputs, suffix=suffix)  # again, just before the rename
    os.replace(tmp, path)


@contextlib.contextmanager
def safe_output(
    out: str | os.PathLike[str],
    *,
    inputs: Iterable[str | os.PathLike[str]] = (),
    suffix: str | None = None,
) -> Iterator[BinaryIO]:
    """Write ``out`` through a binary file object, safely (see the module docstring).

    ::

        with safe_output(out, inputs=(run_dir,), suffix=".mcap") as fh:
            fh.write(data)

    Parameters
    ----------
    out : path
        The file to write (its folder is created).
    inputs : iterable of path
        The files and folders the output is made from (:func:`check_destination`).
    suffix : str, optional
        The output's own suffix (:func:`check_destination`).

    Yields
    ------
    BinaryIO
        The temporary file, renamed to ``out`` when the block ends without an error.

    Raises
    ------
    OutputNotWritableError
        A refused destination, or an :class:`OSError` while writing (naming ``out``).
    """
    sources = [Path(p) for p in inputs]
    path = check_destination(out, inputs=sources, suffix=suffix)
    tmp: Path | None = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp, fd = _exclusive(path)
        with os.fdopen(fd, "wb") as fh:
            yield fh
        _publish(tmp, path, sources, suffix)
        tmp = None
    except OSError as exc:
        if isinstance(exc, ConformalControlError):
            raise
        raise write_error(path, exc) from exc
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


@contextlib.contextmanager
def safe_output_path(
    out: str | os.PathLike[str],
    *,
    inputs: Iterable[str | os.PathLike[str]] = (),
    suffix: str | None = None,
) -> Iterator[Path]:
    """Like :func:`safe_output`, for a library that writes to a path itself (Rerun's
    ``save``): it writes into a private folder (``0700``, made by :mod:`tempfile`), whose
    file is then copied into the exclusively created temporary file and renamed over
    ``out``.

    Parameters
    ----------
    out : path
        The file to write (its folder is created).
    inputs : iterable of path
        The files and folders the output is made from (:func:`check_destination`).
    suffix : str, optional
        The output's own suffix (:func:`check_destination`).

    Yields
    ------
    Path
        A path in the private folder for the library to write.
    """
    sources = [Path(p) for p in inputs]
    path = check_destination(out, inputs=sources, suffix=suffix)
    with tempfile.TemporaryDirectory(prefix="cc-export-") as private:
        staged = Path(private) / (path.name or "out")
        yield staged
        if not staged.is_file():
            raise OutputNotWritableError(f"cannot write {path}: the exporter wrote nothing")
        with staged.open("rb") as src, safe_output(path, inputs=sources, suffix=suffix) as dst:
            shutil.copyfileobj(src, dst)
