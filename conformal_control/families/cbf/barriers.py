"""Pairwise collision-avoidance barriers."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.base import CompiledForm
from .roles import Barrier

__all__ = ["APFBarrier", "APFForm"]


@dataclass(frozen=True)
class APFForm(CompiledForm):
    """The APF barrier as the compiled step reads it (validated constants).

    Attributes
    ----------
    K_rep : float
        Repulsion gain (> 0).
    rho0 : float
        Influence distance (m, > 0).
    d_c : float
        Collision distance (m, >= 0).
    delta : float
        The offset used (:attr:`APFBarrier.effective_delta`).
    surface : bool
        Whether distances are measured between surfaces (``convention="surface"``).
    """

    kernel = "apf"
    K_rep: float
    rho0: float
    d_c: float
    delta: float
    surface: bool


_CONVENTIONS = ("surface", "centre")


class APFBarrier(
    Barrier,
    compiled="apf",
    run_values={
        "d_c": "barrier_distance",
        "K_rep": "K_rep",
        "rho0": "rho0",
        "convention": "convention",
        "delta": "delta",
    },
):
    """Artificial-potential-field barrier (Singletary et al. 2021), as in the paper.

    With the repulsive potential ``U(rho) = K_rep/2 (1/rho - 1/rho0)^2`` for
    ``0 < rho <= rho0`` and 0 beyond, the barrier is ``h = 1 / (1 + U(rho)) - delta``.

    Two distance conventions, chosen by ``convention``:

    * ``"surface"`` (default, what the published code ran): ``rho = d - d_c``, the gap
      between the two discs; ``delta = 1/2``. Then h is in (-1/2, 1/2] and ``h >= 0``
      means the gap is at least ``1 / (sqrt(2 (1/delta - 1) / K_rep) + 1/rho0)`` > 0.
    * ``"centre"`` (the paper's formula read literally): ``rho = d`` and
      ``delta = 1/(1 + U(d_c))`` so that h = 0 exactly at the collision distance.

    The value and the exact gradient are computed in the algebraically equivalent form
    ``h = 2 rho^2 / D - delta``, ``dh/drho = 4 K_rep q rho / D^2`` with
    ``q = 1 - rho/rho0`` and ``D = 2 rho^2 + K_rep q^2``, which is finite for every
    ``rho >= 0`` (no 1/rho blow-up). Overlap (``rho <= 0``) gives ``h = -delta`` with a
    zero gradient, the continuous limit; at zero centre distance the direction is
    undefined and the gradient is zero as well.

    Parameters
    ----------
    K_rep : float
        Repulsive gain in m^2 (> 0).
    rho0 : float
        Influence distance in metres (> 0); beyond it h = 1 - delta.
    d_c : float
        Collision distance in metres (robot radius + agent radius), >= 0.
    convention : {"surface", "centre"}
        Distance convention.
    delta : float, optional
        Offset; defaults to 1/2 ("surface") or 1/(1 + U(d_c)) ("centre").
    """

    def __init__(
        self,
        K_rep: float = 1.0,
        rho0: float = 10.0,
        d_c: float = 1.0,
        convention: str = "surface",
        delta: float | None = None,
    ) -> None:
        self.K_rep = K_rep
        self.rho0 = rho0
        self.d_c = d_c
        self.convention = convention
        self.delta = delta

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{}, {"convention": "centre", "K_rep": 2.0, "rho0": 5.0, "d_c": 0.6}]

    # ------------------------------------------------------------------ helpers
    def _checked(self) -> tuple[float, float, float, float]:
        K, rho0, d_c = float(self.K_rep), float(self.rho0), float(self.d_c)
        if not (math.isfinite(K) and K > 0):
            raise ValueError(f"K_rep must be a finite number > 0, got {self.K_rep!r}")
        if not (math.isfinite(rho0) and rho0 > 0):
            raise ValueError(f"rho0 must be a finite number > 0, got {self.rho0!r}")
        if not (math.isfinite(d_c) and d_c >= 0):
            raise ValueError(f"d_c must be a finite number >= 0, got {self.d_c!r}")
        if self.convention not in _CONVENTIONS:
            raise ValueError(f"convention must be one of {_CONVENTIONS}, got {self.convention!r}")
        return K, rho0, d_c, self.effective_delta

    def compiled_state(self) -> APFForm:
        """The barrier's constants for the compiled step (validated: ``ValueError`` for a
        bad parameter, as :meth:`evaluate` raises)."""
        K, rho0, d_c, delta = self._checked()
        return APFForm(K, rho0, d_c, delta, self.convention == "surface")

    def potential(self, rho: float) -> float:
        """U(rho) (dimensionless); infinite for rho <= 0."""
        if rho <= 0:
            return math.inf
        if rho >= self.rho0:
            return 0.0
        return 0.5 * self.K_rep * (1.0 / rho - 1.0 / self.rho0) ** 2

    @property
    def effective_delta(self) -> float:
        """The delta actually used."""
        if self.delta is not None:
            return float(self.delta)
        if self.convention == "surface":
            return 0.5
        return 1.0 / (1.0 + self.potential(self.d_c))

    @property
    def upper_bound(self) -> float:
        return 1.0 - self.effective_delta

    # ------------------------------------------------------------------ API
    def evaluate(
        self, x_ego: np.ndarray, x_agent: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        K, rho0, d_c, delta = self._checked()
        diff = np.subtract(x_ego, x_agent, dtype=float)
        d = np.hypot(diff[..., 0], diff[..., 1])
        rho = d - d_c if self.convention == "surface" else d
        r = np.minimum(np.maximum(rho, 0.0), rho0)
        q = 1.0 - r / rho0
        r2 = r * r
        inv_d = 1.0 / (2.0 * r2 + K * q * q)
        h = 2.0 * r2 * inv_d - delta
        # dh/drho / d; where d = 0 the distance variable is <= 0, so dh/drho = 0 too
        scale = 4.0 * K * q * r * inv_d * inv_d / np.maximum(d, 1e-300)
        dh_dego = scale[..., None] * diff
        return h, dh_dego, -dh_dego
