"""Reference (nominal) controllers."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...core.base import CompiledForm
from .roles import ReferenceController

__all__ = ["AttractiveField", "AttractiveFieldForm"]


@dataclass(frozen=True)
class AttractiveFieldForm(CompiledForm):
    """The attractive field as the compiled step reads it.

    Attributes
    ----------
    K_att : float
        Gain (1/s).
    v_max : float
        Speed cap of the reference (m/s).
    """

    kernel = "attractive_field"
    K_att: float
    v_max: float


class AttractiveField(
    ReferenceController,
    compiled="attractive_field",
    run_values={"K_att": "K_att", "v_max": "v_max"},
):
    """Attractive potential toward a goal: v_ref = -K_att (X - X_goal), speed-saturated.

    The goal is supplied by the environment at each control instant (it owns the task and
    its waypoints).

    Parameters
    ----------
    K_att : float
        Attractive gain in 1/s.
    v_max : float
        Speed saturation in m/s.
    """

    def __init__(self, K_att: float = 30.0, v_max: float = 2.0) -> None:
        self.K_att = K_att
        self.v_max = v_max

    def reset(self) -> None:
        for name in ("K_att", "v_max"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")

    def compiled_state(self) -> AttractiveFieldForm:
        """The gain and the speed cap, as the compiled step reads them."""
        return AttractiveFieldForm(self.K_att, self.v_max)

    def __call__(self, state: np.ndarray, t: float, goal: np.ndarray) -> np.ndarray:
        v: np.ndarray = -self.K_att * (
            np.asarray(state[:2], dtype=float) - np.asarray(goal, dtype=float)
        )
        speed = math.hypot(v[0], v[1])
        if speed > self.v_max:
            v *= self.v_max / speed
        return v

    def velocity(self, x0: float, x1: float, g0: float, g1: float) -> tuple[float, float]:
        """:meth:`__call__` on Python floats, for a position ``(x0, x1)`` and a goal ``(g0,
        g1)``: the same IEEE operations in the same order, so the same bits (the compiled
        control step takes this path; ``K_att`` and ``v_max`` must be Python numbers).

        Parameters
        ----------
        x0, x1 : float
            The robot's position (m).
        g0, g1 : float
            The goal (m).
        """
        k = -self.K_att
        v0 = k * (x0 - g0)
        v1 = k * (x1 - g1)
        speed = math.hypot(v0, v1)
        if speed > self.v_max:
            f = self.v_max / speed
            v0 *= f
            v1 *= f
        return v0, v1
