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
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # (annotations only: the constraint and the record import nothing from here)
    from .constraint import ConformalConstraint
    from .records import CBFIntervalRecord

__all__ = [
    "DEFAULT_FLOOR_SHARE",
    "FeasibilityFloor",
    "default_lambda_min",
    "feasibility_floor",
    "robot_speed_bound",
    "row_floors",
]

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


def robot_speed_bound(v_max: float, speed_sides: int) -> float:
    """The radius of the robot's speed set (m/s): ``v_max`` for the polygon inscribed in
    the disc of radius ``v_max`` (``speed_sides >= 3``), ``sqrt(2) v_max`` for the box
    (``speed_sides = 0``).

    Parameters
    ----------
    v_max : float
        The speed bound of the safety filter (m/s).
    speed_sides : int
        Its polygon's sides (0: the box).
    """
    return float(v_max) if int(speed_sides) else math.sqrt(2.0) * float(v_max)


def row_floors(
    constraint: ConformalConstraint, record: CBFIntervalRecord, robot_speed: float
) -> np.ndarray:
    """Each agent's own feasibility floor over an interval: the lowest lambda_j at which
    its row stayed satisfiable at every control instant of it (1/s, one per
    ``record.ids``; NaN for an agent with no finite row).

    Agent j's row at instant t is ``A_j(t) . v + b_j(t) + lambda_j >= 0`` with A_j =
    dh^/dx_ego and b_j = dh^/dx_j . v^_j + a h^ (:meth:`ConformalConstraint.rows`, on the
    prediction the robot decided with). Over the speed set (radius ``robot_speed`` = V) the
    largest ``A_j . v`` is at most ``V |A_j|``, so the row has a solution only if
    ``lambda_j >= -(b_j(t) + V |A_j(t)|)``; the floor is the largest of these over the
    interval's instants (the row satisfiable at every one of them). A far agent (no
    gradient, h^ = h_max) has the global feasibility floor ``-a h_max``
    (:func:`feasibility_floor`); an agent predicted close has a higher one. With V the
    radius of the set the floor is a necessary condition (a polygon's largest ``A . v``
    can be up to ``1 - cos(pi / sides)`` below ``V |A|``); it ignores the other rows
    (the joint problem can be infeasible above every row's own floor).

    Parameters
    ----------
    constraint : ConformalConstraint
        The run's constraint (the controller's).
    record : CBFIntervalRecord
        The interval's record (the robot's positions and the predictions per instant).
    robot_speed : float
        The radius of the robot's speed set (m/s, :func:`robot_speed_bound`).

    Raises
    ------
    ValueError
        If ``robot_speed`` is not a finite number >= 0 (one line).
    """
    v = float(robot_speed)
    if not (math.isfinite(v) and v >= 0.0):
        raise ValueError(f"robot_speed must be a finite number of m/s >= 0, got {robot_speed!r}")
    s, n = record.n_steps, record.ids.size
    if s == 0 or n == 0:
        return np.full(n, np.nan)
    x_ego = np.asarray(record.x_ego, dtype=float)[:s, None, :]
    h, dh_dego, dh_dagent = constraint.barrier.evaluate(x_ego, record.x_pred[:s])
    b = (dh_dagent * record.v_pred[:s]).sum(-1) + constraint.a * h
    with np.errstate(invalid="ignore"):
        floor = -(b + v * np.hypot(dh_dego[..., 0], dh_dego[..., 1]))
    ok = np.isfinite(floor)
    out = np.full(n, np.nan)
    has = ok.any(axis=0)
    if has.any():
        out[has] = np.max(np.where(ok[:, has], floor[:, has], -np.inf), axis=0)
    return out
