"""Core predictors (no heavy dependencies). More live in ``plugins/``."""

from .base import Forecast, PredictionQuery, Predictor, TruthUnavailableError
from .constant_velocity import ConstantVelocityPredictor
from .oracle import OraclePredictor
from .var import VARPredictor

__all__ = [
    "ConstantVelocityPredictor",
    "Forecast",
    "OraclePredictor",
    "PredictionQuery",
    "Predictor",
    "TruthUnavailableError",
    "VARPredictor",
]
