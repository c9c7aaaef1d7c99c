"""Measuring an episode of the flagship: checks before and during the run, metrics and
intervals after it, and the configuration written as ``config.json``.

Every engine (:mod:`conformal_control.runs.engines`) measures with these functions, so the
metrics of an episode do not depend on the engine that ran it.
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ... import __version__
from ...core.exceptions import (
    FeasibilityWarning,
    GoalNotReachedWarning,
    LambdaOverflowError,
    NoUpdatesWarning,
)
from ...core.loop import LoopResult
from ...families.cbf.feasibility import feasibility_floor
from ...families.cbf.loss import CBFGapLoss
from ...families.cbf.safe_lambda import DerivedLambdaSafe, derive_lambda_safe
from .collisions import account_collisions
from .metrics import EpisodeMetrics, episode_metrics

if TYPE_CHECKING:
    from ...core.spec import RunSpec
    from ..build import Flagship

__all__ = [
    "LAMBDA_LIMIT",
    "check_lambda",
    "derived_lambda_safe",
    "episode_config",
    "feasibility",
    "jsonable",
    "lambda_safe_values",
    "measure",
    "warn_after_run",
    "warn_before_run",
]


def feasibility(fl: Flagship) -> Any:
    """The run's feasibility floor
    (:func:`~conformal_control.families.cbf.feasibility.feasibility_floor`
    of its ``a``, barrier bound, epsilon and loss scale)."""
    si = fl.params.si
    h_max = fl.barrier.upper_bound
    return feasibility_floor(
        si["a"], math.inf if h_max is None else h_max, si["epsilon"], si["loss_scale"]
    )


def lambda_unit(fl: Flagship) -> tuple[float, str]:
    """How lambda is reported: (SI value of one reported unit, its name). The CBF families'
    lambda is a rate, reported in the scene's time unit (1/frame on SDD); a family that
    declares ``lambda_unit`` in its capabilities (the MPC families: metres, or a level) is
    reported in it."""
    declared = fl.family.capabilities.lambda_unit
    if isinstance(declared, str):
        return 1.0, declared
    return fl.scene.units.factor("lambda_init"), f"1/{fl.scene.units.time_name}"


def lambda_safe_values(
    fl: Flagship, lambda_safe: float | str | None, units: str
) -> tuple[float | None, float | None]:
    """``lambda_safe`` given in ``units``: (in the scene's units, as reported; in SI).

    ``"auto"`` is derived from the built run (:func:`derived_lambda_safe`).
    """
    lam_unit = lambda_unit(fl)[0]
    if isinstance(lambda_safe, str):
        si = derived_lambda_safe(fl).value
        return si / lam_unit, si
    if lambda_safe is not None and units == "si":
        lambda_safe = lambda_safe / lam_unit
    return lambda_safe, None if lambda_safe is None else float(lambda_safe) * lam_unit


def derived_lambda_safe(fl: Flagship) -> DerivedLambdaSafe:
    """``lambda_safe="auto"`` for the built run ``fl`` (SI): the CBF gap loss's (or the
    shortfall loss's, with its own ``level``)
    :func:`~conformal_control.families.cbf.safe_lambda.derive_lambda_safe` with the run's
    constraint, loss scale and epsilon, the robot's speed bound (the radius of its speed
    set: ``v_max``, or ``sqrt(2) v_max`` for the box, ``speed_sides = 0``) and the assumed
    pedestrian speed bound
    (:data:`~conformal_control.families.cbf.safe_lambda.AGENT_SPEED_BOUND`).

    Raises
    ------
    ValueError
        When the run's loss is not the CBF gap loss or its barrier not the APF barrier.
    """
    loss = fl.loss
    if not isinstance(loss, CBFGapLoss):
        raise ValueError(
            f"lambda_safe='auto' is derived for the CBF gap loss only; this run's loss is "
            f"{type(loss).__name__}: give lambda_safe as a number"
        )
    si = fl.params.si
    v_max = float(si["v_max"])
    robot_speed = v_max if int(si.get("speed_sides", 16)) else math.sqrt(2.0) * v_max
    # the loss's own r_eps (CBFShortfallLoss: the same as the gap loss's for epsilon <= 0)
    level = loss.level(si["epsilon"])
    return derive_lambda_safe(loss.constraint, loss.scale, si["epsilon"], robot_speed, level=level)


# ---------------------------------------------------------------------- warnings
# What makes a run probably not the one that was meant is reported with warnings.warn
# (conformal_control.core.exceptions); the CLI prints each as one line.
def _clip_advice(fl: Flagship, floor: Any) -> tuple[str, bool | None]:
    """What to do about lambda sinking below the floor, given the run's ``lambda_min``:
    (advice, whether lambda_min keeps lambda above the floor; None when not given)."""
    unit = f"1/{fl.scene.units.time_name}"
    lam_unit = fl.scene.units.factor("lambda_init")
    lam_floor = floor.lambda_floor / lam_unit
    lam_min = float(fl.params.si.get("lambda_min", -math.inf))
    if not math.isfinite(lam_min):
        return "raise epsilon or a, or clip lambda with lambda_min above the floor", None
    given = lam_min / lam_unit
    if lam_min > floor.lambda_floor:
        return (
            f"lambda_min={given:g} {unit} keeps lambda above that floor, so l_avg cannot "
            "come down to epsilon",
            True,
        )
    return (
        f"lambda_min={given:g} {unit} is at or below the floor ({lam_floor:g} {unit}), so it "
        f"does not keep lambda above it: set lambda_min above {lam_floor:g} {unit}, or raise "
        "epsilon or a",
        False,
    )


def warn_before_run(fl: Flagship, floor: Any, learn: bool, stacklevel: int = 4) -> None:
    """Warn when epsilon is at or below the feasibility floor (known before the first step).

    Parameters
    ----------
    fl : Flagship
        The built episode.
    floor : Feasibility
        Its feasibility floor (:func:`feasibility`).
    learn : bool
        Whether lambda learns (no warning when it does not).
    stacklevel : int
        Frames up the warning points at (4: the caller of run_episode through run_loop).
    """
    if floor.attainable or not learn:
        return
    unit = f"1/{fl.scene.units.time_name}"
    lam_unit = fl.scene.units.factor("lambda_init")
    advice, _ = _clip_advice(fl, floor)
    warnings.warn(
        FeasibilityWarning(
            f"epsilon={floor.epsilon:g} is not attainable: it is at or below the feasibility "
            f"floor s(-a*h_max)={floor.epsilon_floor:.4f} (lambda_floor="
            f"{floor.lambda_floor / lam_unit:g} {unit}), below which a far agent's constraint "
            f"fails and the fallback decides; {advice}"
        ),
        stacklevel=stacklevel,
    )


@dataclass(frozen=True)
class _Floor:
    """The feasibility floor's lambda (SI), as :func:`_clip_advice` reads it."""

    lambda_floor: float


#: share of control instants decided by the fallback from which a missed goal is blamed on it
FALLBACK_SHARE_WARN = 0.25

#: |lambda| (1/s) beyond which the constraint arithmetic (a h + lambda, summed over rows)
#: is no longer meaningful and soon overflows; no sensible run gets anywhere near it
LAMBDA_LIMIT = 1e150


def check_lambda(lam: float, fl: Flagship, k: int) -> None:
    """Stop with a clear error as soon as lambda (SI, after update ``k``, counted from 0)
    leaves any meaningful range."""
    if math.isfinite(lam) and abs(lam) <= LAMBDA_LIMIT:
        return
    units = fl.scene.units
    lam_unit = units.factor("lambda_init")
    eta = fl.params.si["eta"] / lam_unit
    raise LambdaOverflowError(
        f"lambda overflowed: it reached {lam / lam_unit:.3g} 1/{units.time_name} after "
        f"update {k + 1}, beyond +-{LAMBDA_LIMIT / lam_unit:.0e} where the constraint "
        f"arithmetic overflows, because each update moves it by eta = {eta:g} "
        f"1/{units.time_name} times (epsilon - loss); use a far smaller eta or bound lambda "
        "with lambda_min / lambda_max"
    )


def warn_after_run(
    fl: Flagship,
    metrics: EpisodeMetrics,
    learn: bool,
    max_frames: int | None,
    stacklevel: int = 4,
) -> None:
    """No lambda update at all (warning); the goal not reached because the data ended
    (warning) or because of the ``max_frames`` limit the caller set (logged).

    Parameters
    ----------
    fl : Flagship
        The episode as built.
    metrics : EpisodeMetrics
        What it measured.
    learn : bool
        Whether lambda was learned.
    max_frames : int, optional
        The caller's frame limit.
    stacklevel : int
        Whom the warnings point at (default: the caller of ``run_episode`` through the
        loop backend).
    """
    scene, si = fl.scene, fl.params.si
    if learn and metrics["n_updates"] == 0:
        warnings.warn(
            NoUpdatesWarning(
                f"lambda was never updated: no pedestrian came within the sensing radius "
                f"({si['sensing_radius']:.3g} m) at a sampling time, so the run did not "
                "learn (l_avg is undefined); check sensing_radius / rho0 and their unit"
            ),
            stacklevel=stacklevel,
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
    share = float(metrics["fallback_share"] or 0.0)
    clipped: bool | None = None
    if learn and metrics["epsilon_attainable"] is False:
        lam_unit = scene.units.factor("lambda_init")
        floor = _Floor(float(metrics["lambda_floor"]) * lam_unit)
        clip, clipped = _clip_advice(fl, floor)
    if learn and metrics["epsilon_attainable"] is False and not clipped:
        advice = (
            f"epsilon={si['epsilon']:g} is below the feasibility floor, so lambda sank below "
            f"it and the fallback decided at {share:.0%} of the control instants (see the "
            f"warning before the run): {clip}"
        )
    elif share >= FALLBACK_SHARE_WARN:
        advice = (
            f"the fallback decided at {share:.0%} of the control instants (the constraints "
            "were infeasible there): a lambda_min, a larger a or another fallback keeps the "
            "safety filter in charge"
        )
    else:
        advice = "choose an earlier start frame (--start-frame) or a closer goal"
    warnings.warn(
        GoalNotReachedWarning(
            f"the goal was not reached: the scene's data ended at frame {last_data} "
            f"({frames / scene.fps:.1f} s after the start) with the robot {gap:.1f} m "
            f"from it; {advice}",
            "data_ended",
        ),
        stacklevel=stacklevel,
    )


def measure(
    fl: Flagship,
    result: LoopResult,
    learn: bool,
    lambda_safe: float | None,
    floor: Any,
    wall: float,
    positions: np.ndarray | None = None,
) -> tuple[EpisodeMetrics, list[dict[str, Any]], dict[str, np.ndarray]]:
    """The episode's metrics, interval rows and trajectory.

    Parameters
    ----------
    fl : Flagship
        The episode as built (its environment holds the frame log and the counters).
    result : LoopResult
        The loop's intervals, final lambda and monitor.
    learn : bool
        Whether lambda was learned.
    lambda_safe : float, optional
        The safe lambda given, in the scene's units.
    floor : FeasibilityFloor
        The run's feasibility floor (:func:`feasibility`).
    wall : float
        Wall time of the control loop (s).
    positions : ndarray of shape (F, M, 2), optional
        The pedestrians the robot met, when they are not the environment's (default: its
        simulated crowd, else the recording).

    Returns
    -------
    (EpisodeMetrics, list of dict, dict of arrays)
        Metrics, one row per interval, the per-frame trajectory.
    """
    env, scene, si = fl.env, fl.scene, fl.params.si
    lam_unit, lam_name = lambda_unit(fl)
    traj = env.log.arrays()
    updates = result.updates
    n_steps = max(fl.family.n_steps_, 1)
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
    filt = fl.family.stats()  # a CBF family's counters include its safety filter's
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
    frames = traj["frame"] - scene.first_frame
    ids = scene.agent_ids
    if positions is None:
        shown = getattr(env, "simulated_scene", lambda: scene)()
        # the frames of the episode and one on either side (the pedestrians' velocities),
        # the agents seen there: the rest of the scene does not take part
        lo = max(int(frames.min(initial=0)) - 1, 0)
        hi = min(int(frames.max(initial=0)) + 2, shown.n_frames)
        cols = shown.tracks.overlapping(lo, hi)
        positions, ids, frames = shown.tracks.dense(lo, hi, cols), ids[cols], frames - lo
    collisions = account_collisions(
        np.column_stack([traj["x"], traj["y"], traj["vx"], traj["vy"]]),
        frames,
        positions,
        ids,
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
        lam_unit_name=lam_name,
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
        n_steps=fl.family.n_steps_,
        n_infeasible=int(filt.get("n_infeasible", 0)),
        n_fallback=int(filt.get("n_fallback", 0)),
        fallback_share=filt.get("n_fallback", 0) / n_steps,
        n_qp_solves=int(filt.get("n_solves", 0)),
        n_lambda_clipped=mon.n_clipped,
        **(_agent_figures(guarantee) if "agent_n" in guarantee else {}),
        identity_residual=mon.identity_residual if learn else None,
        rule=fl.names["rule"],
        lambda_safe=lambda_safe,
        **g,
        lambda_floor=floor.lambda_floor / lam_unit,
        epsilon_floor=floor.epsilon_floor,
        epsilon_attainable=floor.attainable,
        n_nonfinite_predictions=fl.family.n_nonfinite_predictions_,
        n_truth_missing=int(sum(iv.diagnostics.get("n_truth_missing", 0) for iv in updates)),
        predictor_info=dict(fl.family.forecast_info_),
        wall_s=wall,
        **collisions.figures(),
        collision_events=[e.as_dict() for e in collisions.events],
    )
    return metrics, intervals, traj


#: The per-agent premise counts of the monitor's summary, as metrics (None without
#: lambda_safe).
_PREMISE_KEYS = (
    "n_agents_premise_tested",
    "n_agents_premise_failed",
    "n_premise_checks",
    "n_premise_exceeded",
    "n_agents_premise_exceeded",
)


def _agent_figures(guarantee: dict[str, Any]) -> dict[str, Any]:
    """The metrics of lambda run per agent, from the monitor's summary."""
    avg = np.asarray(guarantee["agent_l_avg"], dtype=float)
    return {
        "n_agents": guarantee["n_agents"],
        "n_agents_checked": guarantee["n_agents_checked"],
        "n_agents_bound_met": guarantee["n_agents_bound_met"],
        "agent_l_avg_median": float(np.median(avg)) if avg.size else None,
        "agent_l_avg_max": float(avg.max()) if avg.size else None,
        **{k: guarantee.get(k) for k in _PREMISE_KEYS},
        "agents": {
            "min_intervals": guarantee["agent_min_intervals"],
            "n": list(guarantee["agent_n"]),
            "l_avg": list(guarantee["agent_l_avg"]),
            "bound": list(guarantee["agent_bound"]),
        },
    }


def _nanmean(values: list[float]) -> float | None:
    """Mean of the finite values, None when there is none (a loss without diagnostics)."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else None


def episode_config(fl: Flagship, run: RunSpec, lambda_safe: float | None) -> dict[str, Any]:
    """``config.json`` of an episode of ``run`` built as ``fl`` (``lambda_safe`` in the
    scene's units): the scene, every role with its parameters, the parameters as given,
    as used and in SI, and the run specification itself (``spec``, what
    :meth:`RunSpec.from_dict <conformal_control.core.spec.RunSpec.from_dict>` reads back)."""
    scene = fl.scene
    rule_params = run.role("rule")[1]
    roles = jsonable(fl.role_params())
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
        "learning": run.learn,
        "rule": {
            "name": rule["name"],
            "params_given": jsonable(dict(rule_params or {})),
            "params_si": rule["params"],
        },
        "units_given": run.units,
        "lambda_safe": lambda_safe,
        "lambda_safe_source": run.lambda_safe_source,
        "seed": run.seed,
        "params": jsonable(fl.params.as_dict()),
        "max_frames": run.max_frames,
        "spec": jsonable(run.as_dict()),
    }


def jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return str(obj)
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if obj is None or isinstance(obj, (str, int, float, bool)):
        return obj
    return repr(obj)
