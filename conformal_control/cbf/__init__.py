"""The conformal CBF controller (the flagship decision family)."""

from .barriers import APFBarrier
from .controller import CBFIntervalRecord, ConformalCBFController, ControlState
from .feasibility import FeasibilityFloor, feasibility_floor
from .loss import CBFGapLoss, CBFTruth
from .qp import QPSafetyFilter

__all__ = [
    "APFBarrier",
    "CBFGapLoss",
    "CBFIntervalRecord",
    "CBFTruth",
    "ConformalCBFController",
    "ControlState",
    "FeasibilityFloor",
    "QPSafetyFilter",
    "feasibility_floor",
]
