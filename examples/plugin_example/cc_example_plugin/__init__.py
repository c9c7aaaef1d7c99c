"""Example third-party plugins for conformal-control (registered through entry points)."""

from .barrier import DistanceSquaredBarrier
from .predictor import DampedConstantVelocity

__all__ = ["DampedConstantVelocity", "DistanceSquaredBarrier"]
__version__ = "0.1.0"
