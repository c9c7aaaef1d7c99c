"""The front door: run the flagship on a scene in one call.

    >>> import conformal_control as cc
    >>> res = cc.run("crossing", epsilon=-0.1, eta=0.5, units="si", seed=0)  # doctest: +SKIP
    >>> print(res.metrics.format())                                      # doctest: +SKIP

Parameters with a unit (``eta``, ``tau``, ``a``, ``rho0``, ...) need an explicit unit
system when the scene's own is not SI: ``units="si"`` (metres, seconds) or
``units="scene"`` (the paper's pixels and frames for SDD scenes). On SI scenes (the
built-in ``crossing``) both mean the same. Everything else is
:func:`conformal_control.runs.episode.run_episode`.

:func:`shadow` (:func:`conformal_control.io.ros2.shadow.shadow`) runs the controller over a
robot's ROS 2 bag instead: the commands it would have sent.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .core.spec import RunSpec
from .io.ros2.shadow import shadow
from .runs.results.episode import EpisodeResult

__all__ = ["run", "shadow"]


def run(
    scene: Any = "crossing",
    spec: RunSpec | None = None,
    *,
    epsilon: float | None = None,
    eta: float | None = None,
    tau: float | None = None,
    params: dict[str, Any] | None = None,
    units: str | None = None,
    data_root: str | Path | None = None,
    start: Any = None,
    goal: Any = None,
    start_frame: int | None = None,
    progress: bool = False,
    extra_config: dict[str, Any] | None = None,
    **settings: Any,
) -> EpisodeResult:
    """Run the conformal CBF controller on a scene and return the result.

    Parameters
    ----------
    scene : str or Scene
        A registered scene name (``conformal-control scenes``), e.g. ``"crossing"`` (built
        in, no data), ``"nexus_4"``, ``"sdd:quad/video2"``, ``"ethucy:crowds_zara01"``; or a
        :class:`~conformal_control.data.scene.Scene`.
    spec : RunSpec, optional
        The run (:class:`~conformal_control.core.spec.RunSpec`); the arguments below are
        applied on it.
    epsilon, eta, tau : float, optional
        Target average loss, learning rate, sampling period (shortcuts for ``params``).
    params : dict, optional
        Any other parameter (``conformal-control params``).
    units : {"si", "scene"}, optional
        Unit system of the dimensional parameters; required when some are given and the
        scene's unit system is not SI.
    data_root : path, optional
        Data folder for scenes read from data (default ``$CONFORMAL_CONTROL_DATA``).
    start, goal : position, optional
        The robot's start and goal (``goal`` may be a list of waypoints) as fractions of
        the scene's frame (``(0.05, 0.5)``: the image on SDD scenes, the walkable box on
        ETH/UCY ones) or with a unit (``"3.2m,1.0m"``, ``"120px,300px"``); see
        :mod:`~conformal_control.data.positions`. None: the scene's own task.
    start_frame : int, optional
        The video frame the robot starts at (default: the scene's).
    progress : bool
        Show the episode's progress in frames (a bar on a terminal, lines in a log).
    extra_config : dict, optional
        Merged into the result's configuration (``config.json``): what the caller wants
        recorded beside the run (the command line records its options).
    **settings
        Any other setting of the run (:meth:`RunSpec.from_settings
        <conformal_control.core.spec.RunSpec.from_settings>`): ``start_m`` and ``goals_m``
        (the task in metres, as numbers), ``predictor`` (an instance or a registered
        name; default ``"constant_velocity"``; a trainable predictor given by name without
        ``weights`` is trained on the scene's data first, or its cached weights are used),
        ``learn`` (False keeps lambda fixed: the noLearn baseline), ``seed`` (of the
        built-in scene and of the plugins declaring it, ``run_values``), ``max_frames``,
        ``barrier``, ``safety_filter``, ``fallback``, ``reference``, ``dynamics``,
        ``loss``, ``rule`` (instances or names) and their ``*_params``, ``lambda_safe``,
        ``record_animation``, ``engine`` (``"auto"``: the compiled engine where it
        applies, ``"loop"``: the generic per-instant loop); and ``on_interval`` (a
        callback per interval).

    Returns
    -------
    EpisodeResult
        ``.metrics`` (with units), ``.intervals``, ``.trajectory``, ``.config``,
        ``.plot()``, ``.save(dir)``.

    Raises
    ------
    InputError
        For what one robot's run cannot honour: a robots section (``robots=3``,
        ``starts``/``goals``, a spec read from a multi-robot ``config.json``; run several
        with :func:`conformal_control.runs.fleet.run_multi`), checked before the scene is loaded.
    """
    from .core.progress import progress as progress_bar
    from .runs.engines.batch import run_single
    from .runs.prepare import prepare_run

    _check_keywords(settings)
    on_interval = settings.pop("on_interval", None)
    prepared = prepare_run(
        scene,
        spec,
        epsilon=epsilon,
        eta=eta,
        tau=tau,
        params=params,
        units=units,
        data_root=data_root,
        start=start,
        goal=goal,
        start_frame=start_frame,
        settings=settings,
    )
    scene, run_spec = prepared.scene, prepared.spec
    # the engine choice run_episode makes too (prepare_run refused a robots section); the
    # run's warnings point at this function's caller
    if not progress:
        return run_single(scene, run_spec, on_interval=on_interval, extra_config=extra_config)
    substeps = prepared.substeps
    bar = progress_bar(prepared.frames, prepared.label, "frames")
    steps = [0]  # control steps so far; the bar advances in whole frames

    def advance(iv: Any) -> None:
        before = -(-steps[0] // substeps)
        steps[0] += iv.n_steps
        if iv.l_avg is not None:
            bar.set_postfix(f"l_avg {iv.l_avg:+.3f}")
        bar.update(-(-steps[0] // substeps) - before)
        if on_interval is not None:
            on_interval(iv)

    with bar:
        return run_single(scene, run_spec, on_interval=advance, extra_config=extra_config)


def _check_keywords(kwargs: dict[str, Any]) -> None:
    """A keyword that is no setting of a run: a TypeError naming the closest keyword, or
    the ``params`` entry for a controller parameter."""
    import difflib
    import inspect

    from .core.spec import OPTION_FIELDS, PARAMETERS, ROBOT_FIELDS, ROLE_FIELDS

    own = [p for p in inspect.signature(run).parameters if p not in ("settings", "spec")]
    passed = [
        "on_interval",
        *ROLE_FIELDS,
        *(f"{r}_params" for r in ROLE_FIELDS),
        *OPTION_FIELDS,
        *ROBOT_FIELDS,
    ]
    for key, value in kwargs.items():
        if key in passed:
            continue
        if key in PARAMETERS:
            raise TypeError(
                f"run() takes the controller parameter {key!r} in params: "
                f"run(..., params={{{key!r}: {value!r}}})"
            )
        close = difflib.get_close_matches(key, [*own, *passed, *PARAMETERS], n=1, cutoff=0.6)
        if not close:
            hint = f"; its keywords are {', '.join([*own, *passed])}, parameters go in params="
        elif close[0] in PARAMETERS and close[0] not in own:
            hint = f"; did you mean params={{{close[0]!r}: {value!r}}}?"
        else:
            hint = f"; did you mean {close[0]}={value!r}?"
        raise TypeError(f"run() got an unexpected keyword argument {key!r}{hint}")
