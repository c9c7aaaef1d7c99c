"""The published CC-MPC: a sampling MPC rewarding distance, its weight learned (``soft_mpc``).

The conformal controller of conformal decision theory (Lekeufack et al. 2024) as the ETH/UCY
planar protocol's published code runs it (CORE-SNU/FCP-MPC, ``controllers/cc.py`` and
``planar/sims/sim_cc.py``, read, not used): no candidate is excluded; the cost of a plan is
the sampling MPC's (goal, terminal goal, effort) **minus** a weight times the sum over its
steps of the distance from the plan's position at the step's end to the nearest predicted
pedestrian then. The weight is the conformal variable: after every step it moves by the
fixed-eta rule on the loss ``-d_min`` (minus the distance from the robot to the nearest
pedestrian now), with target ``epsilon = -2`` m and step ``eta = 5000``, and is kept at
least 0.01. A robot closer than 2 m raises the weight, a robot further lowers it.

In the toolkit's convention (a smaller lambda is more conservative) lambda is minus that
weight: the cost is ``cost + lambda sum_h d_h`` with ``lambda <= -0.01``, the loss is
:class:`NegativeDistanceLoss` (``negative_distance``), and the published update is the
``fixed_eta`` rule with ``epsilon = -2``, ``eta = 5000``, ``lambda_init = -1``,
``lambda_max = -0.01`` (its capabilities' ``default_rule_params``).

Where this differs from the published runs: the published controller updates its weight at
every step of the warm-up too (the robot standing still); in the planar suite an interval
without a decision has no record, so no loss and no update. The published controller applies
the chosen plan's second command, equal to its first when commands are held two steps (the
published setting); this family applies the first.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ...core.base import Loss
from ...core.losses import check_lambda
from ..cbf.controller import CBFIntervalRecord, ControlState
from ..cbf.loss import CBFTruth, gap_test_inputs
from .controller import Plan, PlanInputs, SamplingMPC
from .fieldcp import step_distances

__all__ = ["NegativeDistanceLoss", "SoftRewardMPC"]


class SoftRewardMPC(
    SamplingMPC,
    default_loss="negative_distance",
    lambda_unit="1/m",
    # the published update: target -2 m, step 5000, weight at least 0.01 (lambda <= -0.01)
    default_rule_params={"epsilon": -2.0, "eta": 5000.0, "lambda_init": -1.0, "lambda_max": -0.01},
):
    """Sampling MPC with a reward for distance instead of a safe distance (the published
    CC-MPC).

    See the module docstring: every candidate is safe (no safe distance); the cost gains
    ``lambda sum_h d_h`` (``d_h`` the distance from the plan's position at the end of step h
    to the nearest predicted pedestrian then; lambda <= 0 rewards distance). ``d_c`` and
    ``margin`` do not enter the plan.

    Parameters
    ----------
    predictor, dynamics, reference, sampling, d_c, margin, limits, costs
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    fallback, continuous, substeps, random_state
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC` (no step is ever
        infeasible, so the fallback is never used).
    **grouped
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    """

    def plan_radius(self, lam: float, positions: np.ndarray) -> np.ndarray:
        """No safe distance: every candidate is kept (radius 0)."""
        return np.zeros(positions.shape[:2])

    def plan_begin(self, state: ControlState, lam: float) -> PlanInputs:
        todo = super().plan_begin(state, lam)
        self._reward: np.ndarray | None = None
        if self._ids.size:
            d = step_distances(todo.positions, todo.problem[3])
            self._reward = float(lam) * d.sum(axis=1)
        return todo

    def plan_end(
        self, todo: PlanInputs, cost: np.ndarray, clear: np.ndarray, viol: np.ndarray
    ) -> Plan:
        reward, self._reward = getattr(self, "_reward", None), None
        if reward is not None:
            cost = cost + reward
        return super().plan_end(todo, cost, clear, viol)


class NegativeDistanceLoss(Loss[CBFIntervalRecord, CBFTruth]):
    """l_k = minus the distance (m) from the robot to the nearest sensed pedestrian at the
    interval's first control instant (the published CC-MPC's loss; target epsilon = -2 m:
    on average no closer than 2 m), a distance beyond :attr:`D_MAX` counting as
    :attr:`D_MAX` (a bounded loss, as the guarantees need; the published loss is not
    capped). In [-D_MAX, 0]; no pedestrian with a known position: no loss. It does not
    depend on lambda (only through the decisions taken)."""

    #: Distances beyond this count as this (m).
    D_MAX: ClassVar[float] = 100.0
    bounds = (-100.0, 0.0)

    def __init__(self) -> None:
        pass

    @classmethod
    def _unit_test_inputs(cls) -> list[tuple[CBFIntervalRecord, CBFTruth]]:
        return gap_test_inputs()

    def __call__(self, record: CBFIntervalRecord, truth: CBFTruth, lam: float) -> float | None:
        check_lambda(lam)
        if record.n_steps == 0 or record.ids.size == 0:
            return None
        now = np.asarray(truth.samples, dtype=float)[:, 0]
        if record.scored is not None:
            now = now[np.asarray(record.scored, dtype=bool)]
        d = np.linalg.norm(now - np.asarray(record.x_ego[0], dtype=float), axis=-1)
        d = d[np.isfinite(d)]
        return -min(float(d.min()), self.D_MAX) if d.size else None

    def diagnostics(self, record: Any, truth: Any, lam: float) -> dict[str, float]:
        out = self(record, truth, lam)
        return {} if out is None else {"d_min": -out}
