"""Reference (nominal) controllers."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .base import ReferenceController

__all__ = ["AttractiveField"]


class AttractiveField(ReferenceController):
    """Attractive potential toward a goal: v_ref = -K_att (X - X_goal), speed-saturated.

    The goal is normally supplied by the environment at each control instant (it owns the
    task and its waypoints); ``goal`` is the fallback when none is supplied.

    Parameters
    ----------
    K_att : float
        Attractive gain in 1/s.
    v_max : float
        Speed saturation in m/s.
    goal : (2,) array, optional
        Default goal position in metres.
    """

    def __init__(
        self, K_att: float = 30.0, v_max: float = 2.0, goal: Sequence[float] | None = None
    ) -> None:
        self.K_att = K_att
        self.v_max = v_max
        self.goal = goal

    def reset(self) -> None:
        for name in ("K_att", "v_max"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")

    def __call__(self, state: np.ndarray, t: float, goal: np.ndarray | None = None) -> np.ndarray:
        if goal is None:
            if self.goal is None:
                raise ValueError("AttractiveField has no goal: pass goal= or set the goal param")
            goal = np.asarray(self.goal, dtype=float)
        v = -self.K_att * (np.asarray(state[:2], dtype=float) - goal)
        speed = math.hypot(v[0], v[1])
        if speed > self.v_max:
            v *= self.v_max / speed
        return v
