"""A run as the front door receives it, made ready to run: the scene loaded (or the given
one with the start and goal asked for), the parameters in their unit system, the plugins
given by name checked, a trainable predictor's weights found or trained, in ONE call
(:func:`prepare_run`) that :func:`conformal_control.run` makes before it runs the episode.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..core.exceptions import InputError
from ..core.spec import PARAMETERS, ROBOT_FIELDS, RunSpec
from ..data.scene import Scene

__all__ = ["PreparedRun", "prepare_run"]


@dataclass(frozen=True)
class PreparedRun:
    """A run ready to run: its scene and its complete specification.

    Attributes
    ----------
    scene : Scene
        The scene, loaded, with the start and goal asked for.
    spec : RunSpec
        The run: the caller's settings and parameters applied, ``units`` decided, a
        trainable predictor's ``weights`` filled in.
    frames : int
        Frames the episode can run (its progress in frames runs up to it).
    substeps : int
        Control instants per frame (the run's, else the scene's, else the table's default).
    label : str
        What the progress display calls the run (``run <scene> [<predictor>]``).
    """

    scene: Scene
    spec: RunSpec
    frames: int
    substeps: int
    label: str


def prepare_run(
    scene: Any,
    spec: RunSpec | None,
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
    settings: dict[str, Any] | None = None,
) -> PreparedRun:
    """The run of :func:`conformal_control.run`'s arguments, ready to run.

    Parameters
    ----------
    scene : str or Scene
        A registered scene name or a scene.
    spec : RunSpec, optional
        The run the other arguments apply on.
    epsilon, eta, tau : float, optional
        Target average loss, learning rate, sampling period (shortcuts for ``params``).
    params : dict, optional
        Any other parameter.
    units : {"si", "scene"}, optional
        Unit system of the dimensional parameters (see :func:`conformal_control.run`).
    data_root : path, optional
        Data folder for scenes read from data.
    start, goal : position, optional
        The robot's start and goal (see :func:`conformal_control.run`).
    start_frame : int, optional
        The video frame the robot starts at.
    settings : dict, optional
        Any other setting of the run (:meth:`RunSpec.from_settings
        <conformal_control.core.spec.RunSpec.from_settings>`).

    Raises
    ------
    InputError
        For a robots section (one robot runs here), an unknown plugin name (before the
        scene is loaded), a spec that is no RunSpec.
    """
    from ..data import load_scene
    from ..data.units import PARAM_DIMENSIONS
    from ..predictors.training import with_weights

    settings = dict(settings or {})
    base = spec if spec is not None else RunSpec()
    if not isinstance(base, RunSpec):
        raise InputError(f"spec must be a RunSpec, got {type(base).__name__}")
    _refuse_robots(base, settings)
    seed = int(settings.get("seed", base.seed))
    # the settings applied once: the plugins they name are checked before the scene loads
    applied = RunSpec.from_settings(None, base=base, **settings) if settings else base
    _check_plugins(applied)
    if isinstance(scene, str):
        scene = load_scene(
            scene, data_root, start=start, goals=goal, start_frame=start_frame, seed=seed
        )
    elif start is not None or goal is not None:
        import numpy as np

        from ..data.positions import parse_positions, scene_position

        changes: dict[str, Any] = {}
        if start is not None:
            changes["start"] = scene_position(scene, start, "start")
        if goal is not None:
            goals = [scene_position(scene, g, "goal") for g in parse_positions(goal, "goal")]
            changes["goals"] = np.array(goals)
        scene = scene.replace(**changes)
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
    log = logging.getLogger("conformal_control.run")
    log.info(
        "scene %s: %d agents, %d frames at %g fps",
        scene.name,
        scene.n_agents,
        scene.n_frames,
        scene.fps,
    )
    run_spec = RunSpec.from_settings(given, base=applied, units=units)
    run_spec = with_weights(run_spec, scene, None if data_root is None else str(data_root))
    name, pp = run_spec.role("predictor")
    log.info("predictor %s with %s; rule %s", name, pp, run_spec.role_name("rule"))
    total = scene.n_frames - 1 - scene.start_index
    if run_spec.max_frames is not None:
        total = min(total, run_spec.max_frames)
    # control instants per frame: the run's, else the scene's, else the table's default
    default = scene.defaults.get("substeps", PARAMETERS["substeps"][0])
    substeps = int(run_spec.params.get("substeps", default))
    label = f"run {scene.name} [{run_spec.role_name('predictor')}]"
    return PreparedRun(scene, run_spec, total, substeps, label)


def _check_plugins(run: RunSpec) -> None:
    """Every role given by name is a registered plugin (an unknown name fails here, before
    the scene is loaded, with a did-you-mean)."""
    from ..core import registry

    roles = run.roles()
    order = ("predictor", "rule", "barrier", "safety_filter", "reference", "dynamics", "loss")
    for role in (*order, "family"):
        name = roles[role][0]
        if isinstance(name, str):
            registry.entry(role, name)


def _refuse_robots(spec: RunSpec, settings: dict[str, Any]) -> None:
    """One robot runs here: a robots section (in ``spec`` or the keywords) is refused, never
    dropped (``run("crossing", robots=3)`` used to run one robot without a word)."""
    given = [k for k in ROBOT_FIELDS if k in settings]
    if spec.robots is None and not given:
        return
    import reprlib

    short = reprlib.Repr()
    short.maxstring, short.maxother = 30, 30
    what = (
        ", ".join(f"{k}={short.repr(settings[k])}" for k in given)
        if given
        else f"a robots section (robots={spec.robots.robots if spec.robots else None})"
    )
    raise InputError(
        f"run() drives one robot and cannot honour {what}: run several with "
        "conformal_control.runs.fleet.run_multi(scene, ...) with the same arguments, or "
        "`conformal-control run --robots M`"
    )
