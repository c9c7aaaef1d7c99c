"""Where the data lives: ``--data-root``, ``$CONFORMAL_CONTROL_DATA``, clear errors."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["ENV_VAR", "DataNotFoundError", "ethucy_root", "resolve_data_root", "sdd_root"]

ENV_VAR = "CONFORMAL_CONTROL_DATA"
FETCH_HINT = "conformal-control fetch-data --dest DIR"


class DataNotFoundError(FileNotFoundError):
    """A data file is missing; the message names the path and the download command."""


def missing(path: Path, what: str) -> DataNotFoundError:
    """The error for data that is not where it should be (says what stands there instead)."""
    path = Path(path)
    if path.is_dir() and (path.suffix or "file" in what):
        return DataNotFoundError(
            f"{what} expected at {path}, but that is a folder, not a file; point --data-root "
            f"at the data folder that holds sdd/ and ethucy/ (or set {ENV_VAR}=DIR)."
        )
    if path.is_dir():
        return DataNotFoundError(
            f"{what} not found: the folder {path} exists but holds none of its files; "
            f"download the data with `{FETCH_HINT}` and pass --data-root DIR (or set "
            f"{ENV_VAR}=DIR)."
        )
    if path.exists():
        return DataNotFoundError(
            f"{what} expected at {path}, but that is not a regular file; download the data "
            f"with `{FETCH_HINT}`."
        )
    return DataNotFoundError(
        f"{what} not found at {path}: download the data with `{FETCH_HINT}` and pass "
        f"--data-root DIR (or set {ENV_VAR}=DIR)."
    )


def resolve_data_root(data_root: str | os.PathLike[str] | None = None) -> Path:
    """The data root: the argument, else ``$CONFORMAL_CONTROL_DATA``, else ``./data``."""
    if data_root is None:
        data_root = os.environ.get(ENV_VAR) or "data"
    root = Path(data_root).expanduser()
    if root.exists() and not root.is_dir():
        raise DataNotFoundError(
            f"the data root {root} is a file; pass the data folder (the one holding sdd/ and "
            f"ethucy/) with --data-root DIR or {ENV_VAR}=DIR"
        )
    return root


def _subdir(root: Path, name: str, markers: tuple[str, ...]) -> Path:
    if any((root / m).exists() for m in markers):
        return root
    return root / name


def sdd_root(data_root: str | os.PathLike[str] | None = None) -> Path:
    """The SDD folder: the root itself if it holds SDD files, else ``root/sdd``."""
    return _subdir(
        resolve_data_root(data_root),
        "sdd",
        ("annotations", "trajnet_pixels", "estimated_scales.yaml"),
    )


def ethucy_root(data_root: str | os.PathLike[str] | None = None) -> Path:
    """The ETH/UCY folder: the root itself if it holds the scenes, else ``root/ethucy``."""
    return _subdir(resolve_data_root(data_root), "ethucy", ("eth", "hotel", "univ", "zara1"))
