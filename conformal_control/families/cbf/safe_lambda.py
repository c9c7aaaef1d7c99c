"""A lambda_safe for the CBF gap loss, derived from speed bounds (Theorem 2's premise).

Theorem 2 of the paper bounds the average loss of the fixed-step rule by
``epsilon + (lambda_1 - lambda_safe + eta) / (eta K)`` for any ``lambda_safe`` such that
``lambda <= lambda_safe`` keeps the loss at most ``epsilon`` (its premise; Theorem 1 says
such a ``lambda_safe`` exists under bounded prediction errors). This module derives one
for the gap loss :class:`~conformal_control.families.cbf.loss.CBFGapLoss` with a barrier
of the distance alone (:class:`~conformal_control.families.cbf.barriers.APFBarrier`),
from bounds on speeds only, and says what it rests on.

The derivation. With ``h = phi(rho(d))``, ``d = |x_i - x_j|``, ``u = (x_i - x_j) / d``,
the barrier's gradients are ``dh/dx_i = phi'(rho) u = -dh/dx_j``, so the constraint value
the loss compares is ``c(x_j, v_j) = phi'(rho) u . (v_i - v_j) + a phi(rho)`` and agent
j's gap at an instant is (hats: the prediction)::

    gap_j = c(x^_j, v^_j) - c(x_j, v_j)
          <= M_h |v_i - v^_j| + M_h |v_i - v_j| + a (h_max - h_min)
          <= M_h (2 V_i + V^ + V) + a (h_max - h_min)  =:  G

with ``M_h = sup |phi'|`` (the barrier's largest slope, 1/m), ``V_i`` the largest speed
the robot's decision can have (the speed set's radius), ``V`` and ``V^`` bounds on the
pedestrians' true and predicted speeds. Agent j's loss is ``s(max_t gap_j + lambda_j)``
with ``s`` increasing, so ``lambda_j <= lambda_safe := s^-1(epsilon) - G`` gives
``l_j <= s(G + lambda_safe) = epsilon``: the premise, for every agent, every interval and
every decision in the speed set. With a bound ``E_v`` on the position error, the last term
may be ``a min(h_max - h_min, M_h E_v)`` (phi is M_h-Lipschitz and
``|rho^ - rho| <= |x^_j - x_j|``).

What it does not use: the paper's proof of Theorem 1 bounds ``|dh^/dt - dh/dt|`` by
``M_h E_d``, which leaves out that ``dh/dx_i`` itself moves with the agent's position; the
bound above needs no Hessian and no velocity-error bound, only speeds. It is worst-case:
with the benchmark's barrier (a = 100/s, range 1) the ``a`` term alone is 100/s, far below
any lambda a run reaches, so the premise is rarely *tested* by the run; the monitor checks
it at every interval instead, by re-evaluating each agent's loss at ``lambda_safe``
(:class:`~conformal_control.core.monitor.AgentMonitor`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .barriers import APFBarrier
from .constraint import ConformalConstraint

__all__ = [
    "AGENT_SPEED_BOUND",
    "DerivedLambdaSafe",
    "barrier_slope_bound",
    "derive_lambda_safe",
    "gap_bound",
]

#: The pedestrians' speed bound (m/s) assumed by default, true and predicted: a fast walk
#: or a jog. The gap bound grows with it by ``2 M_h`` per m/s (4/s on the benchmark's
#: barrier, against its 100/s ``a`` term); whether the premise held is checked on the
#: episodes (the loss at ``lambda_safe`` of every agent and interval).
AGENT_SPEED_BOUND = 3.0


def barrier_slope_bound(barrier: APFBarrier) -> float:
    """``M_h = sup_rho |phi'(rho)|``: the largest slope of the APF barrier (1/m).

    ``phi'(rho) = 4 K q rho / (2 rho^2 + K q^2)^2`` with ``q = 1 - rho / rho0`` on
    ``[0, rho0]`` (0 elsewhere): evaluated on a fine grid, then refined around the best
    point with a bounded scalar search (scipy), the larger of the two kept.

    Parameters
    ----------
    barrier : APFBarrier
        The barrier (any distance convention; the slope is the same in both).
    """
    from scipy.optimize import minimize_scalar

    form = barrier.compiled_state()  # validated constants (ValueError for a bad one)
    K, rho0 = form.K_rep, form.rho0

    def slope(rho: np.ndarray | float) -> np.ndarray:
        r = np.clip(np.asarray(rho, dtype=float), 0.0, rho0)
        q = 1.0 - r / rho0
        den = 2.0 * r * r + K * q * q
        out: np.ndarray = 4.0 * K * q * r / (den * den)
        return out

    grid = np.linspace(0.0, rho0, 200_001)
    values = slope(grid)
    i = int(np.argmax(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    best = float(values[i])
    if hi > lo:
        res = minimize_scalar(
            lambda r: -float(slope(r)), bounds=(lo, hi), method="bounded", options={"xatol": 1e-12}
        )
        best = max(best, float(-res.fun))
    return best


def _check_speed(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name} must be a number of m/s >= 0, got {value!r}")
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be a finite number of m/s >= 0, got {value!r}")
    return float(value)


def gap_bound(
    constraint: ConformalConstraint,
    robot_speed: float,
    agent_speed: float = AGENT_SPEED_BOUND,
    predicted_speed: float | None = None,
    position_error: float | None = None,
) -> float:
    """G: a bound on every agent's gap ``c(x^_j, v^_j) - c(x_j, v_j)`` (1/s).

    ``M_h (2 robot_speed + predicted_speed + agent_speed) + a min(h_max - h_min, M_h E_v)``
    (the module's derivation).

    Parameters
    ----------
    constraint : ConformalConstraint
        The constraint the controller and the loss use (its APF barrier and ``a``, SI).
    robot_speed : float
        The largest speed of the robot's decision (m/s; the speed set's radius).
    agent_speed : float
        The pedestrians' true speed bound (m/s).
    predicted_speed : float, optional
        The predicted speeds' bound (m/s); default ``agent_speed``.
    position_error : float, optional
        A bound on the predicted position's error (m); default none (the barrier's whole
        range is used).

    Raises
    ------
    ValueError
        For a barrier that is not an :class:`APFBarrier` (no derivation for it), or a
        speed or error that is not a finite number >= 0.
    """
    barrier = constraint.barrier
    if not isinstance(barrier, APFBarrier):
        raise ValueError(
            f"no lambda_safe is derived for the barrier {type(barrier).__name__} (only for "
            "the APF barrier, a function of the distance alone): give lambda_safe as a number"
        )
    v_i = _check_speed("robot_speed", robot_speed)
    v = _check_speed("agent_speed", agent_speed)
    v_hat = v if predicted_speed is None else _check_speed("predicted_speed", predicted_speed)
    a = float(constraint.a)
    if not (math.isfinite(a) and a > 0):
        raise ValueError(f"the constraint's a must be a finite number > 0, got {constraint.a!r}")
    m_h = barrier_slope_bound(barrier)
    h_range = 1.0  # h = 2 rho^2 / D - delta lies in [-delta, 1 - delta]
    if position_error is not None:
        h_range = min(h_range, m_h * _check_speed("position_error", position_error))
    return m_h * (2.0 * v_i + v_hat + v) + a * h_range


@dataclass(frozen=True)
class DerivedLambdaSafe:
    """A derived ``lambda_safe`` (SI, 1/s) and what it rests on.

    Attributes
    ----------
    value : float
        ``s^-1(epsilon) - G`` (1/s).
    gap_bound : float
        G (1/s).
    source : str
        One line for the run's ``lambda_safe_source``: the bound and its assumption.
    """

    value: float
    gap_bound: float
    source: str


def derive_lambda_safe(
    constraint: ConformalConstraint,
    loss_scale: float,
    epsilon: float,
    robot_speed: float,
    agent_speed: float = AGENT_SPEED_BOUND,
    level: float | None = None,
) -> DerivedLambdaSafe:
    """``lambda_safe = c tan(pi epsilon) - G`` for the gap loss ``s(r) = arctan(r / c) / pi``.

    More generally ``lambda_safe = r_eps - G`` for any loss increasing in
    r = max_t gap_j(t) + lambda_j, with r_eps the largest r whose loss is at most epsilon
    (``level``; the loss's ``level(epsilon)``, e.g.
    :meth:`~conformal_control.families.cbf.loss.CBFShortfallLoss.level`).

    At or below it every agent's gap loss is at most ``epsilon`` whatever the prediction,
    provided the robot's speed is at most ``robot_speed`` and the pedestrians' (true and
    predicted) at most ``agent_speed`` (:func:`gap_bound`).

    Parameters
    ----------
    constraint : ConformalConstraint
        The run's constraint (APF barrier, ``a`` in 1/s).
    loss_scale : float
        The loss's scale c (1/s, > 0).
    epsilon : float
        The target, in (-1/2, 1/2).
    robot_speed : float
        The robot's speed bound (m/s).
    agent_speed : float
        The pedestrians' speed bound (m/s).
    level : float, optional
        r_eps (1/s); default ``c tan(pi epsilon)``, the gap loss's.
    """
    c = float(loss_scale)
    if not (math.isfinite(c) and c > 0):
        raise ValueError(f"loss_scale must be a finite number > 0, got {loss_scale!r}")
    eps = float(epsilon)
    if not -0.5 < eps < 0.5:
        raise ValueError(f"epsilon must lie in (-1/2, 1/2) for the gap loss, got {epsilon!r}")
    g = gap_bound(constraint, robot_speed, agent_speed)
    r_eps = c * math.tan(math.pi * eps) if level is None else float(level)
    if not math.isfinite(r_eps):
        raise ValueError(f"level must be a finite number of 1/s, got {level!r}")
    value = r_eps - g
    source = (
        f"derived: CBF gap bound G = {g:.4g}/s (robot <= {robot_speed:g} m/s, pedestrians "
        f"true and predicted <= {agent_speed:g} m/s)"
    )
    return DerivedLambdaSafe(value, g, source)
