"""conformal-control: safe decisions from imperfect predictions.

Conformal decision theory tunes a scalar lambda online, lambda <- lambda + eta (epsilon -
loss), over a family of decision policies ordered by conservativeness. The flagship
instantiation adds lambda as slack to control-barrier-function constraints built from
predicted pedestrian trajectories (Huriot & Sibai).
"""

__version__ = "0.1.0"

from .base import (
    Barrier,
    DecisionFamily,
    Dynamics,
    Environment,
    FilterResult,
    Forecast,
    Loss,
    PredictionQuery,
    Predictor,
    ReferenceController,
    SafetyFilter,
    UpdateRule,
)
from .loop import ConformalLoop, IntervalLog, LoopResult
from .monitor import GuaranteeMonitor

__all__ = [
    "Barrier",
    "ConformalLoop",
    "DecisionFamily",
    "Dynamics",
    "Environment",
    "FilterResult",
    "Forecast",
    "GuaranteeMonitor",
    "IntervalLog",
    "LoopResult",
    "Loss",
    "PredictionQuery",
    "Predictor",
    "ReferenceController",
    "SafetyFilter",
    "UpdateRule",
    "__version__",
]
