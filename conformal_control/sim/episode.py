"""One episode of the conformal CBF controller on a scene: build, run, measure.

The data flow of one interval, top to bottom (see :class:`~conformal_control.loop.ConformalLoop`):
sensor -> predictor -> per control instant: constraints from the barrier + lambda -> QP ->
double-integrator dynamics; at the next sampling time: truth -> loss -> lambda update.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import __version__, registry
from ..base import UpdateRule
from ..cbf import (
    APFBarrier,
    CBFGapLoss,
    ConformalCBFController,
    ConformalConstraint,
    QPSafetyFilter,
)
from ..cbf.dynamics import VelocityTrackingDoubleIntegrator
from ..cbf.feasibility import feasibility_floor
from ..cbf.reference import AttractiveField
from ..cbf.roles import Barrier
from ..data.scene import Scene
from ..loop import ConformalLoop, LoopResult
from ..predictors.base import Predictor
from ..update_rules import FixedEtaRule
from .config import ResolvedParams, resolve_params
from .environment import ReplayEnvironment

__all__ = ["EpisodeResult", "build_components", "run_episode"]


@dataclass
class EpisodeResult:
    """Everything a run produced (what the run directory is written from)."""

    scene: Scene
    config: dict[str, Any]
    metrics: dict[str, Any]
    intervals: list[dict[str, Any]]
    trajectory: dict[str, np.ndarray]
    steps: dict[str, np.ndarray] = field(default_factory=dict)
    loop: LoopResult | None = None
    animation: dict[str, Any] | None = None


@dataclass
class Components:
    env: ReplayEnvironment
    policy: ConformalCBFController
    loss: CBFGapLoss
    rule: UpdateRule
    barrier: Barrier
    safety_filter: QPSafetyFilter


def build_rule(
    name: str, rule_params: dict[str, Any] | None, params: ResolvedParams, lam_unit: float
) -> UpdateRule:
    """A registered update rule for the flagship, from the scene's parameters.

    The rule receives ``epsilon``, ``eta``, ``lambda_init``, ``lambda_min`` and
    ``lambda_max`` from the run's parameters (SI) for those of its constructor arguments
    with these names; ``rule_params`` (in the scene's units) override them and add the
    rule's own parameters. Parameters the rule declares in ``lambda_params`` (units of
    lambda, e.g. ``eta``, ``K_I``, ``gammas``) are converted with ``lam_unit``.
    """
    cls = registry.get("update_rule", name)
    accepted = set(cls._param_names())
    kwargs = {
        k: params.si[k]
        for k in ("epsilon", "eta", "lambda_init", "lambda_min", "lambda_max")
        if k in accepted
    }
    user = dict(rule_params or {})
    unknown = sorted(set(user) - accepted)
    if unknown:
        raise ValueError(
            f"update rule {name!r} has no parameter(s) {', '.join(unknown)}; "
            f"its parameters: {', '.join(sorted(accepted))}"
        )
    lam_params = set(getattr(cls, "lambda_params", ()))
    for k, v in user.items():
        if isinstance(v, str) and "," in v:  # a list from the command line: "0.1,1,10"
            v = [float(x) for x in v.split(",") if x.strip()]
        if k in lam_params and v is not None:
            v = [x * lam_unit for x in v] if isinstance(v, (list, tuple)) else v * lam_unit
        kwargs[k] = v
    return registry.create("update_rule", name, **kwargs)


def build_components(
    scene: Scene,
    params: ResolvedParams,
    predictor: Predictor,
    max_frames: int | None = None,
    rule: UpdateRule | None = None,
    barrier: Barrier | None = None,
) -> Components:
    """Wire barrier, QP, reference, controller, loss, rule and environment from SI params.

    ``rule`` defaults to the paper's :class:`FixedEtaRule` built from the parameters;
    ``barrier`` replaces the paper's APF barrier (built from the params) when given.
    """
    si = params.si
    # The environment reads radii and v_max from the scene: give it a copy carrying the
    # resolved values, never mutate the caller's scene (runs may share one in a process).
    scene = dataclasses.replace(
        scene,
        robot_radius=si["robot_radius"],
        agent_radius=si["agent_radius"],
        goal_radius=si["goal_radius"],
        v_max=si["v_max"],
    )
    if barrier is None:
        barrier = APFBarrier(
            K_rep=si["K_rep"],
            rho0=si["rho0"],
            d_c=si["robot_radius"] + si["agent_radius"],
            convention=si["convention"],
            delta=si["delta"],
        )
    safety_filter = QPSafetyFilter(
        v_max=si["v_max"], fallback=si["fallback"], speed_sides=si["speed_sides"]
    )
    reference = AttractiveField(K_att=si["K_att"], v_max=si["v_max"])
    constraint = ConformalConstraint(barrier, a=si["a"])
    policy = ConformalCBFController(
        predictor, constraint, safety_filter, reference, substeps=si["substeps"]
    )
    loss = CBFGapLoss(constraint, scale=si["loss_scale"])
    if rule is None:
        rule = FixedEtaRule(
            epsilon=si["epsilon"],
            eta=si["eta"],
            lambda_init=si["lambda_init"],
            lambda_min=si["lambda_min"],
            lambda_max=si["lambda_max"],
        )
    env = ReplayEnvironment(
        scene,
        VelocityTrackingDoubleIntegrator(K_acc=si["K_acc"]),
        tau_frames=params.tau_frames,
        substeps=si["substeps"],
        sensing_radius=si["sensing_radius"],
        history_frames=params.history_frames,
        max_frames=max_frames,
    )
    return Components(env, policy, loss, rule, barrier, safety_filter)


def _nan_to_none(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, np.floating):
        return _nan_to_none(float(x))
    if isinstance(x, np.integer):
        return int(x)
    return x


def run_episode(
    scene: Scene,
    predictor: Predictor | str = "constant_velocity",
    params: dict[str, Any] | None = None,
    *,
    learn: bool = True,
    max_frames: int | None = None,
    seed: int = 0,
    predictor_params: dict[str, Any] | None = None,
    extra_config: dict[str, Any] | None = None,
    rule: str | UpdateRule = "fixed_eta",
    rule_params: dict[str, Any] | None = None,
    lambda_safe: float | None = None,
    barrier: Barrier | str | None = None,
    barrier_params: dict[str, Any] | None = None,
    record_animation: bool = True,
) -> EpisodeResult:
    """Run the conformal CBF controller on ``scene`` and measure it.

    Parameters
    ----------
    scene : Scene
    predictor : Predictor or str
        A predictor instance or a registered name (built with ``predictor_params``).
    params : dict
        Parameter overrides in the scene's units (see ``sim.config.PARAMETERS``).
    learn : bool
        False runs the "noLearn" baseline: lambda stays at ``lambda_init`` (eta = 0).
    max_frames : int, optional
        Limit on simulated frames.
    seed : int
        Recorded in the config; stochastic predictors receive it as ``random_state``.
    rule : str or UpdateRule
        A registered update rule (``conformal-control plugins``) built from the run's
        parameters and ``rule_params`` (scene units; see :func:`build_rule`), or an
        instance (SI units, used as given).
    lambda_safe : float, optional
        lambda known or estimated to keep the robot safe (scene units): metrics then hold
        the Theorem-2 bound and whether it holds (fixed-step rules).
    barrier : Barrier or str, optional
        A barrier instance or a registered name (built with ``barrier_params``, SI units)
        replacing the paper's APF barrier. A named barrier whose constructor takes ``d_c``
        and is not given one receives the scene's collision distance
        (``robot_radius + agent_radius``, m). Recorded in the config with its parameters.
    record_animation : bool
        Keep the compact record ``conformal-control animate`` renders (``result.animation``,
        written as ``animation.npz``; see :mod:`conformal_control.sim.record`).
    """
    given = dict(params or {})
    if not learn:
        given.setdefault("eta", 0.0)
    resolved = resolve_params(scene, given)
    if isinstance(predictor, str):
        pp = dict(predictor_params or {})
        cls = registry.get("predictor", predictor)
        if "random_state" in cls._param_names() and "random_state" not in pp:
            pp["random_state"] = seed
        predictor_name, predictor = predictor, registry.create("predictor", predictor, **pp)
    else:
        predictor_name = type(predictor).__name__
    barrier_name = "apf"
    if isinstance(barrier, str):
        bp = dict(barrier_params or {})
        if "d_c" in registry.get("barrier", barrier)._param_names() and "d_c" not in bp:
            bp["d_c"] = resolved.si["robot_radius"] + resolved.si["agent_radius"]
        barrier_name, barrier = barrier, registry.create("barrier", barrier, **bp)
    elif barrier is not None:
        barrier_name = type(barrier).__name__
    lam_unit = scene.units.factor("lambda_init")
    if isinstance(rule, str):
        rule_name = rule
        rule_obj = build_rule(rule, rule_params, resolved, lam_unit)
    else:
        rule_name, rule_obj = type(rule).__name__, rule
    comp = build_components(scene, resolved, predictor, max_frames, rule=rule_obj, barrier=barrier)
    # from here on, the copy carrying the resolved radii, v_max and goal radius
    scene = comp.env.scene
    si = resolved.si
    lam_safe_si = None if lambda_safe is None else float(lambda_safe) * lam_unit
    h_max = comp.barrier.upper_bound
    floor = feasibility_floor(
        si["a"], math.inf if h_max is None else h_max, si["epsilon"], si["loss_scale"]
    )

    recorder = None
    if record_animation:
        from .record import AnimationRecorder

        recorder = AnimationRecorder(
            scene,
            comp.policy,
            comp.barrier,
            resolved.tau_frames,
            si["substeps"],
            si["sensing_radius"],
        )
    t0 = time.perf_counter()
    loop = ConformalLoop(
        comp.env,
        comp.policy,
        comp.loss,
        comp.rule,
        learn=learn,
        lambda_safe=lam_safe_si,
        on_interval=recorder,
    )
    result = loop.run()
    wall = time.perf_counter() - t0

    env = comp.env
    traj = env.log.arrays()
    d_c = scene.collision_distance
    units = scene.units
    updates = result.updates
    n_steps = max(comp.policy.n_steps_, 1)
    mon = result.monitor
    guarantee = mon.summary() if learn else {}
    losses_applied = [iv.diagnostics.get("loss_applied", math.nan) for iv in updates]
    d = traj["d_min"]
    intervals = [
        {
            "k": iv.k,
            "t": iv.k * resolved.tau_frames / scene.fps,
            "lambda": iv.lam / lam_unit,
            "loss": iv.loss,
            "loss_applied": iv.diagnostics.get("loss_applied"),
            "max_gap": (iv.diagnostics["max_gap"] / lam_unit)
            if "max_gap" in iv.diagnostics
            else None,
            "n_sensed": env.n_sensed_[iv.k] if iv.k < len(env.n_sensed_) else 0,
            "n_steps": iv.n_steps,
        }
        for iv in result.intervals
    ]
    metrics = {
        "t_goal": env.t_goal_,
        "goal_reached": env.goal_reached,
        "n_collide": int(np.sum(d < d_c)),
        "d_min": float(np.nanmin(d)) if np.isfinite(d).any() else None,
        "l_avg": mon.average if (learn and mon.n) else None,
        "l_avg_applied": float(np.nanmean(losses_applied)) if (learn and updates) else None,
        "l_mean": mon.average if mon.n else None,
        "epsilon": si["epsilon"],
        "eta": si["eta"] / lam_unit if learn else 0.0,
        "lambda_final": result.lambda_final / lam_unit,
        "n_updates": result.n_updates if learn else 0,
        "n_scored": result.n_updates,
        "n_intervals": len(result.intervals),
        "n_unscored": len(result.intervals) - result.n_updates,
        "n_steps": comp.policy.n_steps_,
        "n_infeasible": comp.safety_filter.n_infeasible_,
        "n_fallback": comp.safety_filter.n_fallback_,
        "fallback_share": comp.safety_filter.n_fallback_ / n_steps,
        "n_qp_solves": comp.safety_filter.n_solves_,
        "n_lambda_clipped": comp.rule.n_clipped_,
        "identity_residual": mon.identity_residual if learn else None,
        "rule": rule_name,
        "guarantee": guarantee.get("guarantee"),
        "lambda_safe": lambda_safe,
        "lambda_safe_source": guarantee.get("lambda_safe_source"),
        "theorem2_bound": guarantee.get("theorem2_bound"),
        "theorem2_bound_met": guarantee.get("theorem2_bound_met"),
        "theorem2_holds": guarantee.get("theorem2_holds"),
        "theorem2_verdict": guarantee.get("theorem2_verdict"),
        "theorem2_premise_tested": guarantee.get("theorem2_premise_tested"),
        "theorem2_premise_violations": guarantee.get("theorem2_premise_violations"),
        "theorem2_assumption": guarantee.get("theorem2_assumption"),
        "long_run_bound": guarantee.get("long_run_bound"),
        "long_run_holds": guarantee.get("long_run_holds"),
        "lambda_floor": floor.lambda_floor / lam_unit,
        "epsilon_floor": floor.epsilon_floor,
        "epsilon_attainable": floor.attainable,
        "n_nonfinite_predictions": comp.policy.n_nonfinite_predictions_,
        "n_truth_missing": int(sum(iv.diagnostics.get("n_truth_missing", 0) for iv in updates)),
        "predictor_info": dict(comp.policy.forecast_info_),
        "frames": len(traj["frame"]),
        "wall_s": wall,
        "units": {
            "lambda": f"1/{units.time_name}",
            "eta": f"1/{units.time_name}",
            "t": "s",
            "d": "m",
        },
    }
    metrics = {k: _nan_to_none(v) for k, v in metrics.items()}
    config = {
        "version": __version__,
        "scene": {
            "name": scene.name,
            "fps": scene.fps,
            "start_frame": scene.start_frame,
            "start_m": scene.start.tolist(),
            "goals_m": scene.goals.tolist(),
            "units": units.as_dict(),
            "n_agents": scene.n_agents,
            **{k: v for k, v in scene.meta.items() if isinstance(v, (str, int, float, list))},
        },
        "predictor": {"name": predictor_name, "params": _jsonable(predictor.get_params())},
        "barrier": {"name": barrier_name, "params": _jsonable(comp.barrier.get_params())},
        "learning": learn,
        "rule": {
            "name": rule_name,
            "params_given": _jsonable(dict(rule_params or {})),
            "params_si": _jsonable(comp.rule.get_params()),
        },
        "lambda_safe": lambda_safe,
        "seed": seed,
        "max_frames": max_frames,
        "params": _jsonable(resolved.as_dict()),
        "feasibility": _jsonable(floor.as_dict()),
        **(extra_config or {}),
    }
    steps = {
        "t": np.array(env.steps_t),
        "x": np.array(env.steps_x).reshape(-1, 4),
        "cmd": np.array(env.steps_cmd).reshape(-1, 2),
    }
    animation = None
    if recorder is not None:
        animation = recorder.finish(
            traj, intervals, {"epsilon": si["epsilon"], "lambda_unit": metrics["units"]["lambda"]}
        )
    return EpisodeResult(scene, config, metrics, intervals, traj, steps, result, animation)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return str(obj)
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if obj is None or isinstance(obj, (str, int, float, bool)):
        return obj
    return repr(obj)
