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

from dataclasses import dataclass
from typing import Any

from ..spec import PARAM_DIMENSIONS  # the dimensions come from the one parameter table

__all__ = ["PARAM_DIMENSIONS", "SI", "UnitSystem"]


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
