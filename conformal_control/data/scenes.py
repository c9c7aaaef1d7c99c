"""Scene registry: the paper's six SDD scenes, any SDD video by name, the built-in scene.

Scene names accepted by :func:`load_scene` and ``conformal-control run --scene``:

* ``crossing`` - the built-in synthetic scene (no data needed; SI units);
* ``gates_1``, ``nexus_4``, ``bookstore_0``, ``coupa_0``, ``hyang_1``, ``hyang_5`` - the
  paper's scenes with the reference code's start, goals, start frame and speed bound
  (SPEC section 2). nexus_4 is read from the raw annotations; the others exist here only
  in TrajNet form (re-linked and interpolated to 30 fps, see
  :mod:`conformal_control.data.trajnet`). Append ``:trajnet`` or ``:raw`` to force a form
  (e.g. ``nexus_4:trajnet``);
* ``sdd:<scene>/video<N>`` - any SDD video with raw annotations, start and goal given as
  image fractions.

Parameters of SDD scenes are typed in the paper's units (px, frames; see
:mod:`conformal_control.data.units`).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..exceptions import InputError
from .scene import Scene, scene_from_tracks
from .sdd import SDD_FPS, read_annotations, sdd_video
from .synthetic import crossing_scene
from .trajnet import read_trajnet
from .units import UnitSystem

__all__ = ["PAPER_SCENES", "TABLE_I", "TABLE_II", "SceneSpec", "load_scene", "scene_names"]

#: Parameters printed in the paper's Table I (gates_1), paper units.
TABLE_I: dict[str, float] = {
    "a": 0.1,
    "K_acc": 2.0,
    "K_rep": 20.0,
    "K_att": 1.0,
    "rho0": 400.0,
    "tau": 12,
    "eta": 100.0,
}
#: Parameters printed in the paper's Table II (nexus_4), paper units.
TABLE_II: dict[str, float] = {
    "a": 1.0,
    "K_acc": 2.0,
    "K_rep": 40.0,
    "K_att": 1.0,
    "rho0": 400.0,
    "tau": 4,
    "eta": 1.0,
    "epsilon": -0.25,
}
#: The published code hard-coded alpha(h) = 10 h whatever ``a`` said; our SDD defaults use
#: a = 10 so the defaults run as the published code did (SPEC "FEASIBILITY FLOOR").
PUBLISHED_A = 10.0


@dataclass(frozen=True)
class SceneSpec:
    """How to build one of the paper's scenes."""

    name: str
    sdd_scene: str
    video: int
    source: str  # "raw" or "trajnet"
    start: tuple[float, float]
    goals: tuple[tuple[float, float], ...]
    start_frame: int
    v_max: float
    defaults: dict[str, Any] = field(default_factory=dict)
    note: str = ""


def _defaults(table: dict[str, float], **extra: Any) -> dict[str, Any]:
    out: dict[str, Any] = {"epsilon": 0.0, **table, "a": PUBLISHED_A, "loss_scale": 1.0}
    out.update(extra)
    return out


PAPER_SCENES: dict[str, SceneSpec] = {
    s.name: s
    for s in [
        SceneSpec(
            "gates_1",
            "gates",
            1,
            "trajnet",
            (0.05, 0.60),
            ((0.95, 0.60),),
            0,
            4.0,
            _defaults(TABLE_I),
            "Table I scene",
        ),
        SceneSpec(
            "nexus_4",
            "nexus",
            4,
            "raw",
            (0.95, 0.55),
            ((0.10, 0.55),),
            50,
            6.0,
            _defaults(TABLE_II),
            "Table II scene",
        ),
        SceneSpec(
            "bookstore_0",
            "bookstore",
            0,
            "trajnet",
            (0.05, 0.52),
            ((0.95, 0.52),),
            9540,
            4.0,
            _defaults(TABLE_II),
        ),
        SceneSpec(
            "coupa_0",
            "coupa",
            0,
            "trajnet",
            (0.05, 0.125),
            ((0.95, 0.25), (0.05, 0.125)),
            1980,
            4.0,
            _defaults(TABLE_II),
        ),
        SceneSpec(
            "hyang_1",
            "hyang",
            1,
            "trajnet",
            (0.95, 0.48),
            ((0.05, 0.48), (0.95, 0.48)),
            12330,
            4.0,
            _defaults(TABLE_II),
        ),
        SceneSpec(
            "hyang_5",
            "hyang",
            5,
            "trajnet",
            (0.0, 0.5),
            ((0.95, 0.5), (0.0, 0.5)),
            3090,
            4.0,
            _defaults(TABLE_II),
        ),
    ]
}

_SDD_RE = re.compile(r"^sdd:(?P<scene>[A-Za-z]+)/video(?P<video>\d+)$")


def scene_names() -> list[str]:
    """Names of the registered scenes (``sdd:<scene>/video<N>`` works too)."""
    return ["crossing", *PAPER_SCENES]


def _fractions(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float).reshape(-1, 2)
    if not np.all(np.isfinite(arr)) or np.any(arr < 0) or np.any(arr > 1):
        raise ValueError(f"{what} must be image fractions in [0, 1], got {value!r}")
    return arr


def load_scene(
    name: str,
    data_root: str | os.PathLike[str] | None = None,
    *,
    start: tuple[float, float] | None = None,
    goals: list[tuple[float, float]] | None = None,
    start_frame: int | None = None,
    v_max: float | None = None,
    history_frames: int = 120,
    seed: int = 0,
) -> Scene:
    """Build a scene by name (see the module docstring for the accepted names).

    ``start`` and ``goals`` are fractions of the image's width and height (SDD scenes);
    they override the registry's values. ``seed`` only matters for ``crossing``.
    """
    if name == "crossing":
        if any(v is not None for v in (start, goals, start_frame)):
            raise ValueError("the built-in crossing scene has a fixed start, goal and frame")
        return crossing_scene(seed=seed)
    base, _, form = name.partition(":")
    spec: SceneSpec | None = None
    if name.startswith("sdd:"):
        m = _SDD_RE.match(name)
        if not m:
            raise ValueError(f"bad SDD scene name {name!r}; expected sdd:<scene>/video<N>")
        sdd_scene, video, source = m["scene"], int(m["video"]), "raw"
        defaults = _defaults(TABLE_II)
        spec_start, spec_goals, spec_frame, spec_vmax = (0.05, 0.5), ((0.95, 0.5),), 0, 4.0
        scene_name = f"{sdd_scene}_{video}"
    elif base in PAPER_SCENES:
        spec = PAPER_SCENES[base]
        if form not in ("", "raw", "trajnet"):
            raise ValueError(f"unknown form {form!r} in {name!r}; use :raw or :trajnet")
        sdd_scene, video, source = spec.sdd_scene, spec.video, form or spec.source
        defaults = dict(spec.defaults)
        spec_start, spec_goals, spec_frame, spec_vmax = (
            spec.start,
            spec.goals,
            spec.start_frame,
            spec.v_max,
        )
        scene_name = base if not form else f"{base}:{form}"
    else:
        import difflib

        close = difflib.get_close_matches(base, scene_names(), n=1, cutoff=0.6)
        hint = f" did you mean {close[0]!r}?" if close else ""
        raise InputError(
            f"unknown scene {name!r};{hint} known: {', '.join(scene_names())}, or "
            "sdd:<scene>/video<N> (see `conformal-control scenes`)"
        )
    vid = sdd_video(sdd_scene, video, data_root)
    if source == "raw":
        tracks = read_annotations(vid.annotations, vid.m_per_px)
    else:
        tracks = read_trajnet(vid.trajnet, vid.m_per_px)
    size_px = vid.image_size_px()
    if size_px is None:
        raise ValueError(
            f"{vid.image} is missing: the reference image gives the scene's size, which "
            "start and goal fractions refer to"
        )
    extent = (size_px[0] * vid.m_per_px, size_px[1] * vid.m_per_px)
    wh = np.array(extent)
    start_frac = _fractions(start if start is not None else spec_start, "start")[0]
    goal_frac = _fractions(goals if goals is not None else spec_goals, "goals")
    scene = scene_from_tracks(
        tracks,
        name=scene_name,
        start=start_frac * wh,
        goals=goal_frac * wh,
        start_frame=int(start_frame if start_frame is not None else spec_frame),
        v_max=float(v_max if v_max is not None else spec_vmax),
        history_frames=history_frames,
        units=UnitSystem(vid.m_per_px, 1.0 / SDD_FPS, "px", "frame"),
        defaults=defaults,
        extent=extent,
        image=vid.image,
    )
    scene.meta.update(
        {
            "sdd_scene": sdd_scene,
            "video": video,
            "form": source,
            "m_per_px": vid.m_per_px,
            "start_fraction": start_frac.tolist(),
            "goal_fractions": goal_frac.tolist(),
        }
    )
    return scene
