"""conformal-control: safe decisions from imperfect predictions.

Conformal decision theory tunes a scalar lambda online, lambda <- lambda + eta (epsilon -
loss), over a family of decision policies ordered by conservativeness. The flagship
instantiation adds lambda as slack to control-barrier-function constraints built from
predicted pedestrian trajectories (Huriot & Sibai).

The generic core (:mod:`conformal_control.base`, :mod:`conformal_control.loop`,
:mod:`conformal_control.monitor`) is imported eagerly; everything else is imported on
first use, so ``import conformal_control`` stays cheap.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.2.0.dev0"

from .base import (
    DecisionFamily,
    Environment,
    Loss,
    Plugin,
    SingleStepEnvironment,
    UpdateRule,
)
from .loop import ConformalLoop, IntervalLog, LoopResult
from .monitor import GuaranteeMonitor

#: Public names imported on first use: name -> module.
_LAZY = {
    "run": "conformal_control.api",
    "StepwiseCBF": "conformal_control.cbf.stepwise",
    "Predictor": "conformal_control.predictors.base",
    "PredictionQuery": "conformal_control.predictors.base",
    "Forecast": "conformal_control.predictors.base",
    "Barrier": "conformal_control.cbf.roles",
    "SafetyFilter": "conformal_control.cbf.roles",
    "FilterResult": "conformal_control.cbf.roles",
    "ReferenceController": "conformal_control.cbf.roles",
    "Dynamics": "conformal_control.cbf.roles",
}

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
    "Plugin",
    "PredictionQuery",
    "Predictor",
    "ReferenceController",
    "SafetyFilter",
    "SingleStepEnvironment",
    "StepwiseCBF",
    "UpdateRule",
    "__version__",
    "run",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
