"""A sampling MPC whose learned safe distances hold over the span the loss scores
(``interval_margin_mpc``).

The margin losses (:mod:`~conformal_control.families.mpc.margin`) score the forecast's
clearance error at the control instants of one interval: the forecast up to one sampling
period ahead. :class:`~conformal_control.families.mpc.controller.SamplingMPC` applies the
learned safe distance ``d_c + margin - lambda`` at every step of its plan (seconds ahead),
where nothing calibrated it. Under a delayed forecast the learned distance grows, and the
plan detours around where the pedestrians are predicted seconds later.

This family applies the learned distances only over the plan steps that cover one interval
(``span="interval"``: ``ceil(interval / dt_plan)`` steps, at least one) or over the first
``span`` steps (an integer); beyond them every plan keeps the fixed ``d_c + margin`` from
every prediction, as ``mpc`` does. A span of the whole horizon is the plain ``mpc`` family.

**lambda per pedestrian reaches the plan.** With lambda run per pedestrian
(``lambda_per="agent"``), pedestrian j's safe distance over the span is ``max(d_c + margin
- lambda_j, 0)``, each its own, whether ``decide`` plans itself or a lockstep batch
planned for it (as in :class:`~conformal_control.families.mpc.controller.SamplingMPC`).

How a plan is checked: the candidates' cost and their clearance beyond the span come from
one evaluation of the whole horizon (the safe distances of the steps in the span set so low
they never bind), and the clearance within the span from a second evaluation of those steps
only; a plan's clearance is the smaller, its violation the sum. Both evaluations are the
kernels' (:func:`~conformal_control.families.mpc.kernels.evaluate`), so a batch of episodes
evaluating the first for many episodes at once
(:func:`~conformal_control.families.mpc.batch.plan_all`) gives the same plans.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...predictors.base import PredictionQuery, Predictor
from ..cbf.controller import ControlState
from ..cbf.roles import Dynamics, ReferenceController
from .controller import Plan, PlanInputs, SamplingMPC
from .kernels import evaluate
from .settings import Costs, Limits, Sampling

__all__ = ["IntervalMarginMPC"]

#: The safe distance of a step outside an evaluation's part (m): low enough never to bind.
_OFF = -1.0e9


class IntervalMarginMPC(SamplingMPC):
    """Sampling MPC with the learned safe distances over the span one interval covers,
    the fixed ``d_c + margin`` beyond (see the module docstring).

    Parameters
    ----------
    predictor, dynamics, reference, sampling, d_c, margin, limits, costs
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    fallback, continuous, substeps, random_state, edge
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    span : "interval" or int
        The plan steps over which the learned safe distances hold: ``"interval"`` (those
        covering one interval, ``ceil(interval / dt_plan)``, at least one) or a number of
        steps (>= 1; the horizon or more: every step, as ``mpc``).
    **grouped
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    """

    def __init__(
        self,
        predictor: Predictor,
        dynamics: Dynamics,
        reference: ReferenceController | None = None,
        sampling: Sampling | None = None,
        d_c: float = 1.0,
        margin: float = 0.0,
        limits: Limits | None = None,
        costs: Costs | None = None,
        fallback: str = "brake",
        continuous: bool = True,
        substeps: int = 4,
        random_state: int = 0,
        edge: str = "escape",
        span: str | int = "interval",
        **grouped: Any,
    ) -> None:
        self.span = span
        super().__init__(
            predictor,
            dynamics,
            reference,
            sampling,
            d_c,
            margin,
            limits,
            costs,
            fallback,
            continuous,
            substeps,
            random_state,
            edge,
            **grouped,
        )

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        base = super()._unit_test_params()
        return [{**base[0]}, {**base[1], "span": 2}]

    def _validate(self) -> None:
        super()._validate()
        s = self.span
        if s != "interval" and (isinstance(s, (bool, str)) or int(s) != s or s < 1):
            raise ValueError(f"span must be 'interval' or a number of plan steps >= 1, got {s!r}")

    def reset(self) -> None:
        super().reset()
        self._k = int(self.sampling.horizon)
        self._near: tuple[Any, ...] | None = None

    def span_steps(self, observation: PredictionQuery) -> int:
        """The plan steps the learned distances hold over for an interval of
        ``observation`` (its ``horizon`` frames of ``dt`` seconds), from 1 to the horizon.

        Parameters
        ----------
        observation : PredictionQuery
            The interval's query.
        """
        h = int(self.sampling.horizon)
        if self.span == "interval":
            length = float(observation.horizon) * float(observation.dt)
            k = math.ceil(length / float(self.sampling.dt_plan) - 1e-9)
        else:
            k = int(self.span)
        return min(max(k, 1), h)

    def begin_interval(self, observation: PredictionQuery) -> None:
        self._k = self.span_steps(observation)
        super().begin_interval(observation)

    def plan_begin(self, state: ControlState, lam: Any) -> PlanInputs:
        todo = super().plan_begin(state, lam)
        self._near = None
        k, h = self._k, int(self.sampling.horizon)
        if not self._ids.size or k >= h:
            return todo
        p = todo.problem
        radius = np.asarray(p[5], dtype=float)
        # within the span: the learned distances (and offsets per pedestrian) on steps < k
        near_pred = np.ascontiguousarray(p[3][:, :k])
        self._near = (
            np.ascontiguousarray(p[0][:, :k]),
            np.ascontiguousarray(p[1][:, :k]),
            p[2],
            near_pred,
            p[4],
            np.ascontiguousarray(radius[..., :k]),
            *p[6:],
        )
        # beyond it: d_c + margin from every prediction; the cost over the whole horizon
        far = np.full(radius.shape, float(self.d_c) + float(self.margin))
        far[..., :k] = _OFF
        problem = (*p[:5], far, *p[6:10])
        return PlanInputs(todo.state, todo.lam, todo.commands, todo.positions, problem, todo.rows)

    def plan_end(
        self, todo: PlanInputs, cost: np.ndarray, clear: np.ndarray, viol: np.ndarray
    ) -> Plan:
        near, self._near = self._near, None
        if near is not None:
            _, near_clear, near_viol = evaluate(*near)
            clear = np.minimum(clear, near_clear)
            viol = viol + near_viol
        return super().plan_end(todo, cost, clear, viol)
