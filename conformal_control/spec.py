"""The run specification: the one table of controller parameters (this module) and the
:class:`RunSpec` every entry point builds or takes.

:class:`Parameters` is the table: one field per controller parameter, each carrying its
default, its dimension (``length^p time^q``: how it converts between a scene's units and
SI), the range it must lie in and its documentation. Everything else that lists
parameters is derived from it: :data:`PARAMETERS` (name -> (default, doc), what
``conformal-control params`` prints), :data:`PARAM_DIMENSIONS` (what
:class:`~conformal_control.data.units.UnitSystem` converts) and :data:`PLAUSIBLE_SI`
(the SI range outside which a bare number is reported as suspicious).

This module imports nothing of the package but the exceptions, so every floor of the
house can read the table.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "PARAMETERS",
    "PARAM_DIMENSIONS",
    "PLAUSIBLE_SI",
    "ParamInfo",
    "Parameters",
    "parameter_info",
]


@dataclass(frozen=True)
class ParamInfo:
    """What the table knows about one parameter.

    Attributes
    ----------
    doc : str
        One line, as ``conformal-control params`` prints it.
    dimension : (int, int) or None
        Exponents of length and time (``(0, -1)``: a rate); None for a parameter that is
        not converted between unit systems (dimensionless, or always SI such as ``v_max``).
    kind : {"float", "int", "text"}
        The value's type.
    low, high : float
        The range the value (in SI) must lie in.
    closed : (bool, bool)
        Whether ``low`` and ``high`` belong to the range.
    plausible : (float, float, str) or None
        SI range and unit outside which a bare number (no unit suffix) is reported as
        suspicious (probably typed in the wrong unit).
    """

    doc: str
    dimension: tuple[int, int] | None = None
    kind: str = "float"
    low: float = -math.inf
    high: float = math.inf
    closed: tuple[bool, bool] = (True, True)
    plausible: tuple[float, float, str] | None = None

    @property
    def range_text(self) -> str:
        """The range as a reader writes it, e.g. ``(0, inf)`` or ``[1, inf)``."""
        lo = "[" if self.closed[0] and math.isfinite(self.low) else "("
        hi = "]" if self.closed[1] and math.isfinite(self.high) else ")"
        return f"{lo}{self.low:g}, {self.high:g}{hi}"


def _p(default: Any, doc: str, **info: Any) -> Any:
    """A table entry: ``default`` (None: from the scene) and its :class:`ParamInfo`."""
    return field(default=default, metadata={"info": ParamInfo(doc, **info)})


_RATE = (0, -1)
_LENGTH = (1, 0)
_POSITIVE: dict[str, Any] = {"low": 0.0, "closed": (False, True)}
_NON_NEGATIVE: dict[str, Any] = {"low": 0.0}


@dataclass(frozen=True)
class Parameters:
    """Every controller parameter with its default (None: the scene's default).

    Dimensional parameters are typed in the scene's units (SDD: pixels and frames, the
    paper's) unless a run says ``units="si"``; each field's ``metadata["info"]`` is its
    :class:`ParamInfo` (unit, range, doc).
    """

    a: float | None = _p(None, "slope of alpha(h) = a h (1/time)", dimension=_RATE, **_POSITIVE)
    K_acc: float | None = _p(
        None,
        "velocity-tracking gain of u = -K_acc (v - v_QP) (1/time)",
        dimension=_RATE,
        **_POSITIVE,
    )
    K_rep: float | None = _p(
        None, "repulsive gain of the APF barrier (length^2)", dimension=(2, 0), **_POSITIVE
    )
    K_att: float | None = _p(
        None,
        "attractive gain of the reference v_ref = -K_att (X - X_goal) (1/time)",
        dimension=_RATE,
        **_POSITIVE,
    )
    rho0: float | None = _p(
        None,
        "APF influence distance (length)",
        dimension=_LENGTH,
        plausible=(1.0, 100.0, "m"),
        **_POSITIVE,
    )
    sensing_radius: float | None = _p(
        None,
        "sensor range, centre distance (length); default rho0",
        dimension=_LENGTH,
        plausible=(1.0, 100.0, "m"),
        **_POSITIVE,
    )
    tau: float | None = _p(
        None,
        "sampling period of sensor, predictor and lambda update (time)",
        dimension=(0, 1),
        plausible=(0.0, 10.0, "s"),
        **_POSITIVE,
    )
    eta: float | None = _p(
        None, "learning rate of lambda (1/time)", dimension=_RATE, **_NON_NEGATIVE
    )
    epsilon: float | None = _p(
        None,
        "target average loss, in (-1/2, 1/2)",
        low=-0.5,
        high=0.5,
        closed=(False, False),
    )
    loss_scale: float | None = _p(
        None, "loss scale c in s(r) = arctan(r/c)/pi (1/time)", dimension=_RATE, **_POSITIVE
    )
    lambda_init: float = _p(0.0, "initial lambda (1/time)", dimension=_RATE)
    lambda_min: float = _p(
        -math.inf, "clip lambda from below (1/time) against wind-up", dimension=_RATE
    )
    lambda_max: float = _p(math.inf, "clip lambda from above (1/time)", dimension=_RATE)
    convention: str = _p(
        "surface", "barrier distance: 'surface' (disc gap) or 'centre'", kind="text"
    )
    delta: float | None = _p(
        None,
        "barrier offset delta; default 1/2 (surface) or 1/(1+U(d_c)) (centre)",
        low=0.0,
        high=1.0,
        closed=(False, False),
    )
    fallback: str = _p(
        "lambda_search", "on an infeasible QP: lambda_search | brake | hold", kind="text"
    )
    speed_sides: int = _p(
        16, "sides of the inscribed speed polygon (0 = box)", kind="int", **_NON_NEGATIVE
    )
    substeps: int = _p(4, "QP solves (control instants) per data frame", kind="int", low=1.0)
    history: int | None = _p(
        None,
        "frames of history handed to the predictor; default 4 s of frames",
        kind="int",
        low=1.0,
    )
    v_max: float | None = _p(None, "robot speed bound (m/s)", **_POSITIVE)
    barrier_margin: float = _p(
        0.0,
        "extra distance added to d_c in the barrier only (m): a robust CBF",
        **_NON_NEGATIVE,
    )
    robot_radius: float | None = _p(None, "robot radius (m)", **_POSITIVE)
    agent_radius: float | None = _p(None, "pedestrian radius (m)", **_POSITIVE)
    goal_radius: float | None = _p(None, "goal radius (m)", **_POSITIVE)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """Every parameter name, in the table's order."""
        return tuple(f.name for f in dataclasses.fields(cls))


def parameter_info(name: str) -> ParamInfo:
    """The :class:`ParamInfo` of parameter ``name`` (KeyError for an unknown name)."""
    return _INFO[name]


_INFO: dict[str, ParamInfo] = {f.name: f.metadata["info"] for f in dataclasses.fields(Parameters)}

#: name -> (default, description): ``None`` defaults are filled from the scene
#: (``scene.defaults`` first, then the scene's own attributes).
PARAMETERS: dict[str, tuple[Any, str]] = {
    f.name: (f.default, f.metadata["info"].doc) for f in dataclasses.fields(Parameters)
}

#: parameter -> (length exponent, time exponent); parameters not listed are SI already.
PARAM_DIMENSIONS: dict[str, tuple[int, int]] = {
    name: info.dimension for name, info in _INFO.items() if info.dimension is not None
}

#: SI range (and its unit) outside which a bare (suffix-less) value is reported as suspicious.
PLAUSIBLE_SI: dict[str, tuple[float, float, str]] = {
    name: info.plausible for name, info in _INFO.items() if info.plausible is not None
}
