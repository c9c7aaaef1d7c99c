"""conformal-control plugin: any darts forecasting model as a batched predictor."""

from .predictor import DartsPredictor, ForecastCache

__all__ = ["DartsPredictor", "ForecastCache"]
