"""The piqp safety filter (kept under its v0.2 import path).

The filter lives in :mod:`conformal_control.cbf.filters.piqp`, its fallbacks in
:mod:`conformal_control.cbf.fallbacks`.
"""

from __future__ import annotations

from .fallbacks import CORE_FALLBACKS
from .filters.piqp import QPSafetyFilter

__all__ = ["FALLBACKS", "QPSafetyFilter"]

#: Names of the core fallbacks (any registered ``fallback`` plugin is accepted too).
FALLBACKS = tuple(CORE_FALLBACKS)
