"""Every scene name resolved in one place: recorded and built-in scenes
(:mod:`~conformal_control.data.scenes`) and the scenarios of the shipped benchmark suites
(:mod:`~conformal_control.data.suites`, ``scenario:<suite>/<id>``).

This module sits above both (a suite's scenario is read through the scene loader), so
neither of them needs the other's name resolution.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

from . import scenes
from .scene import Scene
from .suites import load_scenario, shipped_scenario

__all__ = ["load_scene"]


def load_scene(
    name: str,
    data_root: str | os.PathLike[str] | None = None,
    *,
    start: Sequence[float] | None = None,
    goals: Sequence[Sequence[float]] | None = None,
    start_frame: int | None = None,
    v_max: float | None = None,
    history_frames: int = 120,
    seed: int = 0,
    last_frame: int | None = None,
    start_m: Sequence[float] | None = None,
    goals_m: Sequence[Sequence[float]] | None = None,
) -> Scene:
    """Build a scene by name.

    Parameters
    ----------
    name : str
        ``scenario:<suite>/<id>`` is a scenario of a shipped benchmark suite (its time
        limit in ``scene.meta["max_frames"]``; the other arguments but ``data_root`` do not
        apply); every other name is one of :func:`conformal_control.data.scenes.load_scene`
        (``crossing``, a paper scene, ``sdd:<scene>/video<N>``, ``ethucy:<recording>``).
    data_root : path, optional
        Data folder (default ``$CONFORMAL_CONTROL_DATA``).
    start, goals, start_frame, v_max, history_frames, seed, last_frame, start_m, goals_m
        As in :func:`conformal_control.data.scenes.load_scene`.
    """
    if name.startswith("scenario:"):
        suite, _, sid = name[len("scenario:") :].partition("/")
        return load_scenario(shipped_scenario(suite, sid), data_root)
    return scenes.load_scene(
        name,
        data_root,
        start=start,
        goals=goals,
        start_frame=start_frame,
        v_max=v_max,
        history_frames=history_frames,
        seed=seed,
        last_frame=last_frame,
        start_m=start_m,
        goals_m=goals_m,
    )
