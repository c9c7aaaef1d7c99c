"""Shared fixtures. Tests that need the real data use ``data_root`` / ``sdd_dir``.

The data is read from ``$CONFORMAL_CONTROL_DATA`` or from ``../shared/data`` beside the
project root. If it is missing, data tests FAIL (they are never skipped): CI always has it.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _data_root() -> Path:
    env = os.environ.get("CONFORMAL_CONTROL_DATA")
    return Path(env) if env else ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def data_root() -> Path:
    root = _data_root()
    if not (root / "sdd").is_dir() or not (root / "ethucy").is_dir():
        pytest.fail(
            f"real data not found at {root} (expected sdd/ and ethucy/ inside); set "
            "CONFORMAL_CONTROL_DATA or place the shared data beside the project",
            pytrace=False,
        )
    return root


@pytest.fixture(scope="session")
def sdd_dir(data_root: Path) -> Path:
    return data_root / "sdd"


@pytest.fixture(scope="session")
def ethucy_dir(data_root: Path) -> Path:
    return data_root / "ethucy"


@pytest.fixture(scope="session")
def nexus4(sdd_dir: Path):
    from conformal_control.data import load_scene

    return load_scene("nexus_4", sdd_dir)


@pytest.fixture(scope="session")
def crossing():
    from conformal_control.data import load_scene

    return load_scene("crossing", seed=0)
