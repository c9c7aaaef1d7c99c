"""Download the data with checksums: ``conformal-control fetch-data``.

The manifest (``manifest.json`` beside this module) lists every file of the data folder
the project is tested with, with its size and SHA-256. Files come from the public
repositories they were copied from:

* ``sdd/annotations/...``, ``sdd/estimated_scales.yaml`` - crowdbotp/OpenTraj
  (``datasets/SDD/``), the original SDD annotations, reference images and scales;
* ``sdd/trajnet_pixels/<scene>_<video>.txt`` - the TrajNet split of xupei0610/SocialVAE
  (``data/sdd/{train,test}/``), which is in metres: converted back to pixels by dividing
  by the video's scale (``frame id x_px y_px`` with 4 decimals);
* ``ethucy/...`` - the standard leave-one-scene-out split of
  StanfordASL/Trajectron-plus-plus (``experiments/pedestrians/raw/``).

Every file is verified against the manifest; a mismatch is an error naming the file,
and nothing unverified is left in place. ``--mirror`` takes a folder or URL laid out like
the data folder (e.g. a colleague's copy) and copies files verbatim.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Iterable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from ..exceptions import ConformalControlError, DataFetchError

__all__ = ["ChecksumError", "FetchPlan", "fetch", "load_manifest", "trajnet_metres_to_pixels"]


class ChecksumError(ConformalControlError, RuntimeError):
    """A downloaded file does not match the manifest."""


def load_manifest() -> dict[str, Any]:
    """The packaged manifest of data files."""
    manifest: dict[str, Any] = json.loads(
        resources.files(__package__).joinpath("manifest.json").read_text()
    )
    return manifest


@dataclass(frozen=True)
class FetchPlan:
    """One file to fetch."""

    path: str
    sha256: str
    size: int
    url: str
    convert: str | None = None  # "trajnet_pixels" when the upstream file is in metres


def _matches(path: str, selector: str) -> bool:
    kind, _, name = selector.partition(":")
    if not path.startswith(kind + "/"):
        return False
    if not name:
        return True
    if kind == "ethucy":
        return path.split("/")[1] == name
    scene, _, video = name.rpartition("_")
    return f"annotations/{scene}/video{video}/" in path or path.endswith(
        f"trajnet_pixels/{name}.txt"
    )


def _select(files: list[dict[str, Any]], only: Iterable[str] | None) -> list[dict[str, Any]]:
    """Filter by ``sdd``, ``ethucy``, ``sdd:<scene>_<video>`` or ``ethucy:<scene>``.

    Selecting any SDD video also selects the scales file and the licence.
    """
    if not only:
        return files
    only = list(only)
    for sel in only:
        if not any(_matches(e["path"], sel) for e in files):
            raise ValueError(f"--only {sel!r} matches no file of the manifest")
    shared = ("sdd/estimated_scales.yaml", "sdd/LICENSE")
    wants_sdd = any(sel.startswith("sdd") for sel in only)
    return [
        e
        for e in files
        if any(_matches(e["path"], sel) for sel in only) or (wants_sdd and e["path"] in shared)
    ]


def plan(only: Iterable[str] | None = None, mirror: str | None = None) -> list[FetchPlan]:
    """What :func:`fetch` would download (and from where)."""
    man = load_manifest()
    out = []
    for e in _select(man["files"], only):
        p: str = e["path"]
        convert = None
        if mirror is not None:
            base = mirror.rstrip("/")
            url = f"{base}/{p}"
        elif p.startswith("ethucy/"):
            url = man["sources"]["trajectron"]["base"] + p.removeprefix("ethucy/")
        elif p.startswith("sdd/trajnet_pixels/"):
            name = Path(p).stem
            url = f"{man['sources']['socialvae']['base']}{man['trajnet_split'][name]}/{name}.txt"
            convert = "trajnet_pixels"
        else:
            url = man["sources"]["opentraj"]["base"] + p.removeprefix("sdd/").replace(
                "annotations/", ""
            )
        out.append(FetchPlan(p, e["sha256"], e["size"], url, convert))
    return out


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _download(url: str, dest: Path) -> None:
    local = (
        Path(url.removeprefix("file://")) if "://" not in url or url.startswith("file://") else None
    )
    if local is not None:
        if not local.exists():
            raise DataFetchError(f"{local} not found in the mirror")
        shutil.copyfile(local, dest)
        return
    try:
        with urllib.request.urlopen(url, timeout=60) as resp, dest.open("wb") as fh:
            shutil.copyfileobj(resp, fh)
    except urllib.error.HTTPError as exc:
        raise DataFetchError(
            f"cannot download {url}: the server answered HTTP {exc.code} ({exc.reason}); "
            "retry later or copy the data from a colleague with --mirror DIR"
        ) from None
    except (urllib.error.URLError, TimeoutError, ConnectionError) as exc:
        reason = getattr(exc, "reason", exc)
        host = urllib.parse.urlsplit(url).netloc
        raise DataFetchError(
            f"cannot download {url}: {host} is unreachable ({reason}); check the network "
            "connection, or copy the data from a colleague with --mirror DIR"
        ) from None


def trajnet_metres_to_pixels(text: str, m_per_px: float) -> str:
    """Convert a SocialVAE TrajNet file (``frame id x_m y_m``) to pixels."""
    lines = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 4:
            raise ValueError(f"line {lineno}: expected 4 fields, got {len(parts)}")
        f, i, x, y = parts
        lines.append(
            f"{int(float(f))} {int(float(i))} {float(x) / m_per_px:.4f} {float(y) / m_per_px:.4f}"
        )
    return "\n".join(lines) + "\n"


def fetch(
    dest: str | Path,
    *,
    only: Iterable[str] | None = None,
    mirror: str | None = None,
    force: bool = False,
    progress: bool = True,
) -> dict[str, int]:
    """Download and verify the data files into ``dest``.

    Returns counts ``{"downloaded": n, "verified_existing": m}``. Raises
    :class:`ChecksumError` on a mismatch (the bad file is removed).
    """
    from ..progress import progress as report

    dest = Path(dest)
    items = plan(only, mirror)
    counts = {"downloaded": 0, "verified_existing": 0}
    # scales are needed to convert TrajNet files: fetch them first
    items.sort(key=lambda it: (it.convert is not None, it.path))
    bar = report(len(items), "fetch-data", "files", delay=None if progress else float("inf"))
    with bar:
        for item in items:
            bar.update()
            target = dest / item.path
            if target.exists() and not force and _sha256(target) == item.sha256:
                counts["verified_existing"] += 1
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            tmp = target.with_suffix(target.suffix + ".part")
            try:
                _download(item.url, tmp)
                if item.convert == "trajnet_pixels":
                    from .sdd import load_scales

                    scene, _, video = Path(item.path).stem.rpartition("_")
                    scale = load_scales(dest / "sdd")[(scene, int(video))]
                    tmp.write_text(trajnet_metres_to_pixels(tmp.read_text(), scale))
                got = _sha256(tmp)
                if got != item.sha256:
                    raise ChecksumError(
                        f"{item.path}: SHA-256 {got} does not match the manifest's {item.sha256} "
                        f"(source {item.url}); the file was not kept"
                    )
                tmp.replace(target)
            finally:
                tmp.unlink(missing_ok=True)
            counts["downloaded"] += 1
    return counts
