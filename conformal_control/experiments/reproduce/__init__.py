"""Reproduction of the paper's Tables I and II (``conformal-control reproduce``)."""

from __future__ import annotations

from .paper import PAPER_TABLES, VARIANTS, PaperRow, PaperTable, variant_a
from .report import IDENTITY_TOL, TARGETS, ReproRow, auto_executor, plan, reproduce

__all__ = [
    "IDENTITY_TOL",
    "PAPER_TABLES",
    "TARGETS",
    "VARIANTS",
    "PaperRow",
    "PaperTable",
    "ReproRow",
    "auto_executor",
    "plan",
    "reproduce",
    "variant_a",
]
