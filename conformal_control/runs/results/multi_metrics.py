"""Metrics of a multi-robot run: per robot, robot-robot contacts, and the fleet's aggregate.

Each robot is measured as a single robot is
(:class:`~conformal_control.runs.results.metrics.EpisodeMetrics`, with ``d_min`` and ``n_collide``
about *pedestrians*), plus :class:`RobotContacts` about the *other robots*. A robot's
``success`` requires its goal and no collision of either kind.

Counting conventions (frames are video frames, counted while the robot is under way, i.e.
until it reaches its last goal or the run ends):

* robot-pedestrian collision frame: centre distance to a pedestrian < robot radius +
  pedestrian radius (as for one robot);
* robot-robot collision frame: centre distance to another robot < 2 robot radii;
* fleet robot-robot *pair-frames*: pairs (i < j) in contact in a frame while at least one
  of the two is under way, each pair counted once (not once per robot);
* a robot-pedestrian collision frame is **robot-nearby** when another robot (under way or
  parked at its goal) is within :data:`ROBOT_NEAR_M` of the hit robot in that frame (the
  fleet's spacing: a contact the other robots may have pushed it into), and **avoidable**
  as for one robot (:mod:`~conformal_control.runs.results.collisions`: a point robot with the
  same speed bound could have kept away from that pedestrian since first sensing it;
  pop-ins never count as avoidable);
* **makespan**: the time the last robot reached its goal (None when one never did);
* **deadlock** (:class:`DeadlockRule`): a robot under way whose *remaining path* (distance
  to its current goal plus the legs after it) has not fallen below its smallest value so
  far by more than ``progress`` metres for ``seconds`` seconds: it stopped making progress
  (stuck face to face with another robot, behind a parked one, or oscillating in place).
  A robot that waits that long for pedestrians to pass counts too; the time of the first
  such frame is its ``t_deadlock``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from .metrics import EpisodeMetrics, MetricsTable, plain
from .metrics import metric as _m

__all__ = [
    "ROBOT_NEAR_M",
    "DeadlockRule",
    "FleetMetrics",
    "RobotContacts",
    "deadlocks",
    "fleet_metrics",
    "remaining_paths",
    "robot_contacts",
]


#: Distance (m) within which another robot makes a pedestrian contact "robot-nearby" (the
#: multi-robot benchmark's spacing between neighbouring robots).
ROBOT_NEAR_M = 2.5


@dataclass(frozen=True)
class DeadlockRule:
    """When a robot counts as deadlocked (see the module docstring).

    Parameters
    ----------
    seconds : float
        How long without progress (s, > 0).
    progress : float
        The least decrease of the remaining path that counts as progress (m, > 0).
    """

    seconds: float = 5.0
    progress: float = 0.25

    def __post_init__(self) -> None:
        for name in ("seconds", "progress"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"deadlock {name} must be a finite number > 0, got {v!r}")


@dataclass
class RobotContacts:
    """One robot's encounters with the other robots (until its goal or the end)."""

    n_collide_robot: int = _m("-", "frames with another robot closer than 2 robot radii", 0)
    any_robot_collision: bool = _m("-", "at least one robot-robot collision frame", False)
    d_min_robot: float | None = _m("m", "smallest centre distance to another robot")
    t_deadlock: float | None = _m("s", "first time it had made no progress for a while")
    n_collide_pedestrian_robot_near: int = _m(
        "-", "pedestrian collision frames with another robot within ROBOT_NEAR_M", 0
    )

    def as_dict(self) -> dict[str, Any]:
        return {f.name: plain(getattr(self, f.name)) for f in dataclasses.fields(self)}


def robot_contacts(
    d_min_robot: Sequence[float],
    robot_radius: float,
    t_deadlock: float | None = None,
    *,
    d_min_pedestrian: Sequence[float] | np.ndarray | None = None,
    collision_distance: float | None = None,
) -> RobotContacts:
    """:class:`RobotContacts` from a robot's per-frame distance to the nearest other robot
    (and the time it deadlocked, :func:`deadlocks`).

    Parameters
    ----------
    d_min_robot : sequence of float
        Per logged frame, the centre distance to the nearest other robot (m; NaN alone).
    robot_radius : float
        The robots' radius (m).
    t_deadlock : float, optional
        When it deadlocked (s).
    d_min_pedestrian : sequence of float, optional
        Per logged frame (the same frames), the centre distance to the nearest pedestrian
        (m; NaN: none present): with ``collision_distance``, the robot's pedestrian
        collision frames, of which those with another robot within :data:`ROBOT_NEAR_M`
        are counted.
    collision_distance : float, optional
        The robot-pedestrian collision distance (m).
    """
    d = np.asarray(d_min_robot, dtype=float)
    near = 0
    with np.errstate(invalid="ignore"):
        n = int(np.sum(d < 2.0 * robot_radius))
        if d_min_pedestrian is not None and collision_distance is not None:
            p = np.asarray(d_min_pedestrian, dtype=float)
            if p.shape != d.shape:
                raise ValueError(f"d_min_pedestrian has {p.size} frames but d_min_robot {d.size}")
            near = int(np.sum((p < collision_distance) & (d < ROBOT_NEAR_M)))
    return RobotContacts(
        n_collide_robot=n,
        any_robot_collision=n > 0,
        d_min_robot=float(np.nanmin(d)) if np.isfinite(d).any() else None,
        t_deadlock=t_deadlock,
        n_collide_pedestrian_robot_near=near,
    )


def remaining_paths(
    track: np.ndarray, goals: Sequence[np.ndarray], goal_radius: float
) -> np.ndarray:
    """Each robot's remaining path at each frame (m), shape (F, R): distance to its current
    goal plus the legs after it, the current goal advancing once within ``goal_radius``
    (NaN where the position is unknown).

    Parameters
    ----------
    track : ndarray of shape (F, R, 2)
        Positions at each frame (m).
    goals : sequence of R arrays of shape (G_i, 2)
    goal_radius : float
    """
    x = np.asarray(track, dtype=float)
    f, r = x.shape[:2]
    out = np.full((f, r), np.nan)
    for i in range(r):
        g = np.asarray(goals[i], dtype=float).reshape(-1, 2)
        legs = np.r_[np.hypot(*np.diff(g, axis=0).T)[::-1].cumsum()[::-1], 0.0]
        k = 0
        for t in range(f):
            p = x[t, i]
            if not np.isfinite(p).all():
                continue
            while k < len(g) - 1 and math.hypot(*(p - g[k])) <= goal_radius:
                k += 1
            out[t, i] = math.hypot(*(p - g[k])) + legs[k]
    return out


def deadlocks(
    remaining: np.ndarray, active: np.ndarray, fps: float, rule: DeadlockRule
) -> list[float | None]:
    """Per robot, the first time (s since the first frame) it had been under way for
    ``rule.seconds`` without its remaining path falling ``rule.progress`` below its
    smallest value so far (None: never).

    Parameters
    ----------
    remaining : ndarray of shape (F, R)
        :func:`remaining_paths`.
    active : ndarray of shape (F, R)
        Whether each robot was under way.
    fps : float
        Frames per second of the track.
    rule : DeadlockRule
    """
    rem = np.asarray(remaining, dtype=float)
    act = np.asarray(active, dtype=bool)
    window = max(round(rule.seconds * fps), 1)
    out: list[float | None] = []
    for i in range(rem.shape[1]):
        mark = math.inf  # the smallest remaining path at the last progress
        since = 0  # the frame of the last progress
        found = None
        for t in range(rem.shape[0]):
            v = rem[t, i]
            if not act[t, i] or not math.isfinite(v):
                continue
            if not math.isfinite(mark) or v <= mark - rule.progress:
                mark, since = v, t
            elif t - since >= window:
                found = t / fps
                break
        out.append(found)
    return out


@dataclass
class FleetMetrics(MetricsTable):
    """What a multi-robot run measured over all its robots (see each field's metadata)."""

    n_robots: int = _m("-", "robots", 0)
    n_goal_reached: int = _m("-", "robots that reached their last goal", 0)
    goal_rate: float = _m("-", "n_goal_reached / n_robots", 0.0)
    n_success: int = _m("-", "robots with their goal and no collision of either kind", 0)
    success_rate: float = _m("-", "n_success / n_robots", 0.0)
    n_collide_pedestrian: int = _m("-", "robot-pedestrian collision frames, summed over robots", 0)
    n_collide_pedestrian_avoidable: int = _m(
        "-", "of them, frames of avoidable events (no pop-in), summed over robots", 0
    )
    n_collide_pedestrian_robot_near: int = _m(
        "-", "of them, frames with another robot within ROBOT_NEAR_M of the hit robot", 0
    )
    n_robots_hit_pedestrian: int = _m("-", "robots with a robot-pedestrian collision frame", 0)
    n_collide_robot_pairs: int = _m("-", "robot-robot collision pair-frames (each pair once)", 0)
    n_robots_hit_robot: int = _m("-", "robots with a robot-robot collision frame", 0)
    d_min_pedestrian: float | None = _m("m", "smallest robot-pedestrian centre distance")
    d_min_robot: float | None = _m("m", "smallest robot-robot centre distance")
    t_goal_mean: float | None = _m("s", "mean time to goal over the robots that reached it")
    makespan: float | None = _m("s", "time the last robot reached its goal (None if one never did)")
    n_deadlocked: int = _m("-", "robots that stopped making progress (DeadlockRule)", 0)
    path_length_mean: float | None = _m("m", "mean path length")
    time_in_personal_space: float = _m("s", "robot-pedestrian personal-space time, summed", 0.0)
    l_avg_mean: float | None = _m("-", "mean over robots of their average loss")
    lambda_final_mean: float | None = _m("lambda", "mean over robots of their final lambda")
    lambda_final_min: float | None = _m("lambda", "smallest final lambda")
    lambda_final_max: float | None = _m("lambda", "largest final lambda")
    n_fallback: int = _m("-", "control instants decided by a fallback, summed", 0)
    n_qp_solves: int = _m("-", "solver calls, summed", 0)
    n_steps: int = _m("-", "control instants decided, summed over robots", 0)
    frames: int = _m("-", "video frames simulated", 0)
    wall_s: float = _m("s", "wall time of the whole run's loop", 0.0)
    wall_s_per_robot: float = _m("s", "wall_s / n_robots", 0.0)
    cpu_s: float = _m("s", "process CPU time of the loop", 0.0)
    units: dict[str, str] | None = _m("-", "unit of each metric")  # noqa: RUF009 (a field)

    SUMMARY: ClassVar[tuple[str, ...]] = (
        "n_robots",
        "goal_rate",
        "success_rate",
        "n_collide_pedestrian",
        "n_collide_pedestrian_avoidable",
        "n_collide_pedestrian_robot_near",
        "n_robots_hit_pedestrian",
        "n_collide_robot_pairs",
        "n_robots_hit_robot",
        "d_min_pedestrian",
        "d_min_robot",
        "t_goal_mean",
        "makespan",
        "n_deadlocked",
        "l_avg_mean",
        "lambda_final_mean",
        "n_fallback",
        "frames",
        "wall_s",
        "wall_s_per_robot",
    )


def _mean(values: list[float | None]) -> float | None:
    v = [x for x in values if x is not None and math.isfinite(x)]
    return float(np.mean(v)) if v else None


def fleet_metrics(
    robots: Sequence[EpisodeMetrics],
    contacts: Sequence[RobotContacts],
    *,
    robot_track: np.ndarray,
    active: np.ndarray,
    robot_radius: float,
    frames: int,
    wall_s: float,
    lam_unit_name: str,
    cpu_s: float = 0.0,
) -> FleetMetrics:
    """Aggregate the robots' metrics.

    Parameters
    ----------
    robots, contacts
        Per robot, its :class:`EpisodeMetrics` and :class:`RobotContacts`.
    robot_track : ndarray of shape (F, R, 2)
        Robot positions at each simulated frame.
    active : ndarray of shape (F, R)
        Whether each robot was under way at each frame.
    robot_radius : float
    frames : int
        Video frames simulated.
    wall_s : float
    lam_unit_name : str
    cpu_s : float
        Unit of lambda (scene units) for the report.
    """
    n = len(robots)
    reached = [m.goal_reached for m in robots]
    success = [
        bool(m.goal_reached and m.n_collide == 0 and c.n_collide_robot == 0)
        for m, c in zip(robots, contacts, strict=True)
    ]
    pairs = 0
    x = np.asarray(robot_track, dtype=float)
    if n > 1 and x.size:
        d = np.hypot(x[:, :, None, 0] - x[:, None, :, 0], x[:, :, None, 1] - x[:, None, :, 1])
        act = np.asarray(active, dtype=bool)
        either = act[:, :, None] | act[:, None, :]
        upper = np.triu(np.ones((n, n), dtype=bool), k=1)
        with np.errstate(invalid="ignore"):
            pairs = int(np.sum((d < 2.0 * robot_radius) & either & upper[None]))
    d_ped = [m.d_min for m in robots if m.d_min is not None]
    d_rob = [c.d_min_robot for c in contacts if c.d_min_robot is not None]
    t_goals = [m.t_goal for m in robots if m.t_goal is not None]
    finals = [m.lambda_final for m in robots if m.lambda_final is not None]
    units = {
        f.name: (lam_unit_name if f.metadata["unit"] == "lambda" else f.metadata["unit"])
        for f in dataclasses.fields(FleetMetrics)
    }
    return FleetMetrics(
        n_robots=n,
        n_goal_reached=int(sum(reached)),
        goal_rate=sum(reached) / n if n else 0.0,
        n_success=int(sum(success)),
        success_rate=sum(success) / n if n else 0.0,
        n_collide_pedestrian=int(sum(m.n_collide for m in robots)),
        n_collide_pedestrian_avoidable=int(sum(m.n_collide_avoidable for m in robots)),
        n_collide_pedestrian_robot_near=int(
            sum(c.n_collide_pedestrian_robot_near for c in contacts)
        ),
        n_robots_hit_pedestrian=int(sum(m.n_collide > 0 for m in robots)),
        n_collide_robot_pairs=pairs,
        n_robots_hit_robot=int(sum(c.n_collide_robot > 0 for c in contacts)),
        d_min_pedestrian=min(d_ped) if d_ped else None,
        d_min_robot=min(d_rob) if d_rob else None,
        t_goal_mean=_mean(list(t_goals)),
        makespan=max(t_goals) if t_goals and len(t_goals) == n else None,
        n_deadlocked=int(sum(c.t_deadlock is not None for c in contacts)),
        path_length_mean=_mean([m.path_length for m in robots]),
        time_in_personal_space=float(sum(m.time_in_personal_space for m in robots)),
        l_avg_mean=_mean([m.l_avg for m in robots]),
        lambda_final_mean=_mean(list(finals)),
        lambda_final_min=min(finals) if finals else None,
        lambda_final_max=max(finals) if finals else None,
        n_fallback=int(sum(m.n_fallback for m in robots)),
        n_qp_solves=int(sum(m.n_qp_solves for m in robots)),
        n_steps=int(sum(m.n_steps for m in robots)),
        frames=int(frames),
        wall_s=float(wall_s),
        wall_s_per_robot=float(wall_s) / n if n else 0.0,
        cpu_s=float(cpu_s),
        units=units,
    )
