"""The generic backend: one episode as :class:`~conformal_control.core.loop.ConformalLoop` runs
it, one chain of Python calls per control instant, for any configuration."""

from __future__ import annotations

import time
from collections.abc import Callable, Generator
from typing import TYPE_CHECKING, Any, cast

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

__all__ = ["loop_steps", "run_loop"]


def run_loop(
    fl: Flagship,
    run: RunSpec,
    *,
    on_interval: Callable[[IntervalLog], None] | None = None,
    extra_config: dict[str, Any] | None = None,
    stacklevel: int = 5,
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
    stacklevel : int
        Frames up the run's warnings point at: 5, the caller of this function's caller
        (:func:`~conformal_control.runs.engines.batch.run_single` passes 6: the caller of
        ``run_episode`` or ``conformal_control.run``).
    """
    steps = loop_steps(
        fl, run, on_interval=on_interval, extra_config=extra_config, stacklevel=stacklevel
    )
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return cast(EpisodeResult, done.value)


def loop_steps(
    fl: Flagship,
    run: RunSpec,
    *,
    on_interval: Callable[[IntervalLog], None] | None = None,
    extra_config: dict[str, Any] | None = None,
    pause: Callable[[Any], bool] | bool = False,
    stacklevel: int = 5,
) -> Generator[tuple[Any, Any, Any], float, EpisodeResult]:
    """:func:`run_loop` as a generator, so that several episodes can advance together (the
    lockstep MPC runs of :mod:`~conformal_control.runs.engines.mpc_batch`): before a control
    instant at which ``pause(family)`` is true (``pause=True``: every instant) it yields
    ``(family, state, lam)`` -- the state and lambda the family then decides with -- and
    receives the seconds of work done for it meanwhile (its share of a joint plan, counted
    in its ``wall_s``); it returns what :func:`run_loop` returns. The loop is
    :meth:`ConformalLoop.run <conformal_control.core.loop.ConformalLoop.run>`'s, one call at a
    time.

    Parameters
    ----------
    fl : Flagship
        The wired episode.
    run : RunSpec
        Its specification.
    on_interval : callable, optional
        Called with each scored interval.
    extra_config : dict, optional
        Merged into the configuration.
    pause : callable or bool
        Whether to yield before the family decides (called with the family).
    stacklevel : int
        Frames up the run's warnings point at (5: the caller of :func:`run_loop`'s caller).
    """
    learn, max_frames = run.learn, run.max_frames
    scene = fl.scene  # the copy carrying the resolved radii, v_max and goal radius
    si = fl.params.si
    lambda_safe, lam_safe_si = lambda_safe_values(fl, run.lambda_safe, run.units)
    floor = feasibility(fl)
    warn_before_run(fl, floor, learn, stacklevel=stacklevel)

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

    wants = pause if callable(pause) else (lambda _family: bool(pause))
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
        lambda_floor_step=si["lambda_floor_step"],
        lambda_floor_limit=si["lambda_floor_limit"],
    )
    # ConformalLoop.run, one control instant at a time
    env, family, away = loop.env, loop.family, 0.0
    env.reset()
    loop.start()
    while not env.done:
        loop.begin_interval(env.sense())
        for _ in range(env.control_instants()):
            state = env.state()
            if wants(family):
                lams = loop.lams
                t1 = time.perf_counter()
                share = yield family, state, (loop.lam if lams is None else lams)
                away += time.perf_counter() - t1 - share
            env.apply(loop.decide(state))
            if env.done:
                break
        loop.end_interval(env.reveal())
    result = loop.result()
    wall = time.perf_counter() - t0 - away

    metrics, intervals, traj = measure(fl, result, learn, lambda_safe, floor, wall)
    warn_after_run(fl, metrics, learn, max_frames, stacklevel=stacklevel)
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
