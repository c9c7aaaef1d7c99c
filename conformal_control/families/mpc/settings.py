"""The sampling MPC's parameter groups, shared by every planning family (``mpc``,
``acp_mpc``, ``ecp_mpc``).

Each is a small frozen :class:`~conformal_control.core.base.Settings`: a family takes it as
one argument (``sampling=Sampling(n_samples=200)``) and reports and takes its fields as
deep parameters (``family.get_params(deep=True)["sampling__n_samples"]``,
``family.set_params(costs__w_goal=2.0)``; the registry's ``("mpc", {"costs__w_goal":
2.0})`` form). The fields are validated when the family is reset, as every parameter.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from ...core.base import Settings

__all__ = [
    "MAX_HORIZON",
    "MAX_PLAN_POINTS",
    "MAX_REPLAN_EVERY",
    "MAX_SAMPLES",
    "Costs",
    "Limits",
    "Sampling",
    "check_groups",
]


@dataclass(frozen=True)
class Sampling(Settings):
    """How plans are drawn and how often they are made.

    Every plan holds ``n_samples x horizon`` points (at most :data:`MAX_PLAN_POINTS`):
    the ranges below are checked when the family is reset, before anything is allocated.

    Parameters
    ----------
    n_samples : int
        Random command sequences per plan (1 to :data:`MAX_SAMPLES`; the family adds its
        seeds).
    horizon : int
        Plan steps H (1 to :data:`MAX_HORIZON`).
    dt_plan : float
        Duration of a plan step (s, > 0).
    hold : int
        Plan steps each random command is held for (1 to ``horizon``).
    replan_every : int
        Control instants between plans (1 to :data:`MAX_REPLAN_EVERY`); in between, the
        plan's commands are replayed.
    """

    n_samples: int = 500
    horizon: int = 12
    dt_plan: float = 0.4
    hold: int = 2
    replan_every: int = 1


@dataclass(frozen=True)
class Costs(Settings):
    """Weights of the plan cost ``w_goal sum_{h<H} |p_h - g|^2 + w_terminal |p_H - g|^2
    + w_effort sum |u_h|^2 + w_comfort sum |u_h - u_{h-1}|^2`` (all >= 0).

    Parameters
    ----------
    w_goal : float
        Squared distance to the goal along the plan (1/m^2 per step).
    w_terminal : float
        Squared distance to the goal at the plan's end.
    w_effort : float
        Squared command (control effort).
    w_comfort : float
        Squared change of the command between steps (0: the published sampling MPCs'
        cost).
    """

    w_goal: float = 1.0
    w_terminal: float = 10.0
    w_effort: float = 0.001
    w_comfort: float = 0.0


@dataclass(frozen=True)
class Limits(Settings):
    """Bounds of the sampled commands.

    Parameters
    ----------
    v_max : float
        Speed bound of sampled velocity commands (m/s, > 0).
    a_max : float
        Bound of sampled acceleration commands (m/s^2, > 0); also the braking bound.
    """

    v_max: float = 1.0
    a_max: float = 2.0


#: The plausible ranges of the sampling sizes: a plan of 100,000 samples over 12 steps
#: takes seconds per control instant already; more is a typo, not a setting
#: (``n_samples=1e9`` asked for 44.7 GiB, ``horizon=100000`` ran for minutes).
MAX_SAMPLES = 100_000
MAX_HORIZON = 1_000
MAX_REPLAN_EVERY = 100_000
#: The most points (samples x steps) one plan holds: 16 MB per coordinate array.
MAX_PLAN_POINTS = 2_000_000


def _positive_int(name: str, v: object, high: int | None = None) -> None:
    ok = isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)
    if not ok or int(v) != v or v < 1 or (high is not None and v > high):  # type: ignore[call-overload, operator]
        bound = "a positive integer" if high is None else f"an integer from 1 to {high:,}"
        raise ValueError(f"{name} must be {bound}, got {v!r}")


def check_groups(sampling: object, costs: object, limits: object) -> None:
    """Validate a family's three groups (one-line ``ValueError`` naming the field).

    Parameters
    ----------
    sampling : Sampling
        The family's ``sampling`` argument.
    costs : Costs
        The family's ``costs`` argument.
    limits : Limits
        The family's ``limits`` argument.
    """
    for name, value, cls in (
        ("sampling", sampling, Sampling),
        ("costs", costs, Costs),
        ("limits", limits, Limits),
    ):
        if not isinstance(value, cls):
            raise ValueError(f"{name} must be a {cls.__name__}, got {value!r}")
    assert isinstance(sampling, Sampling)
    assert isinstance(costs, Costs)
    assert isinstance(limits, Limits)
    _positive_int("n_samples", sampling.n_samples, MAX_SAMPLES)
    _positive_int("horizon", sampling.horizon, MAX_HORIZON)
    _positive_int("hold", sampling.hold, int(sampling.horizon))
    _positive_int("replan_every", sampling.replan_every, MAX_REPLAN_EVERY)
    if sampling.n_samples * sampling.horizon > MAX_PLAN_POINTS:
        raise ValueError(
            f"n_samples x horizon must be at most {MAX_PLAN_POINTS:,} plan points, got "
            f"{sampling.n_samples:,} x {sampling.horizon:,}"
        )
    positive = {"dt_plan": sampling.dt_plan, "v_max": limits.v_max, "a_max": limits.a_max}
    for name, v in positive.items():
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
    for name, v in costs.get_params().items():
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be a finite weight >= 0, got {v!r}")
