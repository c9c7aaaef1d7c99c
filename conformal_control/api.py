"""The front door: run the flagship on a scene in one call.

    >>> import conformal_control as cc
    >>> res = cc.run("crossing", epsilon=-0.1, eta=0.5, units="si", seed=0)  # doctest: +SKIP
    >>> print(res.metrics.format())                                      # doctest: +SKIP

Parameters with a unit (``eta``, ``tau``, ``a``, ``rho0``, ...) need an explicit unit
system when the scene's own is not SI: ``units="si"`` (metres, seconds) or
``units="scene"`` (the paper's pixels and frames for SDD scenes). On SI scenes (the
built-in ``crossing``) both mean the same. Everything else is
:func:`conformal_control.sim.run_episode`.

:func:`shadow` (:func:`conformal_control.ros2.shadow.shadow`) runs the controller over a
robot's ROS 2 bag instead: the commands it would have sent.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .results.episode import EpisodeResult
from .ros2.shadow import shadow
from .spec import RunSpec

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
    start: Sequence[float] | None = None,
    goal: Sequence[float] | None = None,
    **settings: Any,
) -> EpisodeResult:
    """Run the conformal CBF controller on a scene and return the result.

    Parameters
    ----------
    scene : str or Scene
        A registered scene name (``conformal-control scenes``), e.g. ``"crossing"`` (built
        in, no data), ``"nexus_4"``, ``"sdd:quad/video2"``; or a
        :class:`~conformal_control.data.scene.Scene`.
    spec : RunSpec, optional
        The run (:class:`~conformal_control.spec.RunSpec`); the arguments below are
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
    start, goal : (fx, fy), optional
        For ``sdd:`` scenes: start and goal as image fractions.
    **settings
        Any other setting of the run (:meth:`RunSpec.from_settings
        <conformal_control.spec.RunSpec.from_settings>`): ``predictor`` (an instance or a
        registered name; default ``"constant_velocity"``), ``learn`` (False keeps lambda
        fixed: the noLearn baseline), ``seed`` (of the built-in scene and of named plugins
        with a ``random_state``), ``max_frames``, ``barrier``, ``safety_filter``,
        ``fallback``, ``reference``, ``dynamics``, ``loss``, ``rule`` (instances or
        names) and their ``*_params``, ``lambda_safe``, ``record_animation``, ``engine``
        (``"auto"``: the compiled engine where it applies, ``"loop"``: the generic
        per-instant loop); and ``on_interval`` (a callback per interval).

    Returns
    -------
    EpisodeResult
        ``.metrics`` (with units), ``.intervals``, ``.trajectory``, ``.config``,
        ``.plot()``, ``.save(dir)``.
    """
    from .data import load_scene
    from .data.units import PARAM_DIMENSIONS
    from .sim.episode import run_episode

    _check_keywords(settings)
    on_interval = settings.pop("on_interval", None)
    base = spec if spec is not None else RunSpec()
    seed = int(settings.get("seed", base.seed))
    if isinstance(scene, str):
        goals = None if goal is None else [tuple(goal)]
        scene = load_scene(scene, data_root, start=start, goals=goals, seed=seed)
    given = dict(base.params)
    given.update(params or {})
    for name, value in (("epsilon", epsilon), ("eta", eta), ("tau", tau)):
        if value is not None:
            if name in given and given[name] != value:
                raise ValueError(f"{name} given twice with different values")
            given[name] = value
    dimensional = sorted(k for k in given if k in PARAM_DIMENSIONS)
    si_scene = scene.units.length == 1.0 and scene.units.time == 1.0
    if units is None:
        if spec is not None and "units" not in settings:
            units = spec.units
        elif dimensional and not si_scene:
            raise ValueError(
                f"parameter(s) {', '.join(dimensional)} have units and scene {scene.name} is "
                f"typed in {scene.units.length_name} and {scene.units.time_name}: pass "
                f"units='si' (m, s) or units='scene' ({scene.units.length_name}, "
                f"{scene.units.time_name})"
            )
        else:
            units = "si"
    settings["units"] = units
    return run_episode(scene, base, given, on_interval=on_interval, **settings)


def _check_keywords(kwargs: dict[str, Any]) -> None:
    """A keyword that is no setting of a run: a TypeError naming the closest keyword, or
    the ``params`` entry for a controller parameter."""
    import difflib
    import inspect

    from .spec import OPTION_FIELDS, PARAMETERS, ROBOT_FIELDS, ROLE_FIELDS

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
