"""Check every run of a sweep before any starts.

A sweep of a hundred runs whose last grid value is a typo should not run ninety-nine of
them first. :func:`validate_runs` does, for every configuration, what a run does before
it simulates anything - load its scene, resolve its controller parameters against that
scene with :func:`conformal_control.runs.params.resolve_params` (the code the runs use),
look up its predictor and check the predictor's parameter names - and reports every
distinct problem in one sentence.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from .plan import SweepRun, invalid_runs_message

__all__ = ["SweepValidationError", "check_run", "validate_runs"]


class SweepValidationError(ValueError):
    """Some runs of a sweep cannot start; none was started.

    Attributes
    ----------
    problems : dict
        Each distinct problem (message) with the keys of the runs it affects.
    """

    def __init__(self, problems: dict[str, list[str]], total: int) -> None:
        self.problems = problems
        super().__init__(invalid_runs_message({m: len(k) for m, k in problems.items()}, total))


def _message(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if isinstance(exc, ValueError) and text:
        return text
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def check_run(cfg: SweepRun, scenes: dict[tuple[Any, ...], Any] | None = None) -> None:
    """Raise what the run ``cfg`` would raise before simulating anything.

    Parameters
    ----------
    cfg : SweepRun
    scenes : dict, optional
        Cache of loaded scenes (or the errors loading them) shared between calls.
    """
    from ..core import registry
    from ..runs.params import resolve_params
    from .worker import cached_scene

    scenes = {} if scenes is None else scenes
    # Parameters resolve against the scene's units, frame rate, defaults, radii and speed
    # bound; the seed only moves the built-in scene's pedestrians, so one load per scene.
    skey = (cfg.scene, cfg.data_root)
    if skey not in scenes:
        try:
            scenes[skey] = cached_scene(cfg.scene, cfg.data_root, 0)  # a serial sweep reuses it
        except Exception as exc:
            scenes[skey] = exc
    scene = scenes[skey]
    if isinstance(scene, BaseException):
        raise scene
    from ..runs.params import to_scene_units

    spec = cfg.spec
    given = to_scene_units(scene, dict(spec.params), spec.units)
    if not spec.learn:  # as run_episode does: the noLearn baseline keeps lambda fixed
        given.setdefault("eta", 0.0)
    resolve_params(scene, given)
    roles = ("predictor", "barrier", "safety_filter", "fallback", "reference", "dynamics", "loss")
    for role in roles:
        name, params = spec.role(role)
        if isinstance(name, str):
            cls = registry.get(role, name)
            registry.check_params(role, name, cls, dict(params))
    for role in ("family", "rule"):
        name = spec.role(role)[0]
        if isinstance(name, str):
            registry.get(role, name)


def validate_runs(configs: Sequence[SweepRun]) -> None:
    """Check every configuration; raise one :class:`SweepValidationError` for all problems.

    Scenes are loaded once per (scene, data root), through the worker's small scene cache
    (so a serial sweep, whose runs execute in this process, does not load them twice).
    """
    problems: dict[str, list[str]] = {}
    scenes: dict[tuple[Any, ...], Any] = {}
    for cfg in configs:
        try:
            check_run(cfg, scenes)
        except Exception as exc:  # whatever would stop the run before it simulates
            problems.setdefault(_message(exc), []).append(cfg.key)
    if problems:
        raise SweepValidationError(problems, len(configs))
