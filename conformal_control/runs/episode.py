"""One episode of the conformal CBF controller on a scene: build, run, measure.

The data flow of one interval, top to bottom (see
:class:`~conformal_control.core.loop.ConformalLoop`):
sensor -> predictor -> per control instant: constraints from the barrier + lambda -> QP ->
double-integrator dynamics; at the next sampling time: truth -> loss -> lambda update.
Building is :func:`~conformal_control.runs.build.build_flagship`; running is a backend
of :mod:`conformal_control.runs.engines`; measuring is
:mod:`conformal_control.runs.results.measure`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ..core.exceptions import InputError
from ..core.loop import IntervalLog
from ..core.spec import RunSpec
from ..data.scene import Scene
from .build import RoleSpec
from .engines.batch import as_run_spec, run_single
from .results.episode import EpisodeResult

__all__ = ["EpisodeResult", "run_episode"]


def run_episode(
    scene: Scene,
    spec: RunSpec | RoleSpec = None,
    params: dict[str, Any] | None = None,
    *,
    on_interval: Callable[[IntervalLog], None] | None = None,
    extra_config: dict[str, Any] | None = None,
    **settings: Any,
) -> EpisodeResult:
    """Run the conformal CBF controller on ``scene`` and measure it.

    Parameters
    ----------
    scene : Scene
    spec : RunSpec, Predictor or str
        The run (:class:`~conformal_control.core.spec.RunSpec`; the keyword settings below are
        applied on it), or its predictor: an instance or a registered name (built with
        ``predictor_params``).
    params : dict
        Parameter overrides (see ``conformal-control params``), in the unit system
        ``units`` says.
    on_interval : callable, optional
        Called with each scored :class:`~conformal_control.core.loop.IntervalLog` (progress).
    extra_config : dict, optional
        Merged into the result's configuration (``config.json``).
    **settings
        Settings of the run (:meth:`RunSpec.from_settings
        <conformal_control.core.spec.RunSpec.from_settings>`), as follows.

        - ``units`` ({"scene", "si"}):
          ``"scene"``: dimensional parameters are typed in the scene's units (SDD: pixels and
          frames, the paper's); ``"si"``: in metres and seconds.
        - ``learn`` (bool):
          False runs the "noLearn" baseline: lambda stays at ``lambda_init`` (eta = 0).
        - ``max_frames`` (int, optional):
          Limit on simulated frames.
        - ``seed`` (int):
          Recorded in the config; named plugins with a ``random_state`` receive it.
        - ``rule`` (str or UpdateRule):
          A registered update rule built from the run's parameters and ``rule_params``
          (in ``units``; see :func:`~conformal_control.runs.build.build_rule`), or an instance
          (SI units, used as given).
        - ``lambda_safe`` (float, optional):
          lambda known or estimated to keep the robot safe (in ``units``): metrics then hold
          the Theorem-2 bound and the monitor's verdict (fixed-step rules).
        - ``lambda_safe_source`` (str, optional):
          Where ``lambda_safe`` came from (reported with the verdict; default "given").
        - ``barrier``, ``safety_filter``, ``fallback``, ``reference``, ``dynamics``, ``loss``:
          Each an instance, a registered name (built with the matching ``*_params``, SI
          units) or None for the flagship's default; see
          :func:`~conformal_control.runs.build.build_flagship`.
        - ``crowd`` (str):
          ``"replay"`` (default), ``"social_force"``, ``"orca"`` or ``"mixed"``: pedestrians
          who react to the robot, with ``crowd_params`` (SI; see
          :func:`~conformal_control.world.reactive.make_environment`).
        - ``family`` (str, optional):
          A registered decision family built from the flagship's parts (default ``"cbf"``;
          ``"acp"``), with ``family_params``.
        - ``record_animation`` (bool):
          Keep the compact record ``conformal-control animate`` renders (``result.animation``,
          written as ``animation.npz``; see :mod:`conformal_control.runs.results.record`).
        - ``engine`` ({"auto", "loop", "batch"}):
          How the episode is run. ``"loop"``: the generic
          :class:`~conformal_control.core.loop.ConformalLoop`, one chain of Python calls per
          control instant, for any configuration. ``"batch"``: the compiled engine of
          :mod:`~conformal_control.runs.engines.batch` (one compiled call per interval), for the
          configurations :func:`~conformal_control.runs.engines.batch.supports` accepts (the
          flagship's roles given by name, a replayed crowd, no ``on_interval``); raises
          ``ValueError`` with the reason otherwise. ``"auto"`` (default): the engine when it
          runs the configuration, else the loop. Both give the same result (metrics but
          ``wall_s``, intervals, trajectory, steps, animation record, to the last bit);
          ``config["engine"]`` says which ran.

    Raises
    ------
    InputError
        For a run with a robots section (``robots=3``, ``starts=``, a
        :class:`~conformal_control.core.spec.RunSpec` read from a multi-robot ``config.json``):
        one robot runs here, several with :func:`~conformal_control.runs.fleet.run_multi`.
    """
    run = (
        spec
        if isinstance(spec, RunSpec) and params is None and not settings
        else as_run_spec(spec, params, **settings)
    )
    if run.robots is not None:  # one robot here: never drop the section silently
        given = run.robots.robots
        what = f"robots={given}" if given is not None else "a robots section"
        raise InputError(
            f"the run has {what}, and run() / run_episode drive one robot: run several with "
            "conformal_control.runs.fleet.run_multi(scene, spec) or "
            "`conformal-control run --robots`"
        )
    # the engine choice is run_single's, which conformal_control.run calls too
    return run_single(scene, run, on_interval=on_interval, extra_config=extra_config)
