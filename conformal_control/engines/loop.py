"""The generic backend: one episode as :class:`~conformal_control.loop.ConformalLoop` runs
it, one chain of Python calls per control instant, for any configuration."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from ..loop import ConformalLoop, IntervalLog
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
    from ..flagship.build import Flagship

__all__ = ["run_loop"]


def run_loop(
    fl: Flagship,
    *,
    learn: bool = True,
    units: str = "scene",
    seed: int = 0,
    max_frames: int | None = None,
    lambda_safe: float | None = None,
    lambda_safe_source: str | None = None,
    rule_params: dict[str, Any] | None = None,
    extra_config: dict[str, Any] | None = None,
    record_animation: bool = True,
    on_interval: Callable[[IntervalLog], None] | None = None,
) -> EpisodeResult:
    """Run the built flagship ``fl`` through the generic loop and measure it.

    Parameters
    ----------
    fl : Flagship
        The wired episode (:func:`~conformal_control.flagship.build.build_flagship`).
    learn, units, seed, max_frames, lambda_safe, lambda_safe_source, rule_params
        As given to :func:`~conformal_control.sim.run_episode` (recorded in the config;
        ``lambda_safe`` in ``units``).
    extra_config : dict, optional
        Merged into the configuration (``config.json``).
    record_animation : bool
        Keep the compact record ``conformal-control animate`` renders.
    on_interval : callable, optional
        Called with each scored :class:`~conformal_control.loop.IntervalLog`.
    """
    scene = fl.scene  # the copy carrying the resolved radii, v_max and goal radius
    si = fl.params.si
    lambda_safe, lam_safe_si = lambda_safe_values(fl, lambda_safe, units)
    floor = feasibility(fl)
    warn_before_run(fl, floor, learn)

    recorder = None
    if record_animation:
        recorder = AnimationRecorder(
            scene,
            fl.policy,
            fl.barrier,
            fl.params.tau_frames,
            si["substeps"],
            si["sensing_radius"],
        )

    def hooks(log: IntervalLog) -> None:
        check_lambda(loop.lam, fl, log.k)
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

    metrics, intervals, traj = measure(fl, result, learn, lambda_safe, floor, wall)
    warn_after_run(fl, metrics, learn, max_frames)
    config = episode_config(fl, rule_params, units, learn, lambda_safe, lambda_safe_source, seed)
    config["max_frames"] = max_frames
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
