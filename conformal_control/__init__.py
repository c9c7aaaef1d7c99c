"""conformal-control: safe decisions from imperfect predictions.

Conformal decision theory tunes a scalar lambda online, lambda <- lambda + eta (epsilon -
loss), over a family of decision policies ordered by conservativeness. The flagship
instantiation adds lambda as slack to control-barrier-function constraints built from
predicted pedestrian trajectories (Huriot & Sibai).

Every public name, the generic core (:mod:`conformal_control.core.base`,
:mod:`conformal_control.core.loop`, :mod:`conformal_control.core.monitor`) included, is imported on
first use (``from conformal_control import ConformalLoop`` works as usual), so
``import conformal_control`` costs next to nothing: not even numpy is imported until a
name that needs it is used (the command line's ``--help`` and ``--version`` stay instant).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ._moved import install as _install_moved

__version__ = "0.3.0"

if TYPE_CHECKING:  # for type checkers and IDEs; at run time these come from __getattr__
    from .api import run, shadow
    from .core.base import (
        DecisionFamily,
        Environment,
        Loss,
        Plugin,
        SingleStepEnvironment,
        UpdateRule,
    )
    from .core.loop import ConformalLoop, IntervalLog, LoopResult
    from .core.monitor import GuaranteeMonitor
    from .core.spec import Parameters, RunSpec
    from .families.cbf.roles import (
        Barrier,
        Dynamics,
        Fallback,
        FilterResult,
        ReferenceController,
        SafetyFilter,
    )
    from .families.cbf.stepwise import StepwiseCBF, Stream
    from .predictors.base import Forecast, PredictionQuery, Predictor
    from .world.crowds.base import CrowdModel

#: Public names imported on first use: name -> module.
_LAZY = {
    "DecisionFamily": "conformal_control.core.base",
    "Environment": "conformal_control.core.base",
    "Loss": "conformal_control.core.base",
    "Plugin": "conformal_control.core.base",
    "SingleStepEnvironment": "conformal_control.core.base",
    "UpdateRule": "conformal_control.core.base",
    "ConformalLoop": "conformal_control.core.loop",
    "IntervalLog": "conformal_control.core.loop",
    "LoopResult": "conformal_control.core.loop",
    "GuaranteeMonitor": "conformal_control.core.monitor",
    "run": "conformal_control.api",
    "shadow": "conformal_control.api",
    "RunSpec": "conformal_control.core.spec",
    "Parameters": "conformal_control.core.spec",
    "StepwiseCBF": "conformal_control.families.cbf.stepwise",
    "Stream": "conformal_control.families.cbf.stepwise",
    "Predictor": "conformal_control.predictors.base",
    "PredictionQuery": "conformal_control.predictors.base",
    "Forecast": "conformal_control.predictors.base",
    "Barrier": "conformal_control.families.cbf.roles",
    "SafetyFilter": "conformal_control.families.cbf.roles",
    "FilterResult": "conformal_control.families.cbf.roles",
    "ReferenceController": "conformal_control.families.cbf.roles",
    "Dynamics": "conformal_control.families.cbf.roles",
    "Fallback": "conformal_control.families.cbf.roles",
    "CrowdModel": "conformal_control.world.crowds.base",
}

__all__ = [
    "Barrier",
    "ConformalLoop",
    "CrowdModel",
    "DecisionFamily",
    "Dynamics",
    "Environment",
    "Fallback",
    "FilterResult",
    "Forecast",
    "GuaranteeMonitor",
    "IntervalLog",
    "LoopResult",
    "Loss",
    "Parameters",
    "Plugin",
    "PredictionQuery",
    "Predictor",
    "ReferenceController",
    "RunSpec",
    "SafetyFilter",
    "SingleStepEnvironment",
    "StepwiseCBF",
    "Stream",
    "UpdateRule",
    "__version__",
    "run",
    "shadow",
]


_install_moved()  # the module paths of 0.3 keep working, with a dated warning


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
