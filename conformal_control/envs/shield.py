"""``ConformalShield``: filter any policy's actions through the conformal CBF.

The wrapper is the flagship controller with the policy in place of the reference
controller: at each step the policy's action is the nominal velocity, and the shield's
own safety filter returns the velocity closest to it that meets the conformal
constraints ``dh/dx . v + dh/dx_j . v_j + a h + lambda >= 0`` of the agents the robot
sensed at the last sampling time, with their positions and velocities predicted by the
shield's own predictor. The shield learns its own lambda online from its own losses
(the paper's rule by default), exactly as the flagship does: lambda grows (less
conservative) while predictions are good and shrinks when they fail.

Added to ``info`` at every step:

* ``shield_modified`` -- whether the action was changed; ``shield_delta`` -- by how much
  (m/s, the norm of the change); ``shield_action`` -- the velocity sent to the robot;
* ``shield_status`` -- ``"unconstrained"`` (the action met every constraint), ``"optimal"``
  (filtered) or the fallback used when the constraints were infeasible at lambda_k
  (``"lambda_search"``: lambda raised to the smallest feasible value, every row still
  met; ``"brake"`` / ``"hold"``: no row guaranteed);
* ``shield_active`` -- ids of the agents whose constraints bind at the returned velocity
  (slack within ``active_tol``); ``shield_n_constraints``; ``shield_min_slack``;
* ``shield_lambda`` -- lambda_k (1/s) the step was filtered with; ``shield_lambda_applied``
  -- the lambda every constraint holds at (lambda_k unless a fallback raised it; NaN
  for brake/hold); ``shield_loss`` -- the shield's loss when an interval closed;
* ``shield_cause`` -- why the action was changed: ``"none"`` (it was not),
  ``"constraint"`` (a conformal constraint binds at the returned velocity, or a fallback
  was used: the constraints shaped the result) or ``"speed_limit"`` (no constraint binds
  and no fallback was used: the action was only brought into the filter's speed set,
  ``|v| <= v_max`` -- by convexity the filter then returns what it would return without
  any constraint);
* ``shield_interventions`` -- steps the constraints changed so far (cause
  ``"constraint"``); ``shield_speed_clips`` -- steps changed by the speed limit alone.

The base environment must be a ``ConformalCrowd-v0`` (:class:`ConformalCrowdEnv`): the
shield reads the robot's sensor from it (the agents sensed at each sampling time and
their true trajectories at the next), as the flagship reads its environment.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import gymnasium as gym
import numpy as np

from ..core.loop import ConformalStepper
from ..core.spec import RunSpec
from ..runs.build import build_flagship
from .crowd import ConformalCrowdEnv
from .roles import GivenVelocity, LastSolve, RecordingFilter

__all__ = ["ConformalShield"]


class ConformalShield(
    gym.Wrapper[dict[str, np.ndarray], np.ndarray, dict[str, np.ndarray], np.ndarray],
    gym.utils.RecordConstructorArgs,  # gymnasium re-creates it (spec, check_env)
):
    """Filter a policy's velocity commands through the conformal CBF (see module docs).

    Parameters
    ----------
    env : gymnasium.Env
        A ``ConformalCrowd-v0`` environment (possibly wrapped).
    params : dict, optional
        Parameters of the shield, in the environment's units, over the environment's own
        (e.g. ``{"epsilon": -0.1, "eta": 2, "a": 2}``); timing (``tau``, ``substeps``)
        must stay the environment's.
    spec : RunSpec, optional
        The shield's run (:class:`~conformal_control.core.spec.RunSpec`); ``params`` and the
        settings below are applied on it, and its units are the environment's.
    active_tol : float
        A constraint is reported active when its slack is within this (1/s).
    **settings
        Settings of the run: the shield's roles (names or instances) ``predictor``,
        ``barrier``, ``safety_filter``, ``fallback``, ``loss``, ``rule`` and their
        ``*_params``, as for :func:`~conformal_control.runs.build.build_flagship`
        (the default is the flagship's: constant velocity, APF barrier, the exact 2-D
        filter with the lambda-search fallback, the gap loss, the fixed-step rule);
        ``learn`` (False keeps lambda at ``lambda_init``); ``seed`` (``random_state`` of
        named plugins that take one).
    """

    def __init__(
        self,
        env: gym.Env[dict[str, np.ndarray], np.ndarray],
        params: dict[str, Any] | None = None,
        *,
        spec: RunSpec | None = None,
        active_tol: float = 1e-6,
        **settings: Any,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, params=params, spec=spec, active_tol=active_tol, **settings
        )
        gym.Wrapper.__init__(self, env)
        base = env.unwrapped
        if not isinstance(base, ConformalCrowdEnv):
            raise TypeError(
                "ConformalShield wraps a ConformalCrowd-v0 environment (it reads the robot's "
                f"sensor from it), got {type(base).__name__}"
            )
        core = base.core
        env_run = core.spec
        run = RunSpec.from_settings(
            {**env_run.params, **(params or {})}, base=spec, units=env_run.units, **settings
        )
        learn = run.learn
        fl = build_flagship(base.scene, dataclasses.replace(run, reference=GivenVelocity()))
        w = core.world
        if fl.env.tau_frames != w.tau_frames or fl.env.substeps != w.substeps:
            raise ValueError(
                "the shield must run at the environment's rate: its tau and substeps "
                f"({fl.env.tau_frames} frames, {fl.env.substeps}) differ from the "
                f"environment's ({w.tau_frames} frames, {w.substeps})"
            )
        self.filter = RecordingFilter(fl.safety_filter)
        fl.family.safety_filter = self.filter
        self.flagship = fl
        self.controller = fl.family
        self.constraint = fl.constraint
        self.active_tol = float(active_tol)
        self.stepper = ConformalStepper(fl.family, fl.loss, fl.rule, learn=learn)
        #: the last filtering problem (rows, lambda, result), the robot's state and the
        #: sensed agents' predicted positions and velocities at that instant
        self.last_: LastSolve | None = None
        self.last_state_: np.ndarray | None = None
        self.last_prediction_: tuple[np.ndarray, np.ndarray] | None = None
        self.last_ids_: np.ndarray | None = None  # the agents of the rows, in order

    def _begin(self, query: Any) -> None:
        self._ids = np.asarray(query.ids)
        self.stepper.begin_interval(query)

    @property
    def lam(self) -> float:
        """The shield's lambda now (1/s)."""
        return self.stepper.lam

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self.stepper.start()
        self.n_interventions_ = 0
        self.n_speed_clips_ = 0
        self.last_ = None
        core = self.env.unwrapped.core  # type: ignore[attr-defined]
        self._begin(core.query_[0])
        info = {
            **info,
            "shield_lambda": self.stepper.lam,
            "shield_interventions": 0,
            "shield_speed_clips": 0,
        }
        return obs, info

    def step(
        self, action: np.ndarray
    ) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        core = self.env.unwrapped.core  # type: ignore[attr-defined]
        a = np.asarray(action, dtype=float).reshape(-1)
        if a.shape != (2,) or not np.isfinite(a).all():
            raise ValueError(f"an action is a finite velocity (vx, vy) in m/s, got {action!r}")
        state = core.world.state(0)
        self.last_state_ = state.x.copy()
        ref = self.controller.reference
        assert isinstance(ref, GivenVelocity)
        ref.velocity = a
        lam = self.stepper.lam
        v = np.asarray(self.stepper.decide(state), dtype=float)
        last = self.filter.last_
        assert last is not None
        self.last_ = last
        rec = self.controller.interval_record()
        self.last_prediction_ = (rec.x_pred[-1].copy(), rec.v_pred[-1].copy())
        delta = float(np.hypot(*(v - a)))
        modified = delta > 1e-9
        res = last.result
        ids = self._ids
        self.last_ids_ = ids
        if last.A.shape[0]:
            slack = last.slack()
            active = ids[np.abs(slack) <= self.active_tol * max(1.0, abs(lam))]
            min_slack = float(slack.min())
        else:
            active, min_slack = ids[:0], math.inf  # no constraint: unbounded slack
        cause = _cause(modified, active.size > 0, res.fallback is not None)
        self.n_interventions_ += cause == "constraint"
        self.n_speed_clips_ += cause == "speed_limit"
        obs, reward, terminated, truncated, info = self.env.step(v)
        shield_loss = None
        if info.get("interval_closed"):
            shield_loss = self.stepper.end_interval(core.truth_[0]).loss
            if not (terminated or truncated) and not core.world.done:
                self._begin(core.query_[0])
        info = {
            **info,
            "shield_modified": modified,
            "shield_delta": delta,
            "shield_action": v,
            "shield_status": res.fallback or res.status,
            "shield_active": active.tolist(),
            "shield_n_constraints": int(last.A.shape[0]),
            "shield_min_slack": min_slack,
            "shield_lambda": lam,
            "shield_lambda_applied": res.lambda_applied,
            "shield_loss": shield_loss,
            "shield_cause": cause,
            "shield_interventions": int(self.n_interventions_),
            "shield_speed_clips": int(self.n_speed_clips_),
        }
        return obs, float(reward), terminated, truncated, info


def _cause(modified: bool, any_active: bool, fell_back: bool) -> str:
    """Why the shield changed an action: ``"none"``, ``"constraint"`` or ``"speed_limit"``.

    The filter returns the point of its speed set meeting the rows that is closest to the
    action. If no row binds there (and no fallback relaxed them), the rows' multipliers
    are zero and the same point is the closest point of the speed set alone: the change
    is the speed limit's, not the constraints'.
    """
    if not modified:
        return "none"
    return "constraint" if any_active or fell_back else "speed_limit"
