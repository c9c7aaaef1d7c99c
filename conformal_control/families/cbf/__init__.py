"""The conformal CBF controller (the flagship decision family)."""

from .barriers import APFBarrier
from .constraint import ConformalConstraint
from .controller import CBFIntervalRecord, ConformalCBFController, ControlState, PredictorError
from .dynamics import DoubleIntegrator, VelocityTrackingDoubleIntegrator
from .fallbacks import Brake, Hold, LambdaSearch, Relax
from .feasibility import FeasibilityFloor, feasibility_floor
from .filters import Exact2DSafetyFilter, QPSafetyFilter, VelocityFilter
from .loss import CBFGapLoss, CBFShortfallLoss, CBFTruth
from .reference import AttractiveField
from .roles import (
    Barrier,
    Dynamics,
    Fallback,
    FilterResult,
    FilterStatus,
    ReferenceController,
    SafetyFilter,
)
from .stepwise import StepwiseCBF, Stream

__all__ = [
    "APFBarrier",
    "AttractiveField",
    "Barrier",
    "Brake",
    "CBFGapLoss",
    "CBFIntervalRecord",
    "CBFShortfallLoss",
    "CBFTruth",
    "ConformalCBFController",
    "ConformalConstraint",
    "ControlState",
    "DoubleIntegrator",
    "Dynamics",
    "Exact2DSafetyFilter",
    "Fallback",
    "FeasibilityFloor",
    "FilterResult",
    "FilterStatus",
    "Hold",
    "LambdaSearch",
    "PredictorError",
    "QPSafetyFilter",
    "ReferenceController",
    "Relax",
    "SafetyFilter",
    "StepwiseCBF",
    "Stream",
    "VelocityFilter",
    "VelocityTrackingDoubleIntegrator",
    "feasibility_floor",
]
