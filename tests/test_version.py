"""One version everywhere: pyproject, ``__version__``, the changelog's newest section,
CITATION.cff, the README's BibTeX entry and the shipped plugins (whose requirement on the
core admits it)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet
from packaging.version import Version

import conformal_control

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]


def _project(path: Path) -> dict:
    return tomllib.loads(path.read_text())["project"]


def test_the_version_agrees_everywhere() -> None:
    version = _project(ROOT / "pyproject.toml")["version"]
    Version(version)
    assert conformal_control.__version__ == version
    heading = re.search(r"^## (\S+)", (ROOT / "docs/changelog.md").read_text(), re.M)
    assert heading is not None and heading.group(1) == version, "the changelog's newest section"
    cff = re.search(r"^version: (\S+)$", (ROOT / "CITATION.cff").read_text(), re.M)
    assert cff is not None and cff.group(1) == version
    bib = re.search(r"^\s*version\s*=\s*\{([^}]+)\}", (ROOT / "README.md").read_text(), re.M)
    assert bib is not None and bib.group(1) == version
    plugins = sorted((ROOT / "plugins").glob("*/pyproject.toml"))
    assert len(plugins) >= 4
    for path in plugins:
        project = _project(path)
        assert project["version"] == version, path
        core = [
            Requirement(r)
            for r in project["dependencies"]
            if Requirement(r).name == "conformal-control"
        ]
        assert len(core) == 1 and core[0].specifier.contains(version), (path, core)
        said = re.search(
            r"`conformal-control([<>=!~][^`]*)`", (path.parent / "README.md").read_text()
        )
        assert said is not None and SpecifierSet(said.group(1)) == core[0].specifier, path
