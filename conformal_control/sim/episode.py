"""One episode of the conformal CBF controller on a scene: build, run, measure.

The data flow of one interval, top to bottom (see :class:`~conformal_control.loop.ConformalLoop`):
sensor -> predictor -> per control instant: constraints from the barrier + lambda -> QP ->
double-integrator dynamics; at the next sampling time: truth -> loss -> lambda update.
Building is :func:`~conformal_control.sim.build.build_flagship`; measuring is
:func:`~conformal_control.sim.metrics.episode_metrics`.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..cbf.feasibility import feasibility_floor
from ..data.scene import Scene
from ..exceptions import (
    FeasibilityWarning,
    GoalNotReachedWarning,
    LambdaOverflowError,
    NoUpdatesWarning,
)
from ..loop import ConformalLoop, IntervalLog, LoopResult
from .build import Flagship, RoleSpec, build_flagship
from .collisions import account_collisions
from .metrics import EpisodeMetrics, episode_metrics

__all__ = ["EpisodeResult", "run_episode"]


@dataclass
class EpisodeResult:
    """Everything a run produced (what the run directory is written from).

    Attributes
    ----------
    scene : Scene
        The scene as run (with the resolved radii and v_max).
    config : dict
        The full configuration (written as ``config.json``).
    metrics : EpisodeMetrics
        Every metric with its unit (``metrics["t_goal"]`` works; ``metrics.format()``
        prints them).
    intervals : list of dict
        One row per interval (lambda in the scene's units, loss, diagnostics).
    trajectory : dict of arrays
        The robot per video frame (``frame, t, x, y, vx, vy, d_min``; m, s).
    steps : dict of arrays
        The robot per control instant (``t``, state ``x``, command ``cmd``).
    loop : LoopResult
    animation : dict or None
        The compact record ``conformal-control animate`` renders.
    """

    scene: Scene
    config: dict[str, Any]
    metrics: EpisodeMetrics
    intervals: list[dict[str, Any]]
    trajectory: dict[str, np.ndarray]
    steps: dict[str, np.ndarray] = field(default_factory=dict)
    loop: LoopResult | None = None
    animation: dict[str, Any] | None = None

    def plot(self, path: str | Path | None = None) -> Any:
        """The run figure (scene and path, lambda(t), loss(t), distances); saved if ``path``."""
        from ..plotting import plot_run

        fig = plot_run(self)
        if path is not None:
            fig.savefig(path, dpi=110)
        return fig

    def save(self, out: str | Path, *, plot: bool = True) -> Path:
        """Write the run directory (config, metrics, trace, intervals, trajectory, plots)."""
        from .rundir import write_run_dir

        return write_run_dir(self, out, plot=plot)


def run_episode(
    scene: Scene,
    predictor: RoleSpec = "constant_velocity",
    params: dict[str, Any] | None = None,
    *,
    units: str = "scene",
    learn: bool = True,
    max_frames: int | None = None,
    seed: int = 0,
    predictor_params: dict[str, Any] | None = None,
    extra_config: dict[str, Any] | None = None,
    rule: RoleSpec = "fixed_eta",
    rule_params: dict[str, Any] | None = None,
    lambda_safe: float | None = None,
    lambda_safe_source: str | None = None,
    barrier: RoleSpec = None,
    barrier_params: dict[str, Any] | None = None,
    safety_filter: RoleSpec = None,
    safety_filter_params: dict[str, Any] | None = None,
    fallback: RoleSpec = None,
    reference: RoleSpec = None,
    reference_params: dict[str, Any] | None = None,
    dynamics: RoleSpec = None,
    dynamics_params: dict[str, Any] | None = None,
    loss: RoleSpec = None,
    loss_params: dict[str, Any] | None = None,
    crowd: str = "replay",
    crowd_params: dict[str, Any] | None = None,
    family: str | None = None,
    family_params: dict[str, Any] | None = None,
    record_animation: bool = True,
    on_interval: Callable[[IntervalLog], None] | None = None,
    engine: str = "auto",
) -> EpisodeResult:
    """Run the conformal CBF controller on ``scene`` and measure it.

    Parameters
    ----------
    scene : Scene
    predictor : Predictor or str
        A predictor instance or a registered name (built with ``predictor_params``).
    params : dict
        Parameter overrides (see ``conformal-control params``), in the unit system
        ``units`` says.
    units : {"scene", "si"}
        ``"scene"``: dimensional parameters are typed in the scene's units (SDD: pixels and
        frames, the paper's); ``"si"``: in metres and seconds.
    learn : bool
        False runs the "noLearn" baseline: lambda stays at ``lambda_init`` (eta = 0).
    max_frames : int, optional
        Limit on simulated frames.
    seed : int
        Recorded in the config; named plugins with a ``random_state`` receive it.
    rule : str or UpdateRule
        A registered update rule built from the run's parameters and ``rule_params``
        (in ``units``; see :func:`~conformal_control.sim.build.build_rule`), or an instance
        (SI units, used as given).
    lambda_safe : float, optional
        lambda known or estimated to keep the robot safe (in ``units``): metrics then hold
        the Theorem-2 bound and the monitor's verdict (fixed-step rules).
    lambda_safe_source : str, optional
        Where ``lambda_safe`` came from (reported with the verdict; default "given").
    barrier, safety_filter, fallback, reference, dynamics, loss
        Each an instance, a registered name (built with the matching ``*_params``, SI
        units) or None for the flagship's default; see
        :func:`~conformal_control.sim.build.build_flagship`.
    crowd : str
        ``"replay"`` (default), ``"social_force"``, ``"orca"`` or ``"mixed"``: pedestrians
        who react to the robot, with ``crowd_params`` (SI; see
        :func:`~conformal_control.sim.reactive.make_environment`).
    family : str, optional
        A registered decision family built from the flagship's parts (default ``"cbf"``;
        ``"acp"``), with ``family_params``.
    record_animation : bool
        Keep the compact record ``conformal-control animate`` renders (``result.animation``,
        written as ``animation.npz``; see :mod:`conformal_control.sim.record`).
    on_interval : callable, optional
        Called with each scored :class:`~conformal_control.loop.IntervalLog` (progress).
    engine : {"auto", "loop", "batch"}
        How the episode is run. ``"loop"``: the generic
        :class:`~conformal_control.loop.ConformalLoop`, one chain of Python calls per
        control instant, for any configuration. ``"batch"``: the compiled engine of
        :mod:`~conformal_control.sim.batch` (one compiled call per interval), for the
        configurations :func:`~conformal_control.sim.batch.supports` accepts (the
        flagship's roles given by name, a replayed crowd, no ``on_interval``); raises
        ``ValueError`` with the reason otherwise. ``"auto"`` (default): the engine when it
        runs the configuration, else the loop. Both give the same result (metrics but
        ``wall_s``, intervals, trajectory, steps, animation record, to the last bit);
        ``config["engine"]`` says which ran.
    """
    if engine not in ("auto", "loop", "batch"):
        raise ValueError(f"engine must be 'auto', 'loop' or 'batch', got {engine!r}")
    if engine != "loop":
        from .batch import run_single  # imported here: the engine imports this module

        compiled = run_single(
            scene,
            engine,
            predictor=predictor,
            params=params,
            units=units,
            learn=learn,
            max_frames=max_frames,
            seed=seed,
            predictor_params=predictor_params,
            extra_config=extra_config,
            rule=rule,
            rule_params=rule_params,
            lambda_safe=lambda_safe,
            lambda_safe_source=lambda_safe_source,
            barrier=barrier,
            barrier_params=barrier_params,
            safety_filter=safety_filter,
            safety_filter_params=safety_filter_params,
            fallback=fallback,
            reference=reference,
            reference_params=reference_params,
            dynamics=dynamics,
            dynamics_params=dynamics_params,
            loss=loss,
            loss_params=loss_params,
            crowd=crowd,
            crowd_params=crowd_params,
            family=family,
            family_params=family_params,
            record_animation=record_animation,
            on_interval=on_interval,
        )
        if compiled is not None:
            return compiled
    fl = build_flagship(
        scene,
        params,
        units=units,
        predictor=predictor,
        predictor_params=predictor_params,
        barrier=barrier,
        barrier_params=barrier_params,
        safety_filter=safety_filter,
        safety_filter_params=safety_filter_params,
        fallback=fallback,
        reference=reference,
        reference_params=reference_params,
        dynamics=dynamics,
        dynamics_params=dynamics_params,
        loss=loss,
        loss_params=loss_params,
        rule=rule,
        rule_params=rule_params,
        crowd=crowd,
        crowd_params=crowd_params,
        family=family,
        family_params=family_params,
        learn=learn,
        seed=seed,
        max_frames=max_frames,
    )
    scene = fl.scene  # the copy carrying the resolved radii, v_max and goal radius
    si = fl.params.si
    lam_unit = scene.units.factor("lambda_init")
    if lambda_safe is not None and units == "si":
        lambda_safe = lambda_safe / lam_unit
    lam_safe_si = None if lambda_safe is None else float(lambda_safe) * lam_unit
    h_max = fl.barrier.upper_bound
    floor = feasibility_floor(
        si["a"], math.inf if h_max is None else h_max, si["epsilon"], si["loss_scale"]
    )
    _warn_before_run(fl, floor, learn)

    recorder = None
    if record_animation:
        from .record import AnimationRecorder

        recorder = AnimationRecorder(
            scene,
            fl.policy,
            fl.barrier,
            fl.params.tau_frames,
            si["substeps"],
            si["sensing_radius"],
        )

    def hooks(log: IntervalLog) -> None:
        _check_lambda(loop, fl, log)
        if recorder is not None:
            recorder(log)
        if on_interval is not None:
            on_interval(log)

    t0 = time.perf_counter()
    loop = ConformalLoop(
        fl.env,
        fl.policy,
        fl.loss,
        fl.rule,
        learn=learn,
        lambda_safe=lam_safe_si,
        lambda_safe_source=lambda_safe_source,
        on_interval=hooks,
    )
    result = loop.run()
    wall = time.perf_counter() - t0

    metrics, intervals, traj = _measure(fl, result, learn, lambda_safe, floor, wall)
    _warn_after_run(fl, metrics, learn, max_frames)
    config = _config(fl, rule_params, units, learn, lambda_safe, lambda_safe_source, seed)
    config["max_frames"] = max_frames
    config["feasibility"] = _jsonable(floor.as_dict())
    config.update(extra_config or {})
    env = fl.env
    steps = {
        "t": np.array(env.steps_t),
        "x": np.array(env.steps_x).reshape(-1, 4),
        "cmd": np.array(env.steps_cmd).reshape(-1, 2),
    }
    crowd_config = getattr(env, "crowd_config", None)
    config["crowd"] = crowd_config() if crowd_config is not None else {"crowd": "replay"}
    config["engine"] = "loop"
    simulated = getattr(env, "simulated_scene", None)
    animation = None
    if recorder is not None:
        if simulated is not None:  # draw the pedestrians the robot met, not the recording
            recorder.scene = simulated()
        animation = recorder.finish(
            traj, intervals, {"epsilon": si["epsilon"], "lambda_unit": metrics.unit("lambda_final")}
        )
    return EpisodeResult(scene, config, metrics, intervals, traj, steps, result, animation)


# ---------------------------------------------------------------------- warnings
# What makes a run probably not the one that was meant is reported with warnings.warn
# (conformal_control.exceptions); the CLI prints each as one line.
def _warn_before_run(fl: Flagship, floor: Any, learn: bool) -> None:
    """epsilon at or below the feasibility floor (known before the first step)."""
    if floor.attainable or not learn:
        return
    unit = f"1/{fl.scene.units.time_name}"
    lam_unit = fl.scene.units.factor("lambda_init")
    warnings.warn(
        FeasibilityWarning(
            f"epsilon={floor.epsilon:g} is not attainable: it is at or below the feasibility "
            f"floor s(-a*h_max)={floor.epsilon_floor:.4f} (lambda_floor="
            f"{floor.lambda_floor / lam_unit:g} {unit}), below which a far agent's constraint "
            "fails and the fallback decides; raise epsilon or a, or clip lambda with lambda_min"
        ),
        stacklevel=3,
    )


#: |lambda| (1/s) beyond which the constraint arithmetic (a h + lambda, summed over rows)
#: is no longer meaningful and soon overflows; no sensible run gets anywhere near it
LAMBDA_LIMIT = 1e150


def _check_lambda(loop: ConformalLoop, fl: Flagship, log: IntervalLog) -> None:
    """Stop with a clear error as soon as lambda leaves any meaningful range."""
    lam = loop.lam
    if math.isfinite(lam) and abs(lam) <= LAMBDA_LIMIT:
        return
    units = fl.scene.units
    lam_unit = units.factor("lambda_init")
    eta = fl.params.si["eta"] / lam_unit
    raise LambdaOverflowError(
        f"lambda overflowed: it reached {lam / lam_unit:.3g} 1/{units.time_name} after "
        f"update {log.k + 1}, beyond +-{LAMBDA_LIMIT / lam_unit:.0e} where the constraint "
        f"arithmetic overflows, because each update moves it by eta = {eta:g} "
        f"1/{units.time_name} times (epsilon - loss); use a far smaller eta or bound lambda "
        "with lambda_min / lambda_max"
    )


def _warn_after_run(
    fl: Flagship, metrics: EpisodeMetrics, learn: bool, max_frames: int | None
) -> None:
    """No lambda update at all (warning); the goal not reached because the data ended
    (warning) or because of the ``max_frames`` limit the caller set (logged)."""
    scene, si = fl.scene, fl.params.si
    if learn and metrics["n_updates"] == 0:
        warnings.warn(
            NoUpdatesWarning(
                f"lambda was never updated: no pedestrian came within the sensing radius "
                f"({si['sensing_radius']:.3g} m) at a sampling time, so the run did not "
                "learn (l_avg is undefined); check sensing_radius / rho0 and their unit"
            ),
            stacklevel=3,
        )
    if metrics["goal_reached"]:
        return
    frames = int(metrics["frames"])
    last_data = scene.first_frame + scene.n_frames - 1
    x = fl.env.log.state[-1][:2] if fl.env.log.state else scene.start
    gap = float(np.hypot(*(np.asarray(scene.goals[-1]) - np.asarray(x))))
    if max_frames is not None and frames >= max_frames:
        # the caller's limit ended the run (even if the data ends there too, as a benchmark
        # scenario's may): a diagnostic, not a warning
        logging.getLogger("conformal_control.run").info(
            "the goal was not reached within the frame limit of %d frames (%.1f s); the "
            "robot stopped %.1f m from it",
            max_frames,
            max_frames / scene.fps,
            gap,
        )
        return
    warnings.warn(
        GoalNotReachedWarning(
            f"the goal was not reached: the scene's data ended at frame {last_data} "
            f"({frames / scene.fps:.1f} s after the start) with the robot {gap:.1f} m "
            "from it; choose an earlier start frame or a closer goal",
            "data_ended",
        ),
        stacklevel=3,
    )


def _measure(
    fl: Flagship,
    result: LoopResult,
    learn: bool,
    lambda_safe: float | None,
    floor: Any,
    wall: float,
    positions: np.ndarray | None = None,
) -> tuple[EpisodeMetrics, list[dict[str, Any]], dict[str, np.ndarray]]:
    """The episode's metrics, interval rows and trajectory. ``positions``: the pedestrians
    the robot met (F, M, 2), when they are not the environment's (default: its simulated
    crowd, else the recording)."""
    env, scene, si = fl.env, fl.scene, fl.params.si
    units = scene.units
    lam_unit = units.factor("lambda_init")
    traj = env.log.arrays()
    updates = result.updates
    n_steps = max(fl.policy.n_steps_, 1)
    mon = result.monitor
    guarantee = mon.summary() if learn else {}
    losses_applied = [iv.diagnostics.get("loss_applied", math.nan) for iv in updates]
    tau_s = fl.params.tau_frames / scene.fps
    intervals = [
        {
            "k": iv.k,
            "t": iv.k * tau_s,
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
    filt = fl.safety_filter.stats()
    g = {
        k: guarantee.get(k)
        for k in (
            "guarantee",
            "lambda_safe_source",
            "theorem2_bound",
            "theorem2_bound_met",
            "theorem2_holds",
            "theorem2_verdict",
            "theorem2_premise_tested",
            "theorem2_premise_violations",
            "theorem2_assumption",
            "long_run_bound",
            "long_run_holds",
        )
    }
    if positions is None:
        positions = getattr(env, "simulated_scene", lambda: scene)().positions
    collisions = account_collisions(
        np.column_stack([traj["x"], traj["y"], traj["vx"], traj["vy"]]),
        traj["frame"] - scene.first_frame,
        positions,
        scene.agent_ids,
        fps=scene.fps,
        collision_distance=scene.collision_distance,
        sensing_radius=si["sensing_radius"],
        v_max=si["v_max"],
        sample_every=fl.params.tau_frames,
    )
    metrics = episode_metrics(
        trajectory=traj,
        collision_distance=scene.collision_distance,
        fps=scene.fps,
        t_goal=env.t_goal_,
        lambdas=result.lambdas,
        lam_unit=lam_unit,
        lam_unit_name=f"1/{units.time_name}",
        l_avg=mon.average if (learn and mon.n) else None,
        l_avg_applied=_nanmean(losses_applied) if learn else None,
        l_mean=mon.average if mon.n else None,
        epsilon=si["epsilon"],
        eta=si["eta"] / lam_unit if learn else 0.0,
        lambda_final=result.lambda_final / lam_unit,
        n_updates=result.n_updates if learn else 0,
        n_scored=result.n_updates,
        n_intervals=len(result.intervals),
        n_unscored=len(result.intervals) - result.n_updates,
        n_steps=fl.policy.n_steps_,
        n_infeasible=int(filt.get("n_infeasible", 0)),
        n_fallback=int(filt.get("n_fallback", 0)),
        fallback_share=filt.get("n_fallback", 0) / n_steps,
        n_qp_solves=int(filt.get("n_solves", 0)),
        n_lambda_clipped=fl.rule.n_clipped_,
        identity_residual=mon.identity_residual if learn else None,
        rule=fl.names["rule"],
        lambda_safe=lambda_safe,
        **g,
        lambda_floor=floor.lambda_floor / lam_unit,
        epsilon_floor=floor.epsilon_floor,
        epsilon_attainable=floor.attainable,
        n_nonfinite_predictions=fl.policy.n_nonfinite_predictions_,
        n_truth_missing=int(sum(iv.diagnostics.get("n_truth_missing", 0) for iv in updates)),
        predictor_info=dict(fl.policy.forecast_info_),
        wall_s=wall,
        **collisions.figures(),
        collision_events=[e.as_dict() for e in collisions.events],
    )
    return metrics, intervals, traj


def _nanmean(values: list[float]) -> float | None:
    """Mean of the finite values, None when there is none (a loss without diagnostics)."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else None


def _config(
    fl: Flagship,
    rule_params: dict[str, Any] | None,
    units: str,
    learn: bool,
    lambda_safe: float | None,
    lambda_safe_source: str | None,
    seed: int,
) -> dict[str, Any]:
    scene = fl.scene
    roles = _jsonable(fl.role_params())
    rule = roles.pop("rule")
    return {
        "version": __version__,
        "scene": {
            "name": scene.name,
            "fps": scene.fps,
            "start_frame": scene.start_frame,
            "start_m": scene.start.tolist(),
            "goals_m": scene.goals.tolist(),
            "units": scene.units.as_dict(),
            "n_agents": scene.n_agents,
            **{k: v for k, v in scene.meta.items() if isinstance(v, (str, int, float, list))},
        },
        **roles,
        "fallback": fl.names.get("fallback"),
        "learning": learn,
        "rule": {
            "name": rule["name"],
            "params_given": _jsonable(dict(rule_params or {})),
            "params_si": rule["params"],
        },
        "units_given": units,
        "lambda_safe": lambda_safe,
        "lambda_safe_source": lambda_safe_source,
        "seed": seed,
        "params": _jsonable(fl.params.as_dict()),
    }


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
