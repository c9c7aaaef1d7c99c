"""Attacks through the cache folder: what a cache holds is a hint, never code.

The entry-point cache (``$CONFORMAL_CONTROL_CACHE/entry-points-<crc>.json``) was trusted
as written: pointing a core predictor at ``subprocess:Popen`` and passing the command as
predictor parameters ran it. The cache is now checked row by row against the installed
distributions' metadata (``conformal_control.core.registry``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conformal_control.cli import EXIT_ERROR, main
from conformal_control.core import registry


@pytest.fixture
def fresh_registry(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """A registry discovering again from a private cache folder (then restored)."""
    monkeypatch.setenv("CONFORMAL_CONTROL_CACHE", str(tmp_path / "cache"))

    def rediscover() -> None:
        monkeypatch.setattr(registry, "_registry", {role: {} for role in registry.ROLES})
        monkeypatch.setattr(registry, "_clashes", [])
        monkeypatch.setattr(registry, "_discovered", False)

    yield rediscover
    monkeypatch.undo()
    registry.refresh()


@pytest.mark.parametrize("target", ["subprocess:Popen", "os:system"])
def test_a_tampered_entry_point_cache_runs_no_code(
    target: str, fresh_registry, tmp_path: Path, error_line
) -> None:
    registry._entry_point_rows()  # writes the cache, as any command does
    path = registry._cache_file()
    stored = json.loads(path.read_text())
    for row in stored["rows"]:
        if row[1] == "constant_velocity":
            row[2] = target
    path.write_text(json.dumps(stored))
    fresh_registry()
    marker = tmp_path / "pwned"
    argv = ["run", "--scene", "crossing", "--frames", "5", "--no-plot", "--quiet"]
    argv += ["--predictor", "constant_velocity", "--out", str(tmp_path / "r")]
    argv += ["--predictor-param", f"args=touch {marker}", "--predictor-param", "shell=true"]
    assert main(argv) == EXIT_ERROR
    assert "predictor 'constant_velocity' has no parameter 'args'" in error_line()
    assert not marker.exists()
    assert registry.entry("predictor", "constant_velocity").load().__module__ == (
        "conformal_control.predictors.constant_velocity"
    )
