"""The lock file: ``constraints.txt`` pins every dependency at the version the tests pass with.

The README's set-up command installs through it (``-c constraints.txt``) and ``.ci/run`` runs
that same command, so a fresh install gets the versions CI tested, not whatever the registry
serves that day. ``bash .ci/lock`` regenerates it; the last test here fails when a dependency
was added or changed without doing so.
"""

from __future__ import annotations

import importlib.metadata as md
import re
import sys
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "constraints.txt"
PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;#]+)$")


def _readme_setup() -> str:
    lines = [ln for ln in (ROOT / "README.md").read_text().splitlines() if ln.startswith("python3")]
    return lines[0]


def _ci_setup() -> str:
    lines = [ln for ln in (ROOT / ".ci/run").read_text().splitlines() if ln.startswith("python3")]
    assert len(lines) == 1, lines
    return lines[0]


def lock() -> dict[str, str]:
    """``canonical name -> version`` of every pin (comments and blank lines skipped)."""
    pins: dict[str, str] = {}
    for n, line in enumerate(LOCK.read_text().splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        m = PIN.match(line)
        assert m, f"constraints.txt:{n}: not a plain 'name==version' pin: {line!r}"
        name = canonicalize_name(m.group(1))
        assert name not in pins, f"constraints.txt:{n}: {name} pinned twice"
        pins[name] = m.group(2)
    return pins


def test_readme_and_ci_install_through_the_lock() -> None:
    setup = _readme_setup()
    assert " -c constraints.txt " in setup
    assert setup == _ci_setup(), "README.md and .ci/run must run the same set-up command"
    assert "bash .ci/lock" in (ROOT / "CONTRIBUTING.md").read_text()


def test_the_lock_pins_plain_versions_and_the_cpu_torch() -> None:
    pins = lock()
    assert pins["torch"] == "2.13.0"  # the CPU build's file on disk; a bare 'torch' pulls CUDA
    assert not any(name.startswith("nvidia-") for name in pins), "a CUDA build was locked"
    ours = {canonicalize_name(n) for n in _our_distributions()}
    assert not ours & set(pins), "the project's own (editable) packages are not pinned"
    for name, version in pins.items():
        Version(version)  # a valid version: raises otherwise
        assert "+" not in version, (name, version)


def _our_distributions() -> dict[str, set[str]]:
    """Every distribution of the repository with the extras the set-up command installs."""
    out: dict[str, set[str]] = {}
    for path in [ROOT / "pyproject.toml", *sorted(ROOT.glob("*/*/pyproject.toml"))]:
        project = tomllib.loads(path.read_text()).get("project")
        if project is None:
            continue
        extras = set(project.get("optional-dependencies", {})) if path.parent == ROOT else set()
        out[project["name"]] = extras
    return out


def _closure() -> dict[str, str]:
    """Installed distributions the project's packages need (transitively): name -> version."""
    todo = [(name, frozenset(extras)) for name, extras in _our_distributions().items()]
    seen: set[tuple[str, frozenset[str]]] = set()
    needed: dict[str, str] = {}
    ours = {canonicalize_name(n) for n in _our_distributions()}
    while todo:
        name, extras = todo.pop()
        if (name, extras) in seen:
            continue
        seen.add((name, extras))
        try:
            dist = md.distribution(name)
        except md.PackageNotFoundError:
            continue  # a dependency of another platform or Python (its marker is false here)
        if canonicalize_name(name) not in ours:
            needed[canonicalize_name(name)] = dist.version
        for text in dist.requires or []:
            req = Requirement(text)
            envs = [{"extra": e} for e in extras] or [{"extra": ""}]
            if req.marker is None or any(req.marker.evaluate(env) for env in envs):
                todo.append((req.name, frozenset(req.extras)))
    return needed


def test_every_dependency_is_locked_at_its_installed_version() -> None:
    pins = lock()
    needed = _closure()
    assert {"numpy", "scikit-learn", "mkdocs", "torch", "skops"} <= set(needed)
    missing = sorted(n for n in needed if n not in pins)
    assert not missing, (
        f"not in constraints.txt: {', '.join(missing)}; a dependency was added: refresh the "
        "lock with `bash .ci/lock` (CONTRIBUTING.md)"
    )
    drift = sorted(
        f"{n} {needed[n]} installed, {pins[n]} locked"
        for n in needed
        if Version(needed[n]).public != Version(pins[n]).public
    )
    assert not drift, (
        "installed versions differ from constraints.txt (" + "; ".join(drift) + "): install "
        "with the README's set-up command, or refresh the lock with `bash .ci/lock`"
    )
