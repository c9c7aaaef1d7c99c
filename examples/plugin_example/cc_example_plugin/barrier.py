"""A distance-squared collision barrier."""

from __future__ import annotations

import math

import numpy as np

from conformal_control import Barrier

__all__ = ["DistanceSquaredBarrier"]


# run_values: the run hands d_c its collision distance (+ barrier margin) unless given
class DistanceSquaredBarrier(Barrier, run_values={"d_c": "barrier_distance"}):
    """h = ||x_ego - x_agent||^2 - d_c^2 (m^2), with its exact gradient.

    ``h >= 0`` means the centres are at least ``d_c`` apart. The gradients are
    ``dh/dx_ego = 2 (x_ego - x_agent)`` and ``dh/dx_agent = -dh/dx_ego``. h is unbounded
    above (``upper_bound`` is None), so every target loss is attainable.

    Parameters
    ----------
    d_c : float
        Collision distance in metres (>= 0). ``conformal-control run --barrier
        distance_squared`` passes the run's robot radius + agent radius (+ the barrier
        margin) unless given: the class declares it (``run_values``).
    """

    def __init__(self, d_c: float = 1.0) -> None:
        self.d_c = d_c

    @classmethod
    def _unit_test_params(cls) -> list[dict]:
        """Constructor kwargs the contract kit checks."""
        return [{}, {"d_c": 0.45}]

    def evaluate(
        self, x_ego: np.ndarray, x_agent: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if not (math.isfinite(self.d_c) and self.d_c >= 0):
            raise ValueError(f"d_c must be a finite number >= 0, got {self.d_c!r}")
        diff = np.subtract(x_ego, x_agent, dtype=float)  # broadcasts, never writes the inputs
        h = np.einsum("...i,...i->...", diff, diff) - float(self.d_c) ** 2
        grad = 2.0 * diff
        return h, grad, -grad
