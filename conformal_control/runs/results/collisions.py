"""Collision accounting: every collision event of an episode, classified.

A *collision frame* is a frame whose smallest robot-pedestrian centre distance is below
the collision distance d_c (:class:`~conformal_control.runs.results.metrics.EpisodeMetrics`'s
``n_collide``). A *collision event* is a run of consecutive frames during which one
pedestrian is closer than d_c. Each collision frame is attributed to the event of its
nearest pedestrian, so the frame counts of the classes below add up to ``n_collide``.

For every event, :func:`account_collisions` measures:

``penetration``  the deepest intrusion, d_c - smallest distance (m);
``closing``      who moved toward whom at the event's first frame: the robot's velocity
                 along the line of centres toward the pedestrian, and the pedestrian's
                 toward the robot (m/s; the pedestrian's from the track by central
                 differences). Speeds above :data:`CLOSING_TOL` count as closing; the
                 event is ``robot`` (only the robot closes: "robot on person"),
                 ``pedestrian`` (only the pedestrian: "person on robot"), ``both`` or
                 ``neither``;
``popin``        the pedestrian *popped in*: when it first became visible (present in the
                 data and within the sensing radius) it was already within
                 d_c + :data:`POPIN_MARGIN_M` of the robot, or it became visible less
                 than :data:`POPIN_TIME_S` before the event (a track that starts next to
                 the robot: an annotation that starts late, a person leaving a door);
``avoidable``    whether a point robot with speed at most v_max, starting where the
                 robot was when the pedestrian was first *sensed* (the first sampling
                 time at which it was within the sensing radius), could have stayed at
                 least d_c from that pedestrian at every frame up to the event's end.
                 ``True`` when such a path is found (a proof), ``False`` when none exists
                 (a proof), ``None`` when neither was proved at the finest grid (below).
                 A pedestrian first sensed after the event began is ``False`` (the robot
                 had no information). The point robot is more agile than the simulated
                 one (it changes velocity instantly), so ``False`` means unavoidable for
                 any robot with that speed bound, while ``True`` means avoidable by an
                 ideal one; other pedestrians are ignored (one event at a time).

How "avoidable" is decided (discrete time, the frames at which collisions are counted):

1. *Covered*: if at some frame k the pedestrian's disk covers the whole reachable disk,
   ``|p0 - q_k| + v_max (k - k0) dt < d_c``, the event is unavoidable.
2. *Straight escapes*: constant velocities from p0 (64 headings x 4 speeds, and standing
   still); one that keeps d_c at every frame proves the event avoidable.
3. *Grid search*: the set of positions reachable at each frame without entering the
   pedestrian's disk is propagated on a grid of spacing h = v_max dt / 4 (halved twice
   if undecided). Grid points joined by hops of at most v_max dt are real paths: reaching
   a point that no later disk covers (standing there is safe) or surviving to the last
   frame proves avoidable. The same propagation on cells, with every bound widened by the
   cell's half diagonal, over-approximates the reachable set: if it empties, the event
   is unavoidable. Between the two the event stays undecided (``None``); the episode
   metrics count such frames apart (``n_collide_undecided``).

Episode figures (:func:`account_collisions` returns them with the events):
``n_collision_events``, ``n_collide_avoidable`` (frames of avoidable events that are not
pop-ins: the documented rule for pop-in tracks is that they are counted as collisions,
reported apart, and never as avoidable), ``n_collide_unavoidable``, ``n_collide_undecided``,
``n_collide_at_fault`` (collision frames at which the robot moved toward its nearest
pedestrian faster than :data:`CLOSING_TOL`), ``n_collide_popin`` and ``penetration_max``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = [
    "CLOSING_TOL",
    "POPIN_MARGIN_M",
    "POPIN_TIME_S",
    "CollisionAccount",
    "CollisionEvent",
    "account_collisions",
    "avoidable",
]

#: Margin (m) beyond d_c within which a pedestrian that first becomes visible is a pop-in.
POPIN_MARGIN_M = 1.0
#: A pedestrian visible for less than this (s) before its collision popped in.
POPIN_TIME_S = 0.5
#: Speed (m/s) along the line of centres above which a party counts as closing.
CLOSING_TOL = 0.1
#: Headings and speed fractions of the straight escapes.
_HEADINGS = 64
_SPEEDS = (1.0, 0.75, 0.5, 0.25)
#: Grid spacing as a fraction of the largest hop, and refinements when undecided.
_H_FRACTION = 0.25
_REFINE = 2
#: Largest grid side (cells); a larger region gets a coarser grid.
_MAX_SIDE = 800


@dataclass(frozen=True)
class CollisionEvent:
    """One collision event (see the module docstring).

    Attributes
    ----------
    agent : int
        The pedestrian's id.
    t_start, t_end : float
        Time of its first and last frame (s since the episode's start).
    frames : int
        Frames of the event (those attributed to it are ``frames_attributed``).
    frames_attributed : int
        Collision frames whose nearest pedestrian it is.
    d_min : float
        Smallest centre distance (m).
    penetration : float
        d_c - d_min (m).
    robot_closing, pedestrian_closing : float
        Speeds toward each other along the line of centres at the first frame (m/s).
    closing : str
        ``robot``, ``pedestrian``, ``both`` or ``neither``.
    popin : bool
    t_visible : float or None
        When the pedestrian first became visible (s).
    t_sensed : float or None
        When it was first sensed (a sampling time), None if never before the event's end.
    avoidable : bool or None
        See the module docstring.
    decided_by : str
        ``covered``, ``straight``, ``grid``, ``unsensed`` or ``undecided``.
    """

    agent: int
    t_start: float
    t_end: float
    frames: int
    frames_attributed: int
    d_min: float
    penetration: float
    robot_closing: float
    pedestrian_closing: float
    closing: str
    popin: bool
    t_visible: float | None
    t_sensed: float | None
    avoidable: bool | None
    decided_by: str

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class CollisionAccount:
    """The events of an episode and the episode's figures (see the module docstring)."""

    events: list[CollisionEvent]
    n_collide: int
    n_collision_events: int
    n_collide_avoidable: int
    n_collide_unavoidable: int
    n_collide_undecided: int
    n_collide_at_fault: int
    n_collide_popin: int
    penetration_max: float | None

    def figures(self) -> dict[str, Any]:
        """The episode metrics (``n_collision_events`` ... ``penetration_max``)."""
        return {
            "n_collision_events": self.n_collision_events,
            "n_collide_avoidable": self.n_collide_avoidable,
            "n_collide_unavoidable": self.n_collide_unavoidable,
            "n_collide_undecided": self.n_collide_undecided,
            "n_collide_at_fault": self.n_collide_at_fault,
            "n_collide_popin": self.n_collide_popin,
            "penetration_max": self.penetration_max,
        }


# ------------------------------------------------------------------ avoidability
def _disk(radius_cells: float) -> np.ndarray:
    r = math.floor(radius_cells + 1e-12)
    y, x = np.mgrid[-r : r + 1, -r : r + 1]
    out: np.ndarray = (x * x + y * y) <= radius_cells * radius_cells + 1e-12
    return out


def _straight(p0: np.ndarray, q: np.ndarray, k: np.ndarray, r: float, d_c: float) -> bool:
    """Whether a constant velocity (or standing still) from p0 keeps d_c from q[k]."""
    th = 2.0 * np.pi * np.arange(_HEADINGS) / _HEADINGS
    dirs = np.column_stack([np.cos(th), np.sin(th)])
    rel = q - p0  # (K, 2)
    if (np.hypot(rel[:, 0], rel[:, 1]) >= d_c).all():
        return True  # standing still
    kf = k.astype(float)
    for f in _SPEEDS:  # fastest first: most escapes are found at full speed
        u = dirs * (f * r)  # (C, 2) displacement per frame
        dx = u[:, 0, None] * kf[None, :] - rel[None, :, 0]
        dy = u[:, 1, None] * kf[None, :] - rel[None, :, 1]
        if (np.hypot(dx, dy) >= d_c).all(axis=1).any():
            return True
    return False


def _grid(
    p0: np.ndarray, q: np.ndarray, k: np.ndarray, r: float, d_c: float, h: float
) -> bool | None:
    """Decide by propagating reachable sets on a grid of spacing h (see the module
    docstring): True (a path exists), False (none does) or None (undecided)."""
    from scipy import ndimage

    lo = np.minimum(q.min(axis=0), p0) - d_c - 2 * r
    hi = np.maximum(q.max(axis=0), p0) + d_c + 2 * r
    side = np.ceil((hi - lo) / h).astype(int) + 1
    if side.max() > _MAX_SIDE:
        return None
    nx, ny = int(side[0]), int(side[1])
    xs = lo[0] + h * np.arange(nx)
    ys = lo[1] + h * np.arange(ny)
    half = h / math.sqrt(2.0)
    # for every grid point (cell) the last frame at which a disk covers it (the whole
    # cell): standing there after that frame is safe
    last_pt = np.full((nx, ny), -1, dtype=np.int64)
    last_cell = np.full((nx, ny), -1, dtype=np.int64)
    rad = math.ceil((d_c + h) / h) + 1
    boxes = []
    for i in range(len(k)):
        cx, cy = (q[i] - lo) / h
        a0, a1 = max(int(cx) - rad, 0), min(int(cx) + rad + 1, nx)
        b0, b1 = max(int(cy) - rad, 0), min(int(cy) + rad + 1, ny)
        d = np.hypot(xs[a0:a1, None] - q[i, 0], ys[None, b0:b1] - q[i, 1])
        last_pt[a0:a1, b0:b1][d < d_c] = i
        last_cell[a0:a1, b0:b1][d < d_c - half] = i
        boxes.append((a0, a1, b0, b1, d))
    step_in = _disk(r / h)  # grid points within r of each other: real hops
    step_out = _disk((r + 2 * half) / h)  # cells within reach of each other
    g_in, g_out = step_in.shape[0] // 2, step_out.shape[0] // 2
    inner = np.zeros((nx, ny), dtype=bool)
    outer = np.zeros((nx, ny), dtype=bool)
    pc = (p0 - lo) / h  # p0 in grid units
    alive_in = alive_out = True
    reach = 0.0  # how far (grid units) the sets can be from p0

    def window(extra: int) -> tuple[slice, slice]:
        e = math.ceil(reach) + extra + 1
        return (
            slice(max(int(pc[0]) - e, 0), min(int(pc[0]) + e + 1, nx)),
            slice(max(int(pc[1]) - e, 0), min(int(pc[1]) + e + 1, ny)),
        )

    for i in range(len(k)):
        hops = int(k[i] - (k[i - 1] if i else 0))
        if i == 0:
            d0 = np.hypot(xs[:, None] - p0[0], ys[None, :] - p0[1])
            inner = d0 <= r * hops
            outer = d0 <= r * hops + half
            reach = (r * hops + h) / h
        else:
            for _ in range(hops):
                reach += (r + 2 * h) / h
                if alive_in:
                    w = window(g_in)
                    inner[w] = ndimage.binary_dilation(inner[w], structure=step_in)
                if alive_out:
                    w = window(g_out)
                    outer[w] = ndimage.binary_dilation(outer[w], structure=step_out)
        a0, a1, b0, b1, d = boxes[i]
        if alive_in:
            inner[a0:a1, b0:b1] &= ~(d < d_c)
        if alive_out:
            outer[a0:a1, b0:b1] &= ~(d < d_c - half)
        w = window(0)
        if alive_in and (inner[w] & (last_pt[w] <= i)).any():
            return True  # a real path reaches a point no later disk covers
        if alive_out and not outer[w].any():
            return False  # not even the over-approximation survives
        if alive_out and (outer[w] & (last_cell[w] <= i)).any():
            alive_out = False  # the over-approximation may escape: it proves nothing
        if alive_in and not inner[w].any():
            alive_in = False
        if not (alive_in or alive_out):
            return None
    return None


def avoidable(
    p0: np.ndarray, q: np.ndarray, k: np.ndarray, v_max: float, dt: float, d_c: float
) -> tuple[bool | None, str]:
    """Whether a point robot at ``p0`` at frame 0 (speed <= ``v_max``, frames ``dt``
    apart) can keep a centre distance >= ``d_c`` from a pedestrian at ``q[i]`` at frame
    ``k[i]`` (k > 0 increasing; frames where the pedestrian is absent are left out).

    Parameters
    ----------
    p0 : ndarray of shape (2,)
        The robot's position at frame 0 (m).
    q : ndarray of shape (K, 2)
        The pedestrian's positions (m).
    k : ndarray of int, shape (K,)
        Their frames (> 0, increasing).
    v_max : float
        The robot's speed bound (m/s).
    dt : float
        Seconds between frames.
    d_c : float
        The collision distance (m).

    Returns
    -------
    (bool or None, str)
        True (a path was found), False (no path exists) or None (undecided), and which
        test decided (``covered``, ``straight``, ``grid`` or ``undecided``).
    """
    p0 = np.asarray(p0, dtype=float)
    q = np.asarray(q, dtype=float).reshape(-1, 2)
    k = np.asarray(k, dtype=np.int64)
    if k.size == 0:
        return True, "straight"
    r = float(v_max) * float(dt)
    reach = r * k
    if (np.hypot(*(q - p0).T) + reach < d_c).any():
        return False, "covered"
    if _straight(p0, q, k, r, d_c):
        return True, "straight"
    if r <= 0:
        return False, "covered"
    h = _H_FRACTION * r
    for _ in range(_REFINE + 1):
        verdict = _grid(p0, q, k, r, d_c, h)
        if verdict is not None:
            return verdict, "grid"
        h /= 2
    return None, "undecided"


# ------------------------------------------------------------------ the episode
def _velocity(positions: np.ndarray, f: int, j: int, fps: float) -> np.ndarray:
    """Velocity of track ``j`` at frame ``f`` (central difference, one-sided at the end of
    a run of finite samples, 0 for an isolated sample), m/s."""
    p = positions[:, j]
    n = p.shape[0]
    ok = np.isfinite(p[:, 0])
    prev = f > 0 and bool(ok[f - 1])
    nxt = f + 1 < n and bool(ok[f + 1])
    if prev and nxt:
        out: np.ndarray = 0.5 * (p[f + 1] - p[f - 1]) * fps
    elif nxt:
        out = (p[f + 1] - p[f]) * fps
    elif prev:
        out = (p[f] - p[f - 1]) * fps
    else:
        out = np.zeros(2)
    return out


def account_collisions(
    robot: np.ndarray,
    frames: np.ndarray,
    positions: np.ndarray,
    agent_ids: np.ndarray,
    *,
    fps: float,
    collision_distance: float,
    sensing_radius: float,
    v_max: float,
    sample_every: int,
) -> CollisionAccount:
    """Find and classify the collision events of an episode (see the module docstring).

    Parameters
    ----------
    robot : ndarray of shape (F, 4)
        The robot's logged state (x, y, vx, vy; m and m/s) at each logged frame.
    frames : ndarray of shape (F,)
        Index of each logged frame in ``positions`` (consecutive).
    positions : ndarray of shape (N, M, 2)
        Pedestrian positions per frame (m; NaN where absent): the replayed recording or
        the simulated crowd.
    agent_ids : ndarray of shape (M,)
    fps : float
        Frame rate (1/s).
    collision_distance : float
        d_c (m).
    sensing_radius : float
        The sensor's range (m).
    v_max : float
        The robot's speed bound (m/s).
    sample_every : int
        Frames between sampling times (the first logged frame is one).
    """
    robot = np.asarray(robot, dtype=float)
    frames = np.asarray(frames, dtype=np.int64)
    d_c = float(collision_distance)
    n_f = frames.size
    empty = CollisionAccount([], 0, 0, 0, 0, 0, 0, 0, None)
    if n_f == 0:
        return empty
    pos = np.asarray(positions, dtype=float)[frames]  # (F, M, 2)
    present = np.isfinite(pos[..., 0])
    with np.errstate(invalid="ignore"):
        dist = np.hypot(pos[..., 0] - robot[:, 0, None], pos[..., 1] - robot[:, 1, None])
    dist = np.where(present, dist, np.inf)
    close = dist < d_c
    hit = np.asarray(close.any(axis=1), dtype=bool)
    if not hit.any():
        return empty
    nearest = np.argmin(dist, axis=1)
    dt = 1.0 / float(fps)
    t = np.arange(n_f) * dt
    sampling = (np.arange(n_f) % int(sample_every)) == 0
    visible = present & (dist <= sensing_radius)
    sensed = visible & sampling[:, None]
    all_pos = np.asarray(positions, dtype=float)
    events: list[CollisionEvent] = []
    frame_event = np.full(n_f, -1)  # the event of each collision frame's nearest pedestrian
    for j in np.flatnonzero(close.any(axis=0)).tolist():
        col = close[:, j]
        edges = np.flatnonzero(np.diff(np.concatenate([[0], col.astype(np.int8), [0]])))
        for a, b in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
            e_idx = len(events)
            mine = np.arange(a, b)
            attributed = mine[hit[mine] & (nearest[mine] == j)]
            frame_event[attributed] = e_idx
            d_min = float(dist[a:b, j].min())
            u = pos[a, j] - robot[a, :2]
            norm = float(np.hypot(*u))
            u = u / norm if norm > 0 else np.zeros(2)
            rc = float(robot[a, 2:] @ u)
            pc = float(-(_velocity(all_pos, int(frames[a]), j, fps) @ u))
            closing = ("neither", "robot", "pedestrian", "both")[
                int(rc > CLOSING_TOL) + 2 * int(pc > CLOSING_TOL)
            ]
            vis = np.flatnonzero(visible[:b, j])
            t_vis = None if not vis.size else float(t[vis[0]])
            popin = bool(
                vis.size
                and (dist[vis[0], j] < d_c + POPIN_MARGIN_M or (a - vis[0]) * dt < POPIN_TIME_S)
            )
            sen = np.flatnonzero(sensed[:b, j])
            if not sen.size or sen[0] >= a:
                verdict: bool | None = False
                how = "unsensed"
                t_sen = None if not sen.size else float(t[sen[0]])
            else:
                k0 = int(sen[0])
                later = np.arange(k0 + 1, b)
                keep = present[later, j]
                verdict, how = avoidable(
                    robot[k0, :2], pos[later[keep], j], later[keep] - k0, v_max, dt, d_c
                )
                t_sen = float(t[k0])
            events.append(
                CollisionEvent(
                    agent=int(agent_ids[j]),
                    t_start=float(t[a]),
                    t_end=float(t[b - 1]),
                    frames=int(b - a),
                    frames_attributed=int(attributed.size),
                    d_min=d_min,
                    penetration=d_c - d_min,
                    robot_closing=rc,
                    pedestrian_closing=pc,
                    closing=closing,
                    popin=popin,
                    t_visible=t_vis,
                    t_sensed=t_sen,
                    avoidable=verdict,
                    decided_by=how,
                )
            )
    cf = np.flatnonzero(hit)
    ev = [events[i] for i in frame_event[cf].tolist()]
    n_avoid = sum(1 for e in ev if e.avoidable is True and not e.popin)
    n_unavoid = sum(1 for e in ev if e.avoidable is False and not e.popin)
    n_undecided = sum(1 for e in ev if e.avoidable is None and not e.popin)
    # the robot's velocity toward its nearest pedestrian at each collision frame
    near = nearest[cf]
    rel = pos[cf, near] - robot[cf, :2]
    norm = np.hypot(rel[:, 0], rel[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        toward = np.where(norm > 0, (robot[cf, 2:] * rel).sum(axis=1) / norm, 0.0)
    return CollisionAccount(
        events=events,
        n_collide=int(cf.size),
        n_collision_events=len(events),
        n_collide_avoidable=n_avoid,
        n_collide_unavoidable=n_unavoid,
        n_collide_undecided=n_undecided,
        n_collide_at_fault=int((toward > CLOSING_TOL).sum()),
        n_collide_popin=sum(1 for e in ev if e.popin),
        penetration_max=float(d_c - dist[cf, near].min()),
    )
