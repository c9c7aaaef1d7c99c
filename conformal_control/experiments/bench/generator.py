"""Deterministic generation of crossing scenarios from real recordings.

The question the benchmark asks is whether a robot crossing a crowd stays safe, so a
scenario must put pedestrians across the robot's path while the robot is on it. The
generator cuts every recording into time windows and, in each, looks for a straight
start-goal segment that pedestrians cross.

Selection criterion (all lengths in metres, times in seconds; the numbers are
:class:`Criterion`'s defaults and are written into the manifest):

1. **Recording.** Pedestrian tracks at 30 fps in metres: raw SDD annotations (label
   ``Pedestrian``, ``lost = 0``, box centre, pixels x the video's scale), TrajNet SDD
   files (re-linked, interpolated to 30 fps) and ETH/UCY recordings (interpolated from
   2.5 to 30 fps). The geometry below is evaluated on every ``analysis_step``-th frame
   (0.2 s).
2. **Walkable area.** Cells of ``cell`` (1 m) visited by at least one pedestrian of the
   recording at any time, grown by one cell in every direction.
3. **Segment, time, windows.** The segment length L is ``length_m[source]`` (12 m on SDD
   and TrajNet, 10 m on the smaller ETH/UCY areas). The reference speed ``v_ref`` (2 m/s)
   is the robot's speed bound in the scenario: a robot at walking pace has to interact
   with the crowd (at the SDD scenes' usual 4 m/s it outruns most pedestrians). The
   crossing window is the time a robot at ``v_ref`` needs to traverse the segment,
   T = L / v_ref; the time limit is ``time_factor`` (2) x T. The robot starts
   ``history_s`` (1 s) after the recording's first frame and then every ``stride_s``
   (3 s) while the time limit fits in the data, so consecutive windows of a recording
   overlap in time; a scenario's scene keeps up to ``max_history_s`` (4 s) of data before
   its start for the predictor. Window start, crossing window and time limit are rounded
   up to whole analysis frames.
4. **Candidates.** Centres: the ``n_centres`` (5) cells where pedestrians were densest
   during the crossing window (most pedestrian samples; ties by cell index). Directions:
   ``n_directions`` (24) headings 15 degrees apart. Each (centre, heading) is a segment of
   length L centred on the centre, start behind, goal ahead.
5. **Admissible segments.** Start and goal at least ``border_margin`` (1 m) inside the
   image (SDD, TrajNet) or the recording's bounding box (ETH/UCY); both in the walkable
   area and at least ``min_walkable`` (90 %) of the points every 0.5 m along the segment
   too; no pedestrian within ``clearance`` (2 m) of the start at the start time, nor of
   the goal at the start time and at the end of the crossing window.
6. **Crossings.** A pedestrian track crosses the segment when, between two consecutive
   analysis frames of the crossing window, it changes side of the segment's line at a
   point between start and goal. ``n_crossing`` counts such tracks. Among admissible
   candidates the generator keeps the one with the most crossings (ties: most *timed*
   crossings - those within ``timing_tolerance`` (2 s) of the moment a robot moving at
   ``v_ref`` from the start passes the crossing point - then centre rank, then heading).
7. **Acceptance.** The window becomes a scenario if that candidate has at least
   ``min_crossings`` (k = 3) crossing tracks.

For every scenario the generator stores what it measured (``stats``: ``n_crossing``,
``n_timed``, ``n_crossing_episode`` over the whole time limit, ``n_present`` pedestrians
in the scene during the episode, ``corridor_density`` pedestrians per 100 m^2 within
``corridor_half_width`` (2 m) of the segment averaged over the crossing window,
``crossing_speed`` the crossing pedestrians' mean speed) and, when asked, the outcome of
the ``nolearn`` baseline (constant-velocity predictor, lambda fixed at 0, the SDD
defaults with a = 10 per frame as the published code ran, the scenario's speed bound
``v_ref``): ``n_collide`` (frames with a pedestrian closer than the collision distance),
``d_min``, ``goal_reached``, ``t_goal``, ``frames``, ``n_fallback``.

**Split.** By recording, never by scenario: recordings are grouped by location (SDD scene
name; ETH/UCY: eth, hotel, univ, zara); within a location, sorted by video number (or
name), they alternate test, dev, test, ...; locations with a single recording are pooled,
sorted by recording id and alternate the same way. A recording's raw and TrajNet forms
would be the same video: the default suite uses the TrajNet form only for the videos
without raw annotations.

Everything is a pure function of the data files and the parameters: no randomness, and
the numbers written are rounded (metres to 1 mm, fractions to 1e-6) so the manifest is
reproduced byte for byte.
"""

from __future__ import annotations

import functools
import hashlib
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...data.ethucy import ETHUCY_FPS, ETHUCY_ORIGINAL_RATE, ETHUCY_RECORDINGS, ethucy_recording
from ...data.paths import resolve_data_root
from ...data.scenes import read_tracks
from ...data.sdd import SDD_FPS, sdd_video
from ...data.suites import SCHEMA, SCHEMA_VERSION, Scenario, load_scenario
from ...data.tracks import Tracks

__all__ = [
    "CROSSINGS_V1",
    "SUITES",
    "Criterion",
    "Recording",
    "Regenerated",
    "SuiteSpec",
    "assign_splits",
    "generate_suite",
    "manifest_entries",
    "recording_scenarios",
    "regenerate_suite",
]

FPS = SDD_FPS
GENERATOR_VERSION = 1


@dataclass(frozen=True)
class Criterion:
    """Parameters of the crossing criterion (see the module docstring)."""

    length_m: dict[str, float] = field(
        default_factory=lambda: {"sdd": 12.0, "trajnet": 12.0, "ethucy": 10.0}
    )
    v_ref: float = 2.0
    time_factor: float = 2.0
    stride_s: float = 3.0
    min_crossings: int = 3
    n_centres: int = 5
    n_directions: int = 24
    cell: float = 1.0
    min_walkable: float = 0.9
    border_margin: float = 1.0
    clearance: float = 2.0
    timing_tolerance: float = 2.0
    corridor_half_width: float = 2.0
    history_s: float = 1.0
    max_history_s: float = 4.0
    analysis_step: int = 6


@dataclass(frozen=True)
class Recording:
    """One recording a suite draws scenarios from.

    Attributes
    ----------
    id : str
        Scene name for :func:`~conformal_control.data.load_scene`: ``sdd:<scene>/video<N>``,
        ``sdd:<scene>/video<N>:trajnet`` or ``ethucy:<name>``.
    source : {"sdd", "trajnet", "ethucy"}
    location : str
        Where it was filmed (the split keeps a location's recordings apart).
    order : int
        Position within the location (video number; ETH/UCY: file order).
    """

    id: str
    source: str
    location: str
    order: int

    @property
    def slug(self) -> str:
        body = self.id.split(":")[1].replace("/video", "-").replace("/", "-")
        return f"{self.source}-{body}"


_SDD_RAW = {
    "deathCircle": (2, 4),
    "gates": (2, 4, 5, 6, 7, 8),
    "hyang": (7, 8, 9, 12, 13, 14),
    "little": (0,),
    "nexus": (3, 4, 5, 10),
    "quad": (0, 1, 2, 3),
}
_SDD_TRAJNET_ONLY = {"gates": (1,), "bookstore": (0,), "coupa": (0,), "hyang": (1, 5)}
_ETHUCY_LOCATION = {
    "biwi_eth": ("eth", 0),
    "biwi_hotel": ("hotel", 0),
    "students001": ("univ", 1),
    "students003": ("univ", 3),
    "crowds_zara01": ("zara", 1),
    "crowds_zara02": ("zara", 2),
}


def default_recordings(corrected: bool = False) -> list[Recording]:
    """Every raw SDD video of the data, the TrajNet-only videos, the ETH/UCY recordings
    (``corrected``: on their original clock, ``ethucy:<name>:corrected`` where it differs,
    see :data:`conformal_control.data.ethucy.ETHUCY_ORIGINAL_RATE`)."""
    recs = [
        Recording(f"sdd:{sc}/video{v}", "sdd", sc, v) for sc, vs in _SDD_RAW.items() for v in vs
    ]
    recs += [
        Recording(f"sdd:{sc}/video{v}:trajnet", "trajnet", sc, v)
        for sc, vs in _SDD_TRAJNET_ONLY.items()
        for v in vs
    ]
    recs += [
        Recording(
            f"ethucy:{stem}" + (":corrected" if corrected and stem in ETHUCY_ORIGINAL_RATE else ""),
            "ethucy",
            *_ETHUCY_LOCATION[stem],
        )
        for stem in ETHUCY_RECORDINGS
    ]
    return sorted(recs, key=lambda r: r.id)


@dataclass(frozen=True)
class SuiteSpec:
    """A suite: name, version, recordings, criterion and the nolearn baseline's settings."""

    name: str
    version: int
    description: str
    recordings: tuple[Recording, ...]
    criterion: Criterion = field(default_factory=Criterion)
    nolearn_predictor: str = "constant_velocity"
    #: the edge rule pinned off (issue 30), as the filter is: the versioned record does not
    #: change with the controller's defaults
    nolearn_params: dict[str, Any] = field(default_factory=lambda: {"edge": "paper"})
    #: pinned so that a change of the flagship's default filter does not change the record
    nolearn_safety_filter: str = "exact2d"
    #: the nolearn record with the paper's parameters (v1) or the scenes' defaults (v2: the
    #: benchmark's own nolearn)
    nolearn_published: bool = True

    @property
    def full_name(self) -> str:
        return f"{self.name}-v{self.version}"


CROSSINGS_V1 = SuiteSpec(
    name="crossings",
    version=1,
    description=(
        "Straight crossings of real crowds: every raw SDD video of the data, the "
        "TrajNet-only SDD videos and the ETH/UCY recordings, cut into non-overlapping "
        "windows; a window is kept when at least k pedestrian tracks cross the robot's "
        "start-goal segment while a robot at the reference speed traverses it."
    ),
    recordings=tuple(default_recordings()),
)

#: v2: biwi_eth on its original clock (0.667 s per row, real walking speeds) and the nolearn
#: record made with the scenes' defaults (what ``bench run`` runs as ``nolearn``).
CROSSINGS_V2 = SuiteSpec(
    name="crossings",
    version=2,
    description=(
        "Straight crossings of real crowds, as crossings-v1 with biwi_eth on its original "
        "clock (one row every 0.667 s, not 0.4 s): every raw SDD video of the data, the "
        "TrajNet-only SDD videos and the ETH/UCY recordings, cut into windows; a window is "
        "kept when at least k pedestrian tracks cross the robot's start-goal segment while a "
        "robot at the reference speed traverses it."
    ),
    recordings=tuple(default_recordings(corrected=True)),
    nolearn_published=False,
)

SUITES: dict[str, SuiteSpec] = {s.full_name: s for s in (CROSSINGS_V1, CROSSINGS_V2)}


def assign_splits(recordings: Sequence[Recording]) -> dict[str, str]:
    """Recording id -> ``dev`` / ``test`` (the split rule of the module docstring)."""
    by_loc: dict[str, list[Recording]] = {}
    for r in recordings:
        by_loc.setdefault(r.location, []).append(r)
    out: dict[str, str] = {}
    singles: list[Recording] = []
    for loc in sorted(by_loc):
        group = sorted(by_loc[loc], key=lambda r: (r.order, r.id))
        if len(group) == 1:
            singles.append(group[0])
            continue
        for i, r in enumerate(group):
            out[r.id] = ("test", "dev")[i % 2]
    for i, r in enumerate(sorted(singles, key=lambda r: r.id)):
        out[r.id] = ("test", "dev")[i % 2]
    return out


SPLIT_RULE = (
    "by recording: grouped by location (SDD scene; ETH/UCY eth, hotel, univ, zara), sorted by "
    "video number within a location and alternating test, dev, test, ...; single-recording "
    "locations pooled, sorted by recording id, alternating the same way"
)


# ------------------------------------------------------------------------- geometry
@dataclass
class _Source:
    """A recording's tracks at the analysis rate, its bounds and walkable grid."""

    recording: Recording
    file: Path
    file_rel: str
    m_per_px: float | None
    image_px: tuple[int, int] | None
    first: int
    last: int
    frames: np.ndarray  # (S,) analysis frame numbers
    pos: np.ndarray  # (S, M, 2) positions, NaN where absent
    lo: np.ndarray  # (2,) bounds of the admissible area
    hi: np.ndarray
    grid_origin: np.ndarray
    walkable: np.ndarray  # (nx, ny) bool


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _load_source(rec: Recording, data_root: Path, crit: Criterion) -> _Source:
    root = resolve_data_root(data_root)
    if rec.source == "ethucy":
        _, stem, *form = rec.id.split(":")
        path = ethucy_recording(stem, root)
        rate = ETHUCY_ORIGINAL_RATE.get(stem, ETHUCY_FPS) if form == ["corrected"] else ETHUCY_FPS
        tracks = read_tracks("ethucy", path, fps=FPS, rate=rate)
        m_per_px, image_px = None, None
    else:
        body = rec.id.split(":")[1]
        scene, video = body.split("/video")
        vid = sdd_video(scene, int(video), root)
        path = vid.annotations if rec.source == "sdd" else vid.trajnet
        tracks = read_tracks("raw" if rec.source == "sdd" else "trajnet", path, vid.m_per_px)
        m_per_px, image_px = vid.m_per_px, vid.image_size_px()
        if image_px is None:
            raise ValueError(f"{vid.image} is missing: scenarios need the image's size")
    try:
        rel = str(path.relative_to(root))
    except ValueError:
        rel = str(path)
    first, last = tracks.frame_range()
    step = crit.analysis_step
    frames = np.arange(first, last + 1, step)
    pos = _sampled(tracks, first, step, frames.size)
    finite = np.isfinite(pos[..., 0])
    pts = pos[finite]
    if image_px is not None:
        lo = np.zeros(2)
        hi = np.array(image_px, dtype=float) * float(m_per_px or 1.0)
    else:
        lo, hi = pts.min(axis=0), pts.max(axis=0)
    origin = np.floor(lo / crit.cell) * crit.cell
    shape = np.ceil((hi - origin) / crit.cell).astype(int) + 1
    grid = np.zeros(shape, dtype=bool)
    cells = np.floor((pts - origin) / crit.cell).astype(int)
    ok = np.all((cells >= 0) & (cells < shape), axis=1)
    grid[cells[ok, 0], cells[ok, 1]] = True
    grown = grid.copy()  # one-cell dilation (3 x 3)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            grown |= np.roll(np.roll(grid, dx, 0), dy, 1) & _roll_mask(shape, dx, dy)
    return _Source(
        rec, path, rel, m_per_px, image_px, first, last, frames, pos, lo, hi, origin, grown
    )


def _roll_mask(shape: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """Mask of cells a np.roll by (dx, dy) filled from inside the grid (no wrap-around)."""
    m = np.ones(tuple(shape), dtype=bool)
    if dx > 0:
        m[:dx, :] = False
    elif dx < 0:
        m[dx:, :] = False
    if dy > 0:
        m[:, :dy] = False
    elif dy < 0:
        m[:, dy:] = False
    return m


def _sampled(tracks: Tracks, first: int, step: int, n: int) -> np.ndarray:
    """Positions at frames first, first + step, ... (n of them), shape (n, M, 2)."""
    ids = tracks.ids
    pos = np.full((n, len(ids), 2), np.nan)
    for col, i in enumerate(ids):
        f, xy = tracks.tracks[i]
        sel = (f - first) % step == 0
        pos[(f[sel] - first) // step, col] = xy[sel]
    return pos


def _walkable_fraction(src: _Source, a: np.ndarray, b: np.ndarray, crit: Criterion) -> float:
    n = max(round(float(np.linalg.norm(b - a)) / 0.5), 1) + 1
    pts = a[None, :] + np.linspace(0.0, 1.0, n)[:, None] * (b - a)[None, :]
    cells = np.floor((pts - src.grid_origin) / crit.cell).astype(int)
    shape = np.array(src.walkable.shape)
    inside = np.all((cells >= 0) & (cells < shape), axis=1)
    walk = np.zeros(n, dtype=bool)
    walk[inside] = src.walkable[cells[inside, 0], cells[inside, 1]]
    if not (walk[0] and walk[-1]):
        return 0.0
    return float(walk.mean())


def _crossings(
    pos: np.ndarray, c: np.ndarray, u: np.ndarray, half: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where tracks cross the segment c +- half u between consecutive samples.

    Returns boolean (S-1, M) crossing events, the along-segment coordinate of each event
    and its fractional sample time (NaN where no event).
    """
    n = np.array([-u[1], u[0]])
    rel = pos - c
    perp = rel @ n
    par = rel @ u
    p0, p1 = perp[:-1], perp[1:]
    with np.errstate(invalid="ignore", divide="ignore"):
        sign = (p0 * p1 < 0) | ((p0 == 0) & (p1 != 0))
        frac = np.where(sign, p0 / (p0 - p1), np.nan)
        s = par[:-1] + frac * (par[1:] - par[:-1])
        event = sign & (np.abs(s) <= half)
    t = np.arange(pos.shape[0] - 1)[:, None] + frac
    return event, np.where(event, s, np.nan), np.where(event, t, np.nan)


def _window_candidate(
    src: _Source, i0: int, n_cross: int, n_episode: int, length: float, crit: Criterion
) -> dict[str, Any] | None:
    """The best admissible segment of the window starting at analysis index i0."""
    step_s = crit.analysis_step / FPS
    # only the tracks present at some time of the episode (the rest are all NaN here)
    ep = src.pos[i0 : i0 + n_episode + 1]
    ep = ep[:, np.isfinite(ep[..., 0]).any(axis=0)]
    win = ep[: n_cross + 1]
    finite = np.isfinite(win[..., 0])
    if finite.sum() == 0:
        return None
    pts = win[finite]
    cells = np.floor((pts - src.grid_origin) / crit.cell).astype(int)
    keys, counts = np.unique(cells, axis=0, return_counts=True)
    order = np.lexsort((keys[:, 1], keys[:, 0], -counts))[: crit.n_centres]
    centres = src.grid_origin + (keys[order] + 0.5) * crit.cell
    half = 0.5 * length
    lo = src.lo + crit.border_margin
    hi = src.hi - crit.border_margin
    now = win[0][np.isfinite(win[0, :, 0])]
    end = win[-1][np.isfinite(win[-1, :, 0])]
    best: tuple[tuple[int, ...], dict[str, Any]] | None = None
    for ci, c in enumerate(centres):
        for di in range(crit.n_directions):
            th = 2.0 * math.pi * di / crit.n_directions
            u = np.array([math.cos(th), math.sin(th)])
            start, goal = c - half * u, c + half * u
            if not (np.all(start >= lo) and np.all(start <= hi)):
                continue
            if not (np.all(goal >= lo) and np.all(goal <= hi)):
                continue
            if _walkable_fraction(src, start, goal, crit) < crit.min_walkable:
                continue
            if now.size and np.min(np.hypot(*(now - start).T)) <= crit.clearance:
                continue
            if now.size and np.min(np.hypot(*(now - goal).T)) <= crit.clearance:
                continue
            if end.size and np.min(np.hypot(*(end - goal).T)) <= crit.clearance:
                continue
            event, s, t = _crossings(win, c, u, half)
            crossing = event.any(axis=0)
            n_c = int(crossing.sum())
            if n_c == 0:
                continue
            # timed: |t_cross - t_robot(s)| <= tolerance, t in seconds from the start
            t_robot = (s + half) / crit.v_ref
            with np.errstate(invalid="ignore"):
                timed = event & (np.abs(t * step_s - t_robot) <= crit.timing_tolerance)
            n_t = int(timed.any(axis=0).sum())
            key = (n_c, n_t, -ci, -di)
            if best is None or key > best[0]:
                best = (
                    key,
                    {"c": c, "u": u, "start": start, "goal": goal, "crossing": crossing},
                )
    if best is None or best[0][0] < crit.min_crossings:
        return None
    cand = best[1]
    c, u = cand["c"], cand["u"]
    n_timed = best[0][1]
    # statistics over the crossing window and the whole episode
    ev_ep, _, _ = _crossings(ep, c, u, half)
    present = np.isfinite(ep[..., 0]).any(axis=0)
    rel = win - c
    n_vec = np.array([-u[1], u[0]])
    inside = (np.abs(rel @ n_vec) <= crit.corridor_half_width) & (np.abs(rel @ u) <= half)
    inside &= finite
    area = 2.0 * crit.corridor_half_width * length
    density = float(inside.sum(axis=1).mean()) / area * 100.0
    cross_tracks = np.flatnonzero(cand["crossing"])
    speeds = []
    for j in cross_tracks:
        p = win[:, j]
        ok = np.isfinite(p[:, 0])
        d = np.diff(p[ok], axis=0)
        if d.shape[0]:
            speeds.append(float(np.hypot(*d.T).sum()) / (d.shape[0] * step_s))
    return {
        "start": cand["start"],
        "goal": cand["goal"],
        "stats": {
            "n_crossing": int(cand["crossing"].sum()),
            "n_timed": n_timed,
            "n_crossing_episode": int(ev_ep.any(axis=0).sum()),
            "n_present": int(present.sum()),
            "corridor_density": round(density, 3),
            "crossing_speed": round(float(np.mean(speeds)), 3) if speeds else None,
        },
    }


def _r(x: float, nd: int = 3) -> float:
    v = round(float(x), nd)
    return 0.0 if v == 0 else v


def recording_scenarios(
    rec: Recording, split: str, data_root: Path, crit: Criterion
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The recording's manifest entry and its scenarios (without nolearn outcomes).

    Parameters
    ----------
    rec : Recording
        The recording.
    split : str
        The split its scenarios belong to (``dev`` or ``test``).
    data_root : Path
        The data folder.
    crit : Criterion
        The crossing criterion (crossing length, speed, time limit, stride, ...).
    """
    src = _load_source(rec, data_root, crit)
    length = float(crit.length_m[rec.source])
    step = crit.analysis_step
    t_cross = length / crit.v_ref
    time_limit = crit.time_factor * t_cross
    max_frames = math.ceil(round(time_limit * FPS, 6) / step) * step
    n_cross = math.ceil(round(t_cross * FPS, 6) / step)
    n_episode = max_frames // step
    history = math.ceil(round(crit.history_s * FPS, 6) / step) * step
    max_history = round(crit.max_history_s * FPS)
    stride = max(math.ceil(round(crit.stride_s * FPS, 6) / step), 1)
    scenarios = []
    i0 = history // step
    window = 0
    while src.frames[0] + (i0 + n_episode) * step <= src.last:
        cand = _window_candidate(src, i0, n_cross, n_episode, length, crit)
        if cand is not None:
            start_frame = int(src.frames[i0])
            frac = None
            if src.image_px is not None:
                wh = np.array(src.image_px, dtype=float) * float(src.m_per_px or 1.0)
                frac = (cand["start"] / wh, cand["goal"] / wh)
            scenarios.append(
                {
                    "id": f"{rec.slug}-w{window:03d}",
                    "recording": rec.id,
                    "source": rec.source,
                    "scene": rec.id,
                    "split": split,
                    "window": window,
                    "start_frame": start_frame,
                    "fps": FPS,
                    "start_m": [_r(v) for v in cand["start"]],
                    "goal_m": [_r(v) for v in cand["goal"]],
                    "start_fraction": None if frac is None else [_r(v, 6) for v in frac[0]],
                    "goal_fraction": None if frac is None else [_r(v, 6) for v in frac[1]],
                    "length_m": length,
                    "v_ref": crit.v_ref,
                    "time_limit_s": _r(max_frames / FPS, 6),
                    "max_frames": max_frames,
                    "history_frames": min(max_history, start_frame - int(src.first)),
                    "stats": cand["stats"],
                    "nolearn": None,
                }
            )
        i0 += stride
        window += 1
    entry = {
        "id": rec.id,
        "source": rec.source,
        "location": rec.location,
        "split": split,
        "file": src.file_rel,
        "sha256": _sha256(src.file),
        "m_per_px": src.m_per_px,
        "image_size_px": None if src.image_px is None else list(src.image_px),
        "first_frame": int(src.first),
        "last_frame": int(src.last),
        "n_tracks": int(src.pos.shape[1]),
        "n_windows": window,
        "n_scenarios": len(scenarios),
    }
    return entry, scenarios


_NOTE_PUBLISHED = (
    "run_episode(load_scenario(s), predictor, params, learn=False, "
    "max_frames=s.max_frames): lambda fixed at lambda_init = 0, every other "
    "parameter the paper's (scene.meta['published_params'], units='scene') - "
    "SDD/TrajNet: Table II in px and frames "
    "with a = 10 per frame (the published code's alpha(h) = 10 h), "
    "radii 0.5 m; ETH/UCY: the same in m and frames at 30 fps, lengths "
    "converted at 0.04 m per px; v_max = the scenario's v_ref"
)
_NOTE_DEFAULTS = (
    "run_episode(load_scenario(s), predictor, params, learn=False, "
    "max_frames=s.max_frames): lambda fixed at lambda_init = 0, every other parameter the "
    "scene's default (the benchmark's nolearn: a = 100/s, K_rep = 0.2 m^2, radii 0.5 m, "
    "v_max = the scenario's v_ref)"
)


def _map(fn: Callable[[Any], Any], items: list[Any], workers: int) -> list[Any]:
    """``[fn(x) for x in items]``, in order, on ``workers`` processes when > 1."""
    if int(workers) != workers or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if workers == 1 or len(items) < 2:
        return [fn(x) for x in items]
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=int(workers)) as pool:
        return list(pool.map(fn, items, chunksize=4))


def nolearn_outcome(
    scenario: dict[str, Any],
    data_root: Path,
    predictor: str,
    params: dict[str, Any],
    safety_filter: str = "exact2d",
    published: bool = True,
) -> dict[str, Any]:
    """Run the suite's nolearn baseline on one scenario; the rounded outcome.

    Parameters
    ----------
    scenario : dict
        The scenario's manifest entry.
    data_root : Path
        The data folder.
    predictor : str
        The registered predictor the baseline runs with.
    params : dict
        Run parameters, in the scene's units (they win over the published ones).
    safety_filter : str
        The registered safety filter.
    published : bool
        Start from the paper's parameters recorded with the scene (as the v1 suites'
        records were made), not the scene's defaults.

    Returns
    -------
    dict
        ``n_collide``, ``d_min`` (m), ``goal_reached``, ``t_goal`` (s), ``frames``,
        ``n_fallback`` (lengths and times rounded).
    """
    from ...runs.episode import run_episode

    sc = Scenario.from_dict(scenario)
    scene = load_scenario(sc, data_root)
    # v1's record was made with the paper's parameters, whatever the scene's defaults are now
    base = dict(scene.meta.get("published_params") or {}) if published else {}
    res = run_episode(
        scene,
        predictor,
        {**base, **dict(params)},
        units="scene",
        learn=False,
        max_frames=sc.max_frames,
        record_animation=False,
        safety_filter=safety_filter,
    )
    m = res.metrics
    return {
        "n_collide": int(m["n_collide"]),
        "d_min": None if m["d_min"] is None else _r(m["d_min"]),
        "goal_reached": bool(m["goal_reached"]),
        "t_goal": None if m["t_goal"] is None else _r(m["t_goal"]),
        "frames": int(m["frames"]),
        "n_fallback": int(m["n_fallback"]),
    }


def generate_suite(
    spec: SuiteSpec,
    data_root: str | Path | None = None,
    *,
    recordings: Sequence[str] | None = None,
    nolearn: bool = True,
    workers: int = 1,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Generate a suite's manifest from the data (see the module docstring).

    Parameters
    ----------
    spec : SuiteSpec
    data_root : path, optional
        The data folder (``--data-root``).
    recordings : list of str, optional
        Generate only these recordings (ids); their entries and scenarios are identical
        to those of the full generation (the split is always computed over all of the
        suite's recordings).
    nolearn : bool
        Run the nolearn baseline on every scenario (slow: one episode each).
    workers : int
        Processes running the nolearn episodes (the result does not depend on it).
    progress : callable, optional
        Receives one line per recording.
    """
    root = resolve_data_root(data_root)
    splits = assign_splits(spec.recordings)
    known = {r.id: r for r in spec.recordings}
    if recordings is not None:
        unknown = [r for r in recordings if r not in known]
        if unknown:
            raise ValueError(
                f"suite {spec.full_name} has no recording(s) {', '.join(unknown)}; "
                f"its recordings: {', '.join(known)}"
            )
    chosen = [r for r in spec.recordings if recordings is None or r.id in recordings]
    entries, scenarios = [], []
    for rec in chosen:
        t0 = time.perf_counter()
        entry, scs = recording_scenarios(rec, splits[rec.id], root, spec.criterion)
        entries.append(entry)
        scenarios.extend(scs)
        if progress is not None:
            progress(
                f"{rec.id}: {len(scs)} scenario(s) from {entry['n_windows']} window(s) "
                f"[{splits[rec.id]}] in {time.perf_counter() - t0:.1f} s"
            )
    if nolearn:
        t0 = time.perf_counter()
        outcomes = _map(
            functools.partial(
                nolearn_outcome,
                data_root=root,
                predictor=spec.nolearn_predictor,
                params=spec.nolearn_params,
                safety_filter=spec.nolearn_safety_filter,
                published=spec.nolearn_published,
            ),
            scenarios,
            workers,
        )
        for sc, outcome in zip(scenarios, outcomes, strict=True):
            sc["nolearn"] = outcome
        if progress is not None:
            progress(
                f"nolearn baseline: {len(scenarios)} episode(s) in "
                f"{time.perf_counter() - t0:.1f} s on {workers} worker(s)"
            )
    for entry in entries:
        mine = [sc for sc in scenarios if sc["recording"] == entry["id"]]
        entry["n_nolearn_collision"] = (
            sum(int(sc["nolearn"]["n_collide"] > 0) for sc in mine) if nolearn else None
        )
    return {
        "schema": SCHEMA,
        "schema_version": SCHEMA_VERSION,
        "suite": spec.name,
        "version": spec.version,
        "description": spec.description,
        "generator": {
            "module": __name__,
            "generator_version": GENERATOR_VERSION,
            "criterion": asdict(spec.criterion),
            "fps": FPS,
        },
        "nolearn": {
            "measured": nolearn,
            "predictor": spec.nolearn_predictor,
            "learn": False,
            "params": dict(spec.nolearn_params),
            "safety_filter": spec.nolearn_safety_filter,
            "note": _NOTE_PUBLISHED if spec.nolearn_published else _NOTE_DEFAULTS,
        },
        "split_rule": SPLIT_RULE,
        "recordings": entries,
        "scenarios": scenarios,
    }


@dataclass(frozen=True)
class Regenerated:
    """A suite regenerated from the data and compared with the shipped manifest
    (:func:`regenerate_suite`).

    Attributes
    ----------
    manifest : dict
        The regenerated manifest.
    text : str
        It serialised as the shipped file is (:func:`~conformal_control.data.suites.dump_manifest`).
    wall_s : float
        Time the generation took.
    compared : str or None
        What it was compared with (``"the shipped manifest"``, ``"the shipped entries of
        N recording(s)"``); None when no manifest of the suite is shipped.
    same : bool or None
        Byte-identical to it (None: nothing to compare with).
    """

    manifest: dict[str, Any]
    text: str
    wall_s: float
    compared: str | None
    same: bool | None

    @property
    def n_scenarios(self) -> int:
        """Scenarios generated."""
        return len(self.manifest["scenarios"])

    @property
    def n_collisions(self) -> int:
        """Scenarios where the nolearn baseline collided."""
        return sum(int(s["nolearn"]["n_collide"] > 0) for s in self.manifest["scenarios"])


def manifest_entries(manifest: dict[str, Any], recordings: Sequence[str]) -> list[str]:
    """The serialised recording entries and scenarios of some recordings of a manifest.

    Parameters
    ----------
    manifest : dict
        A suite's manifest.
    recordings : sequence of str
        Recording ids.
    """
    import json

    wanted = set(recordings)
    recs = [r for r in manifest["recordings"] if r["id"] in wanted]
    scs = [s for s in manifest["scenarios"] if s["recording"] in wanted]
    return [json.dumps(x, indent=1) for x in (*recs, *scs)]


def regenerate_suite(
    suite: str,
    data_root: str | Path | None = None,
    *,
    recordings: Sequence[str] | None = None,
    workers: int = 1,
    progress: Callable[[str], None] | None = None,
) -> Regenerated:
    """Regenerate a suite that has a generator from the data (``bench scenarios
    --regenerate``) and compare it with the shipped manifest: the whole file, or the
    entries of ``recordings`` when only those were generated.

    Parameters
    ----------
    suite : str
        The suite's name (one of :data:`SUITES`).
    data_root : path, optional
        The data folder.
    recordings : sequence of str, optional
        Regenerate only these recordings.
    workers : int
        Processes running the nolearn episodes.
    progress : callable, optional
        Receives one line per recording.

    Raises
    ------
    ValueError
        For a suite without a generator.
    """
    from ...data.suites import dump_manifest, load_suite, suite_names

    if suite not in SUITES:
        raise ValueError(f"no generator for suite {suite!r}; suites with one: {', '.join(SUITES)}")
    t0 = time.perf_counter()
    manifest = generate_suite(
        SUITES[suite], data_root, recordings=recordings, workers=workers, progress=progress
    )
    wall = time.perf_counter() - t0
    text = dump_manifest(manifest)
    if suite not in suite_names():
        return Regenerated(manifest, text, wall, None, None)
    shipped = load_suite(suite).manifest
    if recordings:
        same = manifest_entries(shipped, recordings) == manifest_entries(manifest, recordings)
        what = f"the shipped entries of {len(set(recordings))} recording(s)"
    else:
        same, what = text == dump_manifest(shipped), "the shipped manifest"
    return Regenerated(manifest, text, wall, what, same)
