"""The feasibility floor of the conformal CBF controller.

lambda is added to the constraint of *every* sensed agent. A far agent has a vanishing
barrier gradient and h close to its supremum h_max, so its constraint reads
``a h_max + lambda >= 0``: no velocity satisfies it once ``lambda < -a h_max``. Below that
floor the QP is infeasible whatever the ego does and the fallback applies at almost every
control instant. The loss is scored with lambda_k (the paper's definition), and a far
agent's gap is about 0, so l_k >= s(lambda_k / c) roughly: a target
``epsilon <= s(-a h_max)`` cannot be reached. lambda_k does not wind down forever; it
settles near the level where the far agents' loss equals epsilon, lambda ~ c tan(pi
epsilon) (about -1 per frame for epsilon = -0.25 with c = 1 per frame), far below the
floor, with the fallback deciding. This module computes the floor so runs can report an
unattainable epsilon before they start.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

__all__ = ["DEFAULT_FLOOR_SHARE", "FeasibilityFloor", "default_lambda_min", "feasibility_floor"]

#: The CBF family's default ``lambda_min`` as a share of the feasibility floor
#: ``-a h_max``: lambda never sinks to where a far agent's row fails and the fallback
#: decides (issue 30). Chosen on the benchmark's dev split (crossings-v2, ``conformal``
#: under ``nominal`` and ``delay-0.5s``): the share with the highest success rate among
#: 1, 0.9, 0.8 and 0.7 (see the Benchmark page, "At the edges").
DEFAULT_FLOOR_SHARE = 0.8


@dataclass(frozen=True)
class FeasibilityFloor:
    """lambda_floor = -a h_max and epsilon_floor = s(lambda_floor)."""

    lambda_floor: float
    epsilon_floor: float
    epsilon: float
    attainable: bool

    def as_dict(self) -> dict[str, float | bool]:
        return asdict(self)

    def message(self, unit: str = "1/s") -> str:
        """A one-sentence explanation for logs."""
        if self.attainable:
            return (
                f"target epsilon={self.epsilon:g} is above the feasibility floor "
                f"s(-a*h_max)={self.epsilon_floor:.4f} (lambda_floor={self.lambda_floor:g} {unit})"
            )
        return (
            f"target epsilon={self.epsilon:g} is at or below the feasibility floor "
            f"s(-a*h_max)={self.epsilon_floor:.4f}: below lambda={self.lambda_floor:g} {unit} "
            "every QP with a sensed agent is infeasible, so lambda will settle below that "
            "floor and the fallback will decide; raise epsilon, raise a, or clip lambda "
            "with lambda_min"
        )


def feasibility_floor(a: float, h_max: float, epsilon: float, scale: float) -> FeasibilityFloor:
    """Floor of lambda and of the attainable target loss.

    Parameters
    ----------
    a : float
        alpha slope (1/s).
    h_max : float
        Supremum of the barrier (``barrier.upper_bound``).
    epsilon : float
        Target average loss.
    scale : float
        Loss scale c (1/s).
    """
    lam_floor = -a * h_max
    eps_floor = math.atan(lam_floor / scale) / math.pi
    return FeasibilityFloor(lam_floor, eps_floor, float(epsilon), bool(epsilon > eps_floor))


def default_lambda_min(a: float, h_max: float | None) -> float:
    """The CBF family's default lambda floor (1/s): :data:`DEFAULT_FLOOR_SHARE` times the
    feasibility floor ``-a h_max``; ``-inf`` for a barrier unbounded above (no floor).

    Parameters
    ----------
    a : float
        alpha slope (1/s).
    h_max : float or None
        Supremum of the barrier (``barrier.upper_bound``).
    """
    if h_max is None or not math.isfinite(h_max):
        return -math.inf
    return -DEFAULT_FLOOR_SHARE * a * h_max
