"""Data fixture for the plugin's tests (same lookup as the core suite's conftest)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

PROJECT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def data_root() -> Path:
    env = os.environ.get("CONFORMAL_CONTROL_DATA")
    root = Path(env) if env else PROJECT.parent / "shared" / "data"
    if not (root / "ethucy").is_dir():
        pytest.fail(f"real data not found at {root} (expected ethucy/ inside)", pytrace=False)
    return root
