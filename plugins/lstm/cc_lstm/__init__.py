"""conformal-control plugin: encoder LSTM -> multi-step LSTM decoder (PyTorch)."""

from .predictor import LSTMPredictor

__all__ = ["LSTMPredictor"]
