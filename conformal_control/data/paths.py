"""Where the data lives: one story, three places, clear errors.

The data folder (the one holding ``sdd/`` and ``ethucy/``) is, in this order:

1. the folder given with ``--data-root DIR`` (``data_root=`` in Python);
2. else ``$CONFORMAL_CONTROL_DATA``;
3. else the per-user data folder of the platform (``platformdirs``; on Linux
   ``~/.local/share/conformal-control``, on macOS ``~/Library/Application
   Support/conformal-control``, on Windows ``%LOCALAPPDATA%\\conformal-control``), which is
   where ``conformal-control fetch-data`` puts its downloads when no ``--dest`` is given.

The root may also be any part of the data folder (its ``sdd/`` or ``ethucy/`` folder, or a
folder inside one): every loader finds its own part from there (:func:`data_part`).

A missing file is a :class:`DataNotFoundError` that names the path, which of the three
places it came from, and the other two.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = [
    "ENV_VAR",
    "PART_MARKERS",
    "DataNotFoundError",
    "data_part",
    "data_root_origin",
    "ethucy_root",
    "external_root",
    "resolve_data_root",
    "sdd_root",
    "user_data_dir",
]

ENV_VAR = "CONFORMAL_CONTROL_DATA"
#: The largest data file read (bytes): SDD's largest annotations file is about 40 MB.
MAX_DATA_FILE_BYTES = 512 << 20
#: the download command (into the per-user data folder unless --dest is given)
FETCH_HINT = "conformal-control fetch-data"
_APP = "conformal-control"


class DataNotFoundError(FileNotFoundError):
    """A data file is missing; the message names the path, where the data folder came
    from, the other places it may be, and the download command."""


def user_data_dir() -> Path:
    """The per-user data folder: the default data root and ``fetch-data``'s default
    destination (``platformdirs.user_data_dir("conformal-control")``)."""
    import platformdirs

    return Path(platformdirs.user_data_dir(_APP, appauthor=False))


def data_root_origin(data_root: str | os.PathLike[str] | None = None) -> tuple[Path, str]:
    """(the data root, where it came from: ``"--data-root"``, ``"$CONFORMAL_CONTROL_DATA"``
    or ``"the per-user data folder"``)."""
    if data_root is not None:
        return Path(data_root).expanduser(), "--data-root"
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env).expanduser(), f"${ENV_VAR}"
    return user_data_dir(), "the per-user data folder"


def _where(path: Path) -> str:
    """Which of the three places a missing path is in, and the other two."""
    env = os.environ.get(ENV_VAR)
    user = user_data_dir()

    def under(folder: Path) -> bool:
        # as written first (a folder that cannot be resolved, e.g. a link loop, is still
        # where the path came from), then resolved
        if Path(os.path.abspath(path)).is_relative_to(os.path.abspath(folder)):
            return True
        try:
            return path.resolve().is_relative_to(folder.resolve())
        except (OSError, RuntimeError):  # an unresolvable path (a link loop)
            return False

    under_user = under(user)
    under_env = env is not None and env != "" and under(Path(env).expanduser())
    if under_env:
        origin = f"the data folder is ${ENV_VAR}={env}"
    elif under_user and not env:
        origin = "the data folder is the per-user data folder"
    else:
        origin = "the data folder was given with --data-root (data_root= in Python)"
    return (
        f"{origin}; the toolkit reads --data-root DIR, else ${ENV_VAR}, else the per-user "
        f"data folder {user}, where `{FETCH_HINT}` downloads the data"
    )


def missing(path: Path, what: str) -> DataNotFoundError:
    """The error for data that is not where it should be (says what stands there instead,
    and where the toolkit looks)."""
    path = Path(path)
    if path.is_dir() and (path.suffix or "file" in what):
        return DataNotFoundError(
            f"{what} expected at {path}, but that is a folder, not a file; point --data-root "
            f"at the data folder that holds sdd/ and ethucy/ (or set {ENV_VAR}=DIR)."
        )
    if path.is_dir():
        return DataNotFoundError(
            f"{what} not found: the folder {path} exists but holds none of its files; "
            f"{_where(path)}."
        )
    if path.exists():
        return DataNotFoundError(
            f"{what} expected at {path}, but that is not a regular file; {_where(path)}."
        )
    return DataNotFoundError(f"{what} not found at {path}: {_where(path)}.")


def resolve_data_root(data_root: str | os.PathLike[str] | None = None) -> Path:
    """The data root: the argument, else ``$CONFORMAL_CONTROL_DATA``, else the per-user
    data folder (:func:`user_data_dir`).

    Raises
    ------
    DataNotFoundError
        If a file stands where the folder should be.
    """
    if data_root is not None and not os.fspath(data_root).strip():
        raise DataNotFoundError(
            "--data-root is empty (data_root= in Python); give the data folder, or leave it "
            f"out to use ${ENV_VAR} or the per-user data folder"
        )
    root, origin = data_root_origin(data_root)
    try:
        os.stat(root)
    except OSError as exc:
        import errno

        if exc.errno == errno.ELOOP:
            raise DataNotFoundError(
                f"the data root {root} ({origin}) is a loop of symbolic links; point it at "
                "the data folder itself"
            ) from None
    if root.exists() and not root.is_dir():
        raise DataNotFoundError(
            f"the data root {root} ({origin}) is a file; pass the data folder (the one "
            f"holding sdd/ and ethucy/) with --data-root DIR or {ENV_VAR}=DIR"
        )
    return root


#: What each part of the data folder holds (the names that recognise it).
PART_MARKERS: dict[str, tuple[str, ...]] = {
    "sdd": ("annotations", "trajnet_pixels", "estimated_scales.yaml"),
    "ethucy": ("eth", "hotel", "univ", "zara1", "zara2"),
    "external": ("trajectron-ethucy", "fcp-planar"),
}
#: How many folders up from the given root a part of the data folder is looked for
#: (``sdd/annotations/nexus/video4`` is four below the data folder).
_LEVELS = 4


def _holds(folder: Path, kind: str) -> bool:
    return any((folder / m).exists() for m in PART_MARKERS[kind])


def data_part(kind: str, data_root: str | os.PathLike[str] | None = None) -> Path:
    """The folder of one part of the data (``"sdd"``, ``"ethucy"`` or ``"external"``),
    whatever part of the data folder the root names: the data folder itself, one of its
    parts (the SDD folder, the ETH/UCY folder: the others are beside it), or a folder
    inside one (``ethucy/zara1``, ``sdd/annotations``).

    Looking up from the root (at most four folders up), the first folder that is
    ``kind``'s own (it holds its files, whatever its name) or holds ``kind/``, or is
    another part (then ``kind`` is beside it), decides; with none, ``root/kind`` (whose
    absence the loaders report).

    Parameters
    ----------
    kind : {"sdd", "ethucy", "external"}
        The part.
    data_root : path, optional
        As :func:`resolve_data_root` takes it.
    """
    if kind not in PART_MARKERS:
        raise ValueError(f"kind must be one of {', '.join(PART_MARKERS)}, got {kind!r}")
    root = resolve_data_root(data_root)
    for folder in [root, *root.parents][: _LEVELS + 1]:
        if _holds(folder, kind):
            return folder
        if (folder / kind).is_dir():
            return folder / kind
        if any(_holds(folder, other) for other in PART_MARKERS if other != kind):
            return folder.parent / kind
    return root / kind


def sdd_root(data_root: str | os.PathLike[str] | None = None) -> Path:
    """The SDD folder (:func:`data_part`): the root itself if it holds SDD files, else
    ``sdd/`` of the data folder the root is or is part of."""
    return data_part("sdd", data_root)


def ethucy_root(data_root: str | os.PathLike[str] | None = None) -> Path:
    """The ETH/UCY folder (:func:`data_part`): the root itself if it holds the scenes,
    else ``ethucy/`` of the data folder the root is or is part of."""
    return data_part("ethucy", data_root)


def external_root(data_root: str | os.PathLike[str] | None = None) -> Path:
    """The folder of the external files (:func:`data_part`): ``external/`` of the data
    folder the root is or is part of."""
    return data_part("external", data_root)


def read_data_text(path: str | os.PathLike[str], what: str = "data file") -> str:
    """The text of a data file, read through
    :func:`~conformal_control.core.fileio.read_limited`: a regular file of at most
    :data:`MAX_DATA_FILE_BYTES` (a FIFO or a device is refused, not read).

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    what : str
        What it is, for the messages.
    """
    from ..core.fileio import read_limited

    return read_limited(path, MAX_DATA_FILE_BYTES, what=what).decode("utf-8", "replace")
