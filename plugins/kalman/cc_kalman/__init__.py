"""conformal-control plugin: per-agent Kalman filter predictor (filterpy)."""

from .predictor import FITTED_DEFAULTS, KalmanPredictor

__all__ = ["FITTED_DEFAULTS", "KalmanPredictor"]
