"""Units: SI inside, the paper's pixel/frame units at the edge.

The paper states its parameters in the reference code's units: lengths in pixels of the
video frame and time in video frames (30 fps). A scene declares its unit system; every
parameter has a dimension ``length^p * time^q`` and converts as

    value_SI = value * (metres per length unit)^p * (seconds per time unit)^q

so for SDD (m/px = the video's scale, s/frame = 1/30):

=================  =========  ====================================
parameter          dimension  paper unit -> SI
=================  =========  ====================================
rho0, sensing      L          px -> m        (x m_per_px)
K_rep              L^2        px^2 -> m^2    (x m_per_px^2)
a, K_att, K_acc    T^-1       1/frame -> 1/s (x fps)
lambda, eta        T^-1       1/frame -> 1/s (x fps)
loss_scale (c)     T^-1       1/frame -> 1/s (x fps)
tau                T          frames -> s    (/ fps)
=================  =========  ====================================

epsilon is dimensionless; speeds (v_max), radii and the goal radius are always given in
SI (m/s, m), as the published code's scene files give them.
"""

from __future__ import annotations

import inspect
import re
from dataclasses import dataclass
from typing import Any

from ..core.exceptions import InputError
from ..core.spec import PARAM_DIMENSIONS  # the dimensions come from the one parameter table

__all__ = ["PARAM_DIMENSIONS", "SI", "SI_UNITS", "UnitSystem", "documented_unit", "si_value"]


@dataclass(frozen=True)
class UnitSystem:
    """A scene's unit system for typed-in parameters.

    Attributes
    ----------
    length : float
        Metres per length unit (SDD: the video's metres per pixel).
    time : float
        Seconds per time unit (SDD: 1/30).
    length_name, time_name : str
        Names used in configs and messages.
    """

    length: float = 1.0
    time: float = 1.0
    length_name: str = "m"
    time_name: str = "s"

    def factor(self, name: str) -> float:
        """Multiply a value of parameter ``name`` in these units by this to get SI."""
        p, q = PARAM_DIMENSIONS.get(name, (0, 0))
        return self.length**p * self.time**q

    def to_si(self, params: dict[str, Any]) -> dict[str, Any]:
        """Convert every numeric parameter of known dimension to SI."""
        out = {}
        for k, v in params.items():
            if k in PARAM_DIMENSIONS and isinstance(v, (int, float)) and not isinstance(v, bool):
                out[k] = v * self.factor(k)
            else:
                out[k] = v
        return out

    def unit_of(self, name: str) -> str:
        """Human-readable unit of a parameter in this system."""
        p, q = PARAM_DIMENSIONS.get(name, (0, 0))
        parts = []
        if p:
            parts.append(self.length_name + (f"^{p}" if p != 1 else ""))
        if q:
            parts.append(self.time_name + (f"^{q}" if q != 1 else "") if q > 0 else "")
        num = " ".join(x for x in parts if x)
        if q < 0:
            den = self.time_name + (f"^{-q}" if q != -1 else "")
            return f"{num or '1'}/{den}"
        return num or "-"

    def as_dict(self) -> dict[str, Any]:
        return {
            "length": self.length,
            "time": self.time,
            "length_name": self.length_name,
            "time_name": self.time_name,
        }


SI = UnitSystem()


# ------------------------------------------------------------------ plugin parameters (SI)
#: unit suffix -> ((length exponent, time exponent), value of one unit in SI), for the
#: parameters of plugins and crowd models, which are always in SI (pixels and frames
#: depend on a scene and are not accepted there)
SI_UNITS: dict[str, tuple[tuple[int, int], float]] = {
    "m": ((1, 0), 1.0),
    "cm": ((1, 0), 0.01),
    "mm": ((1, 0), 0.001),
    "km": ((1, 0), 1000.0),
    "m^2": ((2, 0), 1.0),
    "m2": ((2, 0), 1.0),
    "m²": ((2, 0), 1.0),
    "s": ((0, 1), 1.0),
    "ms": ((0, 1), 0.001),
    "min": ((0, 1), 60.0),
    "m/s": ((1, -1), 1.0),
    "km/h": ((1, -1), 1.0 / 3.6),
    "/s": ((0, -1), 1.0),
    "1/s": ((0, -1), 1.0),
    "hz": ((0, -1), 1.0),
    "m/s^2": ((1, -2), 1.0),
    "m/s2": ((1, -2), 1.0),
    "m/s²": ((1, -2), 1.0),
    "1/s^2": ((0, -2), 1.0),
    "1/s2": ((0, -2), 1.0),
    "1/s²": ((0, -2), 1.0),
}
_DIMENSION_WORDS = {
    (1, 0): "a length",
    (2, 0): "an area",
    (0, 1): "a time",
    (1, -1): "a speed",
    (0, -1): "a rate",
    (1, -2): "an acceleration",
    (0, -2): "a rate per second",
}
_QUANTITY = re.compile(
    r"^\s*(?P<num>[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|[+-]?inf)\s*(?P<unit>[^\d\s].*?)\s*$"
)
_PARAM_ENTRY = re.compile(r"^(?P<names>\w[\w, ]*?)\s*:[^\n]*\n(?P<desc>(?:[ \t]+[^\n]*\n?)*)", re.M)


def documented_unit(cls: type, name: str) -> str | None:
    """The SI unit of constructor argument ``name`` of ``cls``, as its numpy docstring
    states it (the first parenthesis of the description: ``tau : float`` /
    ``Relaxation time (s) ...``) or its name says it (``delay_s``, ``sigma_m``); None if
    neither does."""
    for suffix, unit in (("_s", "s"), ("_m", "m"), ("_mps", "m/s")):
        if name.endswith(suffix):
            return unit
    for klass in getattr(cls, "__mro__", (cls,)):
        doc = inspect.getdoc(klass) or ""
        section = doc.partition("Parameters\n----------\n")[2]
        section = re.split(r"\n\n\S[^\n]*\n-{3,}\n", section)[0]
        for m in _PARAM_ENTRY.finditer(section + "\n"):
            if name not in [n.strip() for n in m["names"].split(",")]:
                continue
            for group in re.findall(r"\(([^()]*)\)", " ".join(m["desc"].split())):
                unit = re.split(r"[,;]", group)[0].strip()
                if unit.lower() in SI_UNITS and unit.lower() not in ("min",):
                    return unit
            return None
    return None


def si_value(key: str, value: Any, unit: str | None, flag: str) -> Any:
    """A plugin parameter given with a unit suffix (``2m/s``, ``500ms``, ``20cm``), in SI;
    anything else unchanged.

    Parameters
    ----------
    key : str
        The parameter's name (in the errors).
    value : Any
        The value as given (a string with a suffix is converted).
    unit : str, optional
        The parameter's documented SI unit (:func:`documented_unit`).
    flag : str
        The option it came with (in the errors), e.g. ``--predictor-param``.

    Raises
    ------
    InputError
        For an unknown suffix, pixels or frames, a suffix of another dimension than the
        documented unit, or a suffix on a parameter without a documented unit.
    """
    if not isinstance(value, str):
        return value
    m = _QUANTITY.match(value)
    if m is None:
        return value
    number, suffix = float(m["num"]), m["unit"]
    given = SI_UNITS.get(suffix) or SI_UNITS.get(suffix.lower())
    known = "m, cm, mm, s, ms, m/s, km/h, 1/s, Hz, m/s^2, m^2"
    if suffix.lower() in ("px", "frame", "frames", "/frame", "1/frame", "px/frame"):
        raise InputError(
            f"{flag} {key}={value}: plugin parameters are in SI units ({known}); pixels and "
            "frames depend on the scene and are not converted here"
        )
    if given is None:
        raise InputError(f"unknown unit {suffix!r} in {flag} {key}={value}; use one of {known}")
    if unit is None:
        raise InputError(
            f"{flag} {key}={value}: {key} has no documented unit, so a suffix cannot be "
            f"checked; write {key}={m['num']} (in SI)"
        )
    want = SI_UNITS[unit.lower()]
    if given[0] != want[0]:
        raise InputError(
            f"{flag} {key}={value}: {key} is {_DIMENSION_WORDS.get(want[0], 'a quantity')} "
            f"in {unit}, but {suffix} is {_DIMENSION_WORDS.get(given[0], 'another quantity')}"
        )
    return number * given[1] / want[1]
