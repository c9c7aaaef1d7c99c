"""The documentation site builds with ``mkdocs build --strict`` (broken links fail)."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_mkdocs_build_strict(tmp_path: Path) -> None:
    if importlib.util.find_spec("mkdocs") is None:
        pytest.fail("mkdocs is not installed: pip install -e '.[docs]'")
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(site)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for page in (
        "index.html",
        "getting-started/index.html",
        "concepts/index.html",
        "controller/index.html",
        "data/index.html",
        "benchmarks/index.html",
        "cli/index.html",
        "api/index.html",
        "changelog/index.html",
        "examples/quickstart/index.html",
    ):
        assert (site / page).is_file(), page
    # generated sections: every parameter and every subcommand, straight from the code
    from conformal_control.cli import build_parser
    from conformal_control.sim.config import PARAMETERS

    controller = (site / "controller/index.html").read_text()
    assert "generated:parameters" not in controller
    for name in PARAMETERS:
        assert f"<code>{name}</code>" in controller, name
    cli = (site / "cli/index.html").read_text()
    subs = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    for name in subs.choices:
        assert f"conformal-control {name}" in cli, name
    started = (site / "getting-started/index.html").read_text()
    assert "generated:run" not in started
    assert started.count("results written to") == 2  # the demo and nexus_4, run at build time
    api = (site / "api/index.html").read_text()
    assert "ConformalLoop" in api and "run_episode" in api
    # math is emitted for MathJax, assets are in place
    assert 'class="arithmatex"' in (site / "concepts/index.html").read_text()
    assert (site / "assets/demo.png").is_file()
