"""Core predictors (no heavy dependencies). More live in ``plugins/``."""

from .constant_velocity import ConstantVelocityPredictor
from .oracle import OraclePredictor

__all__ = ["ConstantVelocityPredictor", "OraclePredictor"]
