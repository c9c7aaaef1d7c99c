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
  StanfordASL/Trajectron-plus-plus (``experiments/pedestrians/raw/``);
* ``external/...`` - published predictions and protocols of other work (Trajectron++
  predictions on ETH/UCY as CSV, the FCP-MPC / ECP-MPC planar protocol as JSON; see the
  manifest's ``sources.external``). Their upstream form is a Python pickle, which this
  tool never loads, so they are **mirror-only**: ``--mirror`` copies the converted files
  from a colleague's data folder; without it they are listed as not fetched.

Every file is verified against the manifest; a mismatch is an error naming the file,
and nothing unverified is left in place. A download is cut off as soon as it exceeds the
size the manifest allows (its size, or four times it for the TrajNet files converted from
metres), so a wrong or hostile source cannot fill the disk. ``--mirror`` takes a folder or
URL laid out like the data folder (e.g. a colleague's copy) and copies files verbatim.
"""

from __future__ import annotations

import hashlib
import json
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Iterable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, BinaryIO

from ..core.exceptions import ConformalControlError, DataFetchError
from ..core.fileio import write_error

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
    url: str | None  # None: mirror-only (no upstream source this tool reads)
    convert: str | None = None  # "trajnet_pixels" when the upstream file is in metres

    @property
    def max_bytes(self) -> int:
        """Most bytes a download of this file may have before it is cut off."""
        return self.size if self.convert is None else 4 * self.size + 65536


def _matches(path: str, selector: str) -> bool:
    kind, _, name = selector.partition(":")
    if not path.startswith(kind + "/"):
        return False
    if not name:
        return True
    if kind in ("ethucy", "external"):
        return path.split("/")[1] == name
    scene, _, video = name.rpartition("_")
    return f"annotations/{scene}/video{video}/" in path or path.endswith(
        f"trajnet_pixels/{name}.txt"
    )


def _select(files: list[dict[str, Any]], only: Iterable[str] | None) -> list[dict[str, Any]]:
    """Filter by ``sdd``, ``ethucy``, ``external``, ``sdd:<scene>_<video>``,
    ``ethucy:<scene>`` or ``external:<folder>`` (``trajectron-ethucy``, ``fcp-planar``).

    Selecting any SDD video also selects the scales file and the licence; selecting
    anything external also selects ``external/README.md`` (sources and licences).
    """
    if not only:
        return files
    from .catalog import fetch_selector  # names and their aliases are resolved there

    only = [fetch_selector(sel) for sel in only]
    for sel in only:
        if not any(_matches(e["path"], sel) for e in files):
            raise ValueError(f"--only {sel!r} matches no file of the manifest")
    shared = {
        "sdd": ("sdd/estimated_scales.yaml", "sdd/LICENSE"),
        "external": ("external/README.md",),
    }
    also = {
        p for kind, paths in shared.items() if any(s.startswith(kind) for s in only) for p in paths
    }
    return [e for e in files if any(_matches(e["path"], sel) for sel in only) or e["path"] in also]


def plan(only: Iterable[str] | None = None, mirror: str | None = None) -> list[FetchPlan]:
    """What :func:`fetch` would download (and from where)."""
    man = load_manifest()
    out = []
    for e in _select(man["files"], only):
        p: str = e["path"]
        convert = None
        url: str | None
        if mirror is not None:
            base = mirror.rstrip("/")
            url = f"{base}/{p}"
        elif p.startswith("external/"):
            url = None  # mirror-only: upstream is a pickle, never loaded here
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


def _copy_capped(src: BinaryIO, dest: Path, limit: int, what: str) -> None:
    """Copy ``src`` to ``dest``, refusing (and stopping) past ``limit`` bytes."""
    n = 0
    with dest.open("wb") as fh:
        while chunk := src.read(min(1 << 20, limit + 1 - n)):
            n += len(chunk)
            if n > limit:
                raise ChecksumError(
                    f"{what} is larger than the {limit} bytes the manifest allows; the "
                    "download was stopped and not kept"
                )
            fh.write(chunk)


def _download(url: str, dest: Path, limit: int) -> None:
    local = (
        Path(url.removeprefix("file://")) if "://" not in url or url.startswith("file://") else None
    )
    if local is not None:
        if not local.is_file():
            raise DataFetchError(f"{local} not found in the mirror")
        if local.stat().st_size > limit:
            raise ChecksumError(
                f"{local} has {local.stat().st_size} bytes, more than the {limit} the manifest "
                "allows; it was not copied"
            )
        with local.open("rb") as src:
            _copy_capped(src, dest, limit, str(local))
        return
    try:
        with urllib.request.urlopen(url, timeout=60) as resp:
            length = resp.headers.get("Content-Length")
            if length is not None and length.isdigit() and int(length) > limit:
                raise ChecksumError(
                    f"{url} announces {length} bytes, more than the {limit} the manifest "
                    "allows; nothing was downloaded"
                )
            _copy_capped(resp, dest, limit, url)
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

    Returns counts ``{"downloaded": n, "verified_existing": m, "mirror_only": k}``
    (``mirror_only``: files with no upstream source this tool reads, not fetched because
    no ``mirror`` was given; they are fetched, or a clear error raised, when selected
    explicitly with ``only``). Raises :class:`ChecksumError` on a mismatch or an
    oversized download (the bad file is removed).

    Parameters
    ----------
    dest : str or Path
        The data folder files are written into (``sdd/``, ``ethucy/``, ``external/``).
    only : iterable of str, optional
        Select files: ``sdd``, ``ethucy``, ``external``, ``sdd:<scene>_<video>``,
        ``ethucy:<scene>`` or ``external:<folder>`` (None: every file of the manifest).
    mirror : str, optional
        A base URL or folder to copy every file from instead of the upstream sources.
    force : bool
        Download again files that exist and match their checksum.
    progress : bool
        Show a progress bar.
    """
    from ..core.progress import progress as report

    dest = Path(dest)
    items = plan(only, mirror)
    counts = {"downloaded": 0, "verified_existing": 0, "mirror_only": 0}
    unreachable = [it for it in items if it.url is None]
    if unreachable and only:
        wanted = [it.path for it in unreachable if it.path != "external/README.md"]
        raise DataFetchError(
            f"{', '.join(wanted or [unreachable[0].path])} can only be copied from a mirror "
            "(the upstream files are Python pickles, which are never loaded); pass --mirror "
            "DIR with a colleague's data folder"
        )
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
            if item.url is None:
                counts["mirror_only"] += 1
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            tmp = target.with_suffix(target.suffix + ".part")
            try:
                _download(item.url, tmp, item.max_bytes)
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
            except OSError as exc:
                if isinstance(exc, ConformalControlError):
                    raise
                raise write_error(target, exc) from exc
            finally:
                tmp.unlink(missing_ok=True)
            counts["downloaded"] += 1
    return counts
