"""The conformal CBF controller (the flagship decision family)."""

from .barriers import APFBarrier
from .constraint import ConformalConstraint
from .controller import CBFIntervalRecord, ConformalCBFController, ControlState, PredictorError
from .dynamics import DoubleIntegrator, VelocityTrackingDoubleIntegrator
from .feasibility import FeasibilityFloor, feasibility_floor
from .loss import CBFGapLoss, CBFTruth
from .qp import QPSafetyFilter
from .reference import AttractiveField
from .roles import (
    Barrier,
    Dynamics,
    FilterResult,
    FilterStatus,
    ReferenceController,
    SafetyFilter,
)
from .stepwise import StepwiseCBF

__all__ = [
    "APFBarrier",
    "AttractiveField",
    "Barrier",
    "CBFGapLoss",
    "CBFIntervalRecord",
    "CBFTruth",
    "ConformalCBFController",
    "ConformalConstraint",
    "ControlState",
    "DoubleIntegrator",
    "Dynamics",
    "FeasibilityFloor",
    "FilterResult",
    "FilterStatus",
    "PredictorError",
    "QPSafetyFilter",
    "ReferenceController",
    "SafetyFilter",
    "StepwiseCBF",
    "VelocityTrackingDoubleIntegrator",
    "feasibility_floor",
]
