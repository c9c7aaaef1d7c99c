"""Scene registry: the paper's six SDD scenes, any SDD video by name, the built-in scene.

Scene names accepted by :func:`load_scene` and ``conformal-control run --scene``:

* ``crossing`` - the built-in synthetic scene (no data needed; SI units);
* ``gates_1``, ``nexus_4``, ``bookstore_0``, ``coupa_0``, ``hyang_1``, ``hyang_5`` - the
  paper's scenes with the start, goals, start frame and speed bound of the published code's
  per-scene files. nexus_4 is read from the raw annotations; the others exist here only
  in TrajNet form (re-linked and interpolated to 30 fps, see
  :mod:`conformal_control.data.trajnet`). Append ``:trajnet`` or ``:raw`` to force a form
  (e.g. ``nexus_4:trajnet``);
* ``sdd:<scene>/video<N>`` - any SDD video with raw annotations, start and goal given as
  image fractions; ``sdd:<scene>/video<N>:trajnet`` reads the video's TrajNet file instead
  (re-linked and interpolated to 30 fps);
* ``ethucy:<recording>`` - a full ETH/UCY recording (``biwi_eth``, ``biwi_hotel``,
  ``students001``, ``students003``, ``crowds_zara01``, ``crowds_zara02``), interpolated
  from 2.5 to 30 fps (:func:`conformal_control.data.ethucy.read_ethucy`). These
  recordings are in world metres without an image; their frame is the **walkable box**
  (:func:`walkable_box`: the box holding the middle 95 % of the recorded positions along
  each axis), and their **default task** crosses it along its longer side, from 5 % to
  95 % of that side on the box's middle line (:data:`ETHUCY_TASK`), starting one history
  window (120 frames, 4 s) after the recording's first frame.
  ``ethucy:<recording>:corrected`` replays the recording on
  its original clock: biwi_eth's rows are 0.667 s apart, not the literature's 0.4 s
  (:data:`conformal_control.data.ethucy.ETHUCY_ORIGINAL_RATE`); the other recordings are the
  same in both forms. The corrected biwi_eth scene is named ``biwi_eth:corrected``. The
  names of the leave-one-out splits (``ethucy:zara1``, ...) are aliases of their recording,
  resolved by :mod:`~conformal_control.data.catalog`.

Starts and goals are positions as :mod:`~conformal_control.data.positions` reads them:
fractions of the scene's frame (the image on SDD, the walkable box on ETH/UCY), metres
(``"3.2m,1.0m"``) or pixels (``"120px,300px"``, SDD).

Parameters of SDD scenes are typed in the paper's units (px, frames; see
:mod:`conformal_control.data.units`). ETH/UCY scenes are typed in metres and frames of
1/30 s, with the SDD defaults' lengths converted at :data:`REFERENCE_M_PER_PX` (see
:data:`ETHUCY_DEFAULTS`), so that one set of numbers means the same robot on both.

Defaults: the paper's scenes carry the paper's parameters (Table I/II, a = 10 per frame as
the published code ran). Every other scene carries the same parameters except the barrier
(a and K_rep, :data:`CROWD_A_SI` and :data:`CROWD_K_REP_SI`) and epsilon
(:data:`CROWD_EPSILON`), chosen on the benchmark's dev split;
``scene.meta["published_params"]`` holds the paper's for comparison.
"""

from __future__ import annotations

import functools
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.exceptions import InputError
from .ethucy import (
    ETHUCY_FPS,
    ETHUCY_ORIGINAL_RATE,
    ETHUCY_RECORDINGS,
    ethucy_recording,
    read_ethucy,
)
from .positions import Position, parse_position, parse_positions, to_metres
from .scene import Scene, scene_from_tracks
from .sdd import SDD_FPS, read_annotations, sdd_video
from .synthetic import crossing_scene
from .track_cache import cached_tracks
from .tracks import Tracks
from .trajnet import read_trajnet
from .units import UnitSystem

__all__ = [
    "CROWD_A_SI",
    "CROWD_EPSILON",
    "CROWD_K_REP_SI",
    "ETHUCY_DEFAULTS",
    "ETHUCY_PUBLISHED",
    "ETHUCY_TASK",
    "PAPER_SCENES",
    "REFERENCE_M_PER_PX",
    "TABLE_I",
    "TABLE_II",
    "WALKABLE_QUANTILE",
    "SceneSpec",
    "crowd_defaults",
    "load_scene",
    "read_tracks",
    "scene_names",
    "walkable_box",
]

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
#: a = 10 so the defaults run as the published code did. With the printed a = 1 lambda
#: cannot go below -a h_max = -1/2 per frame (a far agent's row), which leaves epsilon =
#: -0.25 out of reach (see :mod:`conformal_control.experiments.reproduce.paper`).
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

#: Metres per "pixel" used to carry the SDD defaults' lengths to scenes without pixels: a
#: typical SDD scale (the median over the 60 videos of ``estimated_scales.yaml`` is
#: 0.0397 m/px), rounded.
REFERENCE_M_PER_PX = 0.04
#: Default parameters of ETH/UCY scenes (lengths in m, times in frames of 1/30 s): the SDD
#: defaults (Table II, a = 10 per frame) with rho0 and K_rep converted at
#: :data:`REFERENCE_M_PER_PX`.
ETHUCY_DEFAULTS: dict[str, Any] = {
    **_defaults(TABLE_II),
    "rho0": TABLE_II["rho0"] * REFERENCE_M_PER_PX,
    "K_rep": TABLE_II["K_rep"] * REFERENCE_M_PER_PX**2,
}
#: The paper-equivalent ETH/UCY parameters (as :data:`ETHUCY_DEFAULTS` was before the
#: crowd defaults were tuned); what the benchmark suite's ``nolearn`` record was run with.
ETHUCY_PUBLISHED: dict[str, Any] = dict(ETHUCY_DEFAULTS)

#: Barrier defaults of every scene that is not one of the paper's (``sdd:...``,
#: ``ethucy:...`` and benchmark scenarios), in SI: class-K slope a (1/s) and APF gain
#: K_rep (m^2). Chosen on the ``dev`` split of the ``crossings-v1`` benchmark suite (66
#: scenarios, noLearn and the conformal controller over K_rep in {0.05, 0.2} m^2 and a in
#: {100, 300} 1/s): against the published barrier (a = 10 per frame = 300/s, K_rep = 40 px^2
#: = 0.03-0.06 m^2) they cut collision frames by two thirds and raise the success rate
#: (the Benchmark page of the docs has the figures). The paper's scenes keep the paper's
#: parameters so that ``reproduce`` reproduces it.
CROWD_A_SI = 100.0
CROWD_K_REP_SI = 0.2
#: epsilon of the same scenes: on dev every epsilon in [-0.05, 0.02] gave the same success
#: and collision frames within noise (-0.1 and below cost collisions at this barrier);
#: -0.05 keeps lambda visibly working (mean about -5/s) at no measured cost.
CROWD_EPSILON = -0.05


def crowd_defaults(m_per_unit: float, fps: float, base: dict[str, Any]) -> dict[str, Any]:
    """``base`` (scene units) with :data:`CROWD_EPSILON`, and :data:`CROWD_A_SI` and
    :data:`CROWD_K_REP_SI` converted
    to a scene whose length unit is ``m_per_unit`` metres and whose time unit is a frame
    of ``1 / fps`` seconds."""
    out = dict(base)
    out["a"] = CROWD_A_SI / fps
    out["K_rep"] = CROWD_K_REP_SI / m_per_unit**2
    out["epsilon"] = CROWD_EPSILON
    return out


ETHUCY_DEFAULTS = crowd_defaults(1.0, 30.0, ETHUCY_PUBLISHED)

#: Frame rate ETH/UCY recordings are interpolated to (the SDD frame rate).
ETHUCY_SCENE_FPS = SDD_FPS

_SDD_RE = re.compile(r"^sdd:(?P<scene>[A-Za-z]+)/video(?P<video>\d+)(?::(?P<form>raw|trajnet))?$")
_ETHUCY_RE = re.compile(r"^ethucy:(?P<stem>\w+)(?P<corrected>:corrected)?$")


def scene_names() -> list[str]:
    """Names of the registered scenes (``sdd:<scene>/video<N>`` and ``ethucy:<recording>``
    work too)."""
    return ["crossing", *PAPER_SCENES]


@functools.lru_cache(maxsize=8)
def _read_tracks_cached(
    kind: str,
    path: str,
    m_per_px: float,
    fps: float | None,
    _stamp: tuple[int, int],
    rate: float = ETHUCY_FPS,
) -> Tracks:
    def read() -> Tracks:
        if kind == "raw":
            return read_annotations(path, m_per_px)
        if kind == "trajnet":
            return read_trajnet(path, m_per_px)
        return read_ethucy(path, fps=fps, rate=rate)

    return cached_tracks(kind, path, {"m_per_px": m_per_px, "fps": fps, "rate": rate}, read)


def read_tracks(
    kind: str,
    path: str | os.PathLike[str],
    m_per_px: float = 1.0,
    fps: float | None = None,
    rate: float = ETHUCY_FPS,
) -> Tracks:
    """Tracks of a recording (``kind``: ``raw`` SDD, ``trajnet`` or ``ethucy``), read once.

    The last few files read are kept in memory (keyed by path, size and modification
    time), so that many short episodes on one recording parse it once, and every file parsed
    is kept on disk as ``.npz`` (:mod:`~conformal_control.data.track_cache`: keyed by the
    file's content and the loaders' code), so that the next process reads it in
    milliseconds. Treat the result as read-only: it is shared.

    Parameters
    ----------
    kind : {"raw", "trajnet", "ethucy"}
        The file's format.
    path : path
        The file.
    m_per_px : float
        Metres per pixel (SDD files are in pixels).
    fps : float, optional
        The recording's frame rate.
    rate : float
        Rows per second of an ETH/UCY file.
    """
    if kind not in ("raw", "trajnet", "ethucy"):
        raise ValueError(f"kind must be raw, trajnet or ethucy, got {kind!r}")
    p = Path(path)
    try:
        st = p.stat()
        stamp = (st.st_size, st.st_mtime_ns)
    except OSError:
        stamp = (-1, -1)  # the reader raises the clear missing-file error
    return _read_tracks_cached(kind, str(p), float(m_per_px), fps, stamp, float(rate))


def _metres(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float).reshape(-1, 2)
    if arr.shape[0] == 0 or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be finite (x, y) positions in metres, got {value!r}")
    return arr


#: Share of a recording's positions left outside its walkable box on each side of each axis
#: (:func:`walkable_box`): a few stray samples (a pedestrian at the edge of the camera's
#: view) do not stretch the box.
WALKABLE_QUANTILE = 0.025
#: The default task on an ETH/UCY recording, as fractions of its walkable box along its
#: longer side and across it: start at 5 %, goal at 95 %, on the middle line.
ETHUCY_TASK: tuple[tuple[float, float], tuple[float, float]] = ((0.05, 0.5), (0.95, 0.5))


def walkable_box(tracks: Tracks, every: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) corners in metres of a recording's walkable box: along each axis, the
    :data:`WALKABLE_QUANTILE` and ``1 - WALKABLE_QUANTILE`` quantiles of every recorded
    position (the box holding the middle 95 % of them).

    Parameters
    ----------
    tracks : Tracks
        The recording (metres).
    every : int
        Frames between two recorded samples (12 for ETH/UCY's 2.5 rows per second
        interpolated to 30 fps): the box is taken over the recorded positions only, not
        the interpolated ones.
    """
    xy = np.concatenate([p[f % every == 0] for f, p in tracks.tracks.values()])
    xy = xy[np.isfinite(xy).all(axis=1)]
    if xy.shape[0] == 0:
        raise ValueError(f"{tracks.source}: no finite position; no walkable box")
    lo = np.quantile(xy, WALKABLE_QUANTILE, axis=0)
    hi = np.quantile(xy, 1.0 - WALKABLE_QUANTILE, axis=0)
    return lo, hi


def _default_task(lo: np.ndarray, hi: np.ndarray) -> tuple[Position, Position]:
    """:data:`ETHUCY_TASK` on a box: along its longer side (x on a tie)."""
    (s_along, s_across), (g_along, g_across) = ETHUCY_TASK
    if hi[0] - lo[0] >= hi[1] - lo[1]:
        return Position(s_along, s_across), Position(g_along, g_across)
    return Position(s_across, s_along), Position(g_across, g_along)


def _task(
    start: Any,
    goals: Any,
    start_m: Any,
    goals_m: Any,
    default: tuple[Any, Any],
    *,
    frame: tuple[np.ndarray, np.ndarray],
    m_per_px: float | None,
    scene: str,
) -> tuple[np.ndarray, np.ndarray]:
    """Start (2,) and goals (G, 2) in metres: metres given as ``start_m`` / ``goals_m``,
    else positions as typed (:mod:`~conformal_control.data.positions`), else ``default``."""
    if start_m is not None:
        s_m = _metres(start_m, "start_m")[0]
    else:
        pos = parse_position(start if start is not None else default[0], "start")
        s_m = to_metres(pos, frame=frame, m_per_px=m_per_px, scene=scene, what="start")
    if goals_m is not None:
        g_m = _metres(goals_m, "goals_m")
    else:
        given = parse_positions(goals if goals is not None else default[1], "goal")
        g_m = np.array(
            [to_metres(p, frame=frame, m_per_px=m_per_px, scene=scene, what="goal") for p in given]
        )
    return s_m, g_m


def _ethucy_scene(
    name: str,
    data_root: str | os.PathLike[str] | None,
    *,
    start: Any,
    goals: Any,
    start_m: Any,
    goals_m: Any,
    start_frame: int | None,
    v_max: float | None,
    history_frames: int,
    last_frame: int | None,
) -> Scene:
    m = _ETHUCY_RE.match(name)
    if not m or m["stem"] not in ETHUCY_RECORDINGS:
        raise InputError(
            f"bad ETH/UCY scene name {name!r}; expected ethucy:<recording> with a recording "
            f"among {', '.join(ETHUCY_RECORDINGS)}"
        )
    path = ethucy_recording(m["stem"], data_root)
    rate = ETHUCY_ORIGINAL_RATE.get(m["stem"], ETHUCY_FPS) if m["corrected"] else ETHUCY_FPS
    tracks = read_tracks("ethucy", path, fps=ETHUCY_SCENE_FPS, rate=rate)
    lo, hi = walkable_box(tracks, every=round(ETHUCY_SCENE_FPS / rate))
    scene_name = m["stem"] + (":corrected" if rate != ETHUCY_FPS else "")
    start_xy, goals_xy = _task(
        start,
        goals,
        start_m,
        goals_m,
        _default_task(lo, hi),
        frame=(lo, hi - lo),
        m_per_px=None,
        scene=scene_name,
    )
    scene = scene_from_tracks(
        tracks,
        name=scene_name,
        start=start_xy,
        goals=goals_xy,
        start_frame=int(
            start_frame if start_frame is not None else tracks.frame_range()[0] + history_frames
        ),
        v_max=float(v_max if v_max is not None else 4.0),
        history_frames=history_frames,
        last_frame=last_frame,
        units=UnitSystem(1.0, 1.0 / ETHUCY_SCENE_FPS, "m", "frame"),
        defaults=dict(ETHUCY_DEFAULTS),
    )
    scene.meta.update(
        {
            "ethucy_recording": m["stem"],
            "ethucy_scene": ETHUCY_RECORDINGS[m["stem"]],
            "ethucy_rate": rate,
            "walkable_box": [lo.tolist(), hi.tolist()],
        }
    )
    scene.meta["published_params"] = dict(ETHUCY_PUBLISHED)
    return scene


def load_scene(
    name: str,
    data_root: str | os.PathLike[str] | None = None,
    *,
    start: Any = None,
    goals: Any = None,
    start_frame: int | None = None,
    v_max: float | None = None,
    history_frames: int = 120,
    seed: int = 0,
    last_frame: int | None = None,
    start_m: Sequence[float] | None = None,
    goals_m: Sequence[Sequence[float]] | None = None,
) -> Scene:
    """Build a scene by name (see the module docstring for the accepted names).

    ``start`` and ``goals`` replace the scene's task: fractions of its frame (the image on
    SDD scenes, the walkable box on ETH/UCY ones), or with a unit, ``"3.2m,1.0m"`` or
    ``"120px,300px"`` (:mod:`~conformal_control.data.positions`). ``start_m`` and
    ``goals_m`` give them as numbers in metres.
    ``last_frame`` ends the replayed data early (a smaller scene for a short episode).
    ``seed`` only matters for ``crossing``. ``scenario:<suite>/<id>`` (a scenario of a
    shipped benchmark suite) is read by :func:`conformal_control.data.catalog.load_scene`,
    which resolves every name (``conformal_control.data.load_scene`` is that one).

    Parameters
    ----------
    name : str
        ``crossing``, ``sdd:<scene>/video<N>[:trajnet]``, a paper scene name
        (``nexus_4``, ...) or ``ethucy:<scene>``.
    data_root : str or path, optional
        The data folder; None: ``$CONFORMAL_CONTROL_DATA``, else the per-user data folder.
    start : position, optional
        Robot start: ``(fx, fy)`` fractions of the scene's frame, ``"3.2m,1.0m"`` metres or
        ``"120px,300px"`` pixels (None: the scene's own).
    goals : position or sequence of positions, optional
        Goals visited in order, as ``start`` (None: the scene's own).
    start_frame : int, optional
        The frame the robot starts at (None: the registry's).
    v_max : float, optional
        Robot speed bound (m/s; None: the registry's).
    history_frames : int
        Frames kept before ``start_frame`` (the predictor's history).
    seed : int
        Seed of the built-in ``crossing`` scene.
    last_frame : int, optional
        The last frame replayed (None: the recording's last).
    start_m : (x, y), optional
        Robot start in metres (replaces ``start``).
    goals_m : sequence of (x, y), optional
        Goals in metres (replace ``goals``).
    """
    if name.startswith("scenario:"):
        raise ValueError(
            f"{name!r} is a benchmark scenario: load it with conformal_control.data.load_scene"
        )
    if name == "crossing":
        if any(v is not None for v in (start, goals, start_frame, start_m, goals_m)):
            raise ValueError("the built-in crossing scene has a fixed start, goal and frame")
        return crossing_scene(seed=seed)
    if name.startswith("ethucy:"):
        return _ethucy_scene(
            name,
            data_root,
            start=start,
            goals=goals,
            start_m=start_m,
            goals_m=goals_m,
            start_frame=start_frame,
            v_max=v_max,
            history_frames=history_frames,
            last_frame=last_frame,
        )
    base, _, form = name.partition(":")
    spec: SceneSpec | None = None
    spec_goals: tuple[tuple[float, float], ...]
    if name.startswith("sdd:"):
        m = _SDD_RE.match(name)
        if not m:
            raise ValueError(
                f"bad SDD scene name {name!r}; expected sdd:<scene>/video<N>[:trajnet]"
            )
        sdd_scene, video, source = m["scene"], int(m["video"]), m["form"] or "raw"
        published = _defaults(TABLE_II)
        defaults = None  # the crowd defaults, once the video's scale is known
        spec_start, spec_goals, spec_frame, spec_vmax = (0.05, 0.5), ((0.95, 0.5),), 0, 4.0
        scene_name = f"{sdd_scene}_{video}" + (":trajnet" if m["form"] == "trajnet" else "")
    elif base in PAPER_SCENES:
        spec = PAPER_SCENES[base]
        if form not in ("", "raw", "trajnet"):
            raise ValueError(f"unknown form {form!r} in {name!r}; use :raw or :trajnet")
        sdd_scene, video, source = spec.sdd_scene, spec.video, form or spec.source
        defaults = dict(spec.defaults)
        published = dict(spec.defaults)
        spec_start, spec_goals, spec_frame, spec_vmax = (
            spec.start,
            spec.goals,
            spec.start_frame,
            spec.v_max,
        )
        scene_name = base if not form else f"{base}:{form}"
    else:
        import difflib
        import reprlib

        close = (
            difflib.get_close_matches(base, scene_names(), n=1, cutoff=0.6)
            if len(base) <= 100
            else []
        )
        hint = f" did you mean {close[0]!r}?" if close else ""
        short = reprlib.Repr()
        short.maxstring = 80  # a name read from a file may be megabytes long
        raise InputError(
            f"unknown scene {short.repr(name)};{hint} known: {', '.join(scene_names())}, or "
            "sdd:<scene>/video<N>[:trajnet] or ethucy:<recording> (see `conformal-control scenes`)"
        )
    vid = sdd_video(sdd_scene, video, data_root)
    if defaults is None:
        defaults = crowd_defaults(vid.m_per_px, SDD_FPS, published)
    if source == "raw":
        tracks = read_tracks("raw", vid.annotations, vid.m_per_px)
    else:
        tracks = read_tracks("trajnet", vid.trajnet, vid.m_per_px)
    size_px = vid.image_size_px()
    if size_px is None:
        raise ValueError(
            f"{vid.image} is missing: the reference image gives the scene's size, which "
            "start and goal fractions refer to"
        )
    extent = (size_px[0] * vid.m_per_px, size_px[1] * vid.m_per_px)
    wh = np.array(extent)
    start_xy, goals_xy = _task(
        start,
        goals,
        start_m,
        goals_m,
        (Position(*spec_start), [Position(*g) for g in spec_goals]),
        frame=(np.zeros(2), wh),
        m_per_px=vid.m_per_px,
        scene=scene_name,
    )
    start_frac, goal_frac = start_xy / wh, goals_xy / wh
    scene = scene_from_tracks(
        tracks,
        name=scene_name,
        start=start_xy,
        goals=goals_xy,
        start_frame=int(start_frame if start_frame is not None else spec_frame),
        v_max=float(v_max if v_max is not None else spec_vmax),
        history_frames=history_frames,
        last_frame=last_frame,
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
            "published_params": published,
        }
    )
    return scene
