"""Where expensive predictors keep persistent caches (forecasts, trained weights)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["CACHE_ENV_VAR", "cache_dir"]

CACHE_ENV_VAR = "CONFORMAL_CONTROL_CACHE"


def cache_dir(sub: str = "") -> Path:
    """``$CONFORMAL_CONTROL_CACHE/sub``, else ``~/.cache/conformal-control/sub`` (created)."""
    root = os.environ.get(CACHE_ENV_VAR)
    base = Path(root).expanduser() if root else Path.home() / ".cache" / "conformal-control"
    path = base / sub if sub else base
    path.mkdir(parents=True, exist_ok=True)
    return path
