"""The generic backend: one episode as :class:`~conformal_control.core.loop.ConformalLoop` runs
it, one chain of Python calls per control instant, for any configuration."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core.loop import ConformalLoop, IntervalLog
from ..results.episode import EpisodeResult
from ..results.measure import (
    check_lambda,
    episode_config,
    feasibility,
    jsonable,
    lambda_safe_values,
    measure,
    warn_after_run,
    warn_before_run,
)
from ..results.record import AnimationRecorder

if TYPE_CHECKING:
    from ...core.spec import RunSpec
    from ..build import Flagship

__all__ = ["run_loop"]


def run_loop(
    fl: Flagship,
    run: RunSpec,
    *,
    on_interval: Callable[[IntervalLog], None] | None = None,
    extra_config: dict[str, Any] | None = None,
) -> EpisodeResult:
    """Run the built flagship ``fl`` of ``run`` through the generic loop and measure it.

    Parameters
    ----------
    fl : Flagship
        The wired episode (:func:`~conformal_control.runs.build.build_flagship`).
    run : RunSpec
        Its specification (options: ``learn``, ``lambda_safe``, ``record_animation``, ...).
    on_interval : callable, optional
        Called with each scored :class:`~conformal_control.core.loop.IntervalLog`.
    extra_config : dict, optional
        Merged into the configuration (``config.json``).
    """
    learn, max_frames = run.learn, run.max_frames
    scene = fl.scene  # the copy carrying the resolved radii, v_max and goal radius
    si = fl.params.si
    lambda_safe, lam_safe_si = lambda_safe_values(fl, run.lambda_safe, run.units)
    floor = feasibility(fl)
    warn_before_run(fl, floor, learn)

    recorder = None
    if run.record_animation:
        recorder = AnimationRecorder(
            scene,
            fl.family,
            fl.barrier,
            fl.params.tau_frames,
            si["substeps"],
            si["sensing_radius"],
        )

    def hooks(log: IntervalLog) -> None:
        check_lambda(loop.lam_extreme, fl, log.k)
        if recorder is not None:
            recorder(log)
        if on_interval is not None:
            on_interval(log)

    t0 = time.perf_counter()
    loop = ConformalLoop(
        fl.env,
        fl.family,
        fl.loss,
        fl.rule,
        learn=learn,
        lambda_safe=lam_safe_si,
        lambda_safe_source=run.lambda_safe_source,
        on_interval=hooks,
        lambda_per=si["lambda_per"],
        lambda_prior=si["lambda_prior"],
        lambda_floor_row=si["lambda_floor_row"],
    )
    result = loop.run()
    wall = time.perf_counter() - t0

    metrics, intervals, traj = measure(fl, result, learn, lambda_safe, floor, wall)
    warn_after_run(fl, metrics, learn, max_frames)
    config = episode_config(fl, run, lambda_safe)
    config["feasibility"] = jsonable(floor.as_dict())
    config.update(extra_config or {})
    env = fl.env
    steps = {
        "t": np.array(env.steps_t),
        "x": np.array([x[:4] for x in env.steps_x]).reshape(-1, 4),
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
