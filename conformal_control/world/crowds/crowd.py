"""The pedestrians of a scene, simulated by a crowd model and seeded from the recording.

A :class:`Crowd` turns the recorded tracks of a :class:`~conformal_control.data.scene.Scene`
into simulated pedestrians, frame by frame, around a robot it is told about at every
step:

* **Seeding.** A pedestrian starts at its recorded position with its recorded velocity
  (a backward difference over ``velocity_window`` seconds), either at the robot's start
  frame or, if it enters later, at its first recorded frame.
* **Where it walks.** Its own track, subsampled every ``waypoint_interval`` seconds (and
  its last recorded position), is its route *and its schedule*: at time ``t`` it heads
  for the first waypoint recorded at least one interval after ``t`` at the speed that
  would reach it on time (so that, unhindered, it walks as recorded, stops included),
  bounded by ``v_max = max(max_speed_factor * v0, min_max_speed)`` with ``v0`` its mean
  recorded speed (Helbing & Molnár 1995 bound the speed at 1.3 times the desired one;
  the floor lets a pedestrian who stood still in the recording step out of the way).
  Once its recording is over it walks on to its last recorded position at ``v0`` and
  leaves the scene there (within ``arrival_radius``), or ``max_delay`` seconds after
  its recording ended at the latest (counted in ``n_late_``).
* **Who it sees.** Every other simulated pedestrian, the robot (radius the scene's
  ``robot_radius``, its velocity as driven by the controller) and, in mixed mode, the
  pedestrians still replayed (their recorded velocity); the model moves none of those.
* **Mixed mode** (``mixed_radius`` set). Every pedestrian is replayed from the recording
  until the robot comes within ``mixed_radius`` of it (centre distance, checked at every
  control instant against its recorded position interpolated between frames); it then
  switches to the model from its recorded position and velocity for the rest of the
  episode. A pedestrian never that close follows the recording exactly (bit for bit).

Positions are in metres, times in seconds (frames only where named so).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...core import registry
from ...core.base import Plugin
from .base import CrowdModel

__all__ = ["Crowd", "build_model", "model_names"]


def model_names() -> list[str]:
    """The registered crowd models (the ``crowd`` role: ``conformal-control plugins``)."""
    return registry.names("crowd")


REPLAY, ACTIVE, GONE = 0, 1, 2


def build_model(model: CrowdModel | str, model_params: dict[str, Any] | None = None) -> CrowdModel:
    """A crowd model from a registered name (with parameters) or an instance."""
    params = dict(model_params or {})
    if isinstance(model, CrowdModel):
        if params:
            raise ValueError(
                "model_params apply to a model given by name; set the parameters of a model "
                "instance on the instance"
            )
        return model
    if not isinstance(model, str):
        raise ValueError(
            f"a crowd model must be a registered name ({', '.join(model_names())}) or a "
            f"CrowdModel instance, got {model!r}"
        )
    cls = registry.get("crowd", model)  # an unknown name: the known ones, did you mean
    registry.check_params("crowd", model, cls, params)
    built: CrowdModel = cls(**params)
    return built


class Crowd(Plugin):
    """Recorded pedestrians turned into agents of a crowd model (see the module docstring).

    Parameters
    ----------
    model : str or CrowdModel
        ``"social_force"``, ``"orca"`` or a model instance.
    model_params : dict, optional
        Constructor parameters of a model given by name.
    mixed_radius : float, optional
        Mixed mode: a pedestrian is replayed until the robot comes within this distance
        (m); None (default) simulates every pedestrian from the start frame.
    body_radius : float
        Pedestrians' body radius (m) for the models that use one (ORCA). 0.3 m, within
        the 0.25-0.35 m of Helbing, Farkas & Vicsek (2000) and as in CrowdNav.
    waypoint_interval : float
        Spacing (s) of the waypoints taken from each recorded track.
    velocity_window : float
        Window (s) of the backward difference giving a recorded velocity.
    max_speed_factor : float
        Speed bound as a multiple of the mean recorded speed (Helbing & Molnár 1995: 1.3).
    min_max_speed : float
        Floor of the speed bound (m/s).
    arrival_radius : float
        A pedestrian past the end of its recording leaves the scene within this distance
        (m) of its last recorded position.
    max_delay : float
        ... or this many seconds after its recording ended, whichever comes first.
    seed : int
        Seed of the generator handed to the model (used by noisy models only).
    """

    def __init__(
        self,
        model: CrowdModel | str = "social_force",
        model_params: dict[str, Any] | None = None,
        *,
        mixed_radius: float | None = None,
        body_radius: float = 0.3,
        waypoint_interval: float = 1.0,
        velocity_window: float = 0.4,
        max_speed_factor: float = 1.3,
        min_max_speed: float = 1.0,
        arrival_radius: float = 0.5,
        max_delay: float = 10.0,
        seed: int = 0,
    ) -> None:
        self.model = model
        self.model_params = model_params
        self.mixed_radius = mixed_radius
        self.body_radius = body_radius
        self.waypoint_interval = waypoint_interval
        self.velocity_window = velocity_window
        self.max_speed_factor = max_speed_factor
        self.min_max_speed = min_max_speed
        self.arrival_radius = arrival_radius
        self.max_delay = max_delay
        self.seed = seed

    # ------------------------------------------------------------------ set-up
    def validate(self) -> None:
        """Check the crowd's parameters (``ValueError`` naming the bad one): the
        construction-time check of :func:`~conformal_control.world.reactive.make_environment`,
        so a bad value fails before a run starts rather than mid-run."""
        self._validate()

    def _validate(self) -> None:
        for name in (
            "body_radius",
            "waypoint_interval",
            "velocity_window",
            "max_speed_factor",
            "min_max_speed",
            "arrival_radius",
            "max_delay",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise ValueError(f"{name} must be a number, got {v!r}")
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")
        r = self.mixed_radius
        if r is not None and (
            isinstance(r, bool)
            or not isinstance(r, (int, float, np.integer, np.floating))
            or not (math.isfinite(r) and r > 0)
        ):
            raise ValueError(f"mixed_radius must be None or a finite number > 0, got {r!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)):
            raise ValueError(f"seed must be an integer, got {self.seed!r}")

    @property
    def mixed(self) -> bool:
        return self.mixed_radius is not None

    def reset(
        self,
        positions: np.ndarray,
        fps: float,
        start_index: int,
        substeps: int,
        robot_radius: float,
    ) -> None:
        """Seed the crowd from a recording; the episode starts at ``start_index``.

        Parameters
        ----------
        positions : ndarray of shape (F, M, 2)
            The recording (m), NaN where a pedestrian is absent. Not modified.
        fps : float
            Its frame rate.
        start_index : int
            Frame the robot starts at.
        substeps : int
            Model steps per frame (one per control instant).
        robot_radius : float
            Radius (m) of the robot as the pedestrians see it.
        """
        self._validate()
        self.model_ = build_model(self.model, self.model_params)
        self.model_.reset(np.random.default_rng(self.seed))
        self.recording_ = positions
        self.fps_ = float(fps)
        self.substeps_ = int(substeps)
        self.dt_ = 1.0 / (self.fps_ * self.substeps_)
        self.robot_radius_ = float(robot_radius)
        m = positions.shape[1]
        self._plan(positions)
        self.status_ = np.full(m, REPLAY, dtype=np.int8)
        self.pos_ = np.full((m, 2), np.nan)
        self.vel_ = np.full((m, 2), np.nan)
        self.switched_at_ = np.full(m, -1, dtype=np.int64)  # frame of the switch (-1: never)
        self.n_late_ = 0
        self.n_left_ = 0
        if not self.mixed:
            self._enter(start_index)

    def _plan(self, positions: np.ndarray) -> None:
        """Waypoints, schedules, mean speeds and recorded velocities of every track."""
        f, m, _ = positions.shape
        fps = self.fps_
        step = max(1, round(self.waypoint_interval * fps))
        self.lookahead_ = float(step)  # frames
        finite = np.isfinite(positions[..., 0])
        times: list[np.ndarray] = []
        points: list[np.ndarray] = []
        v0 = np.zeros(m)
        for j in range(m):
            idx = np.flatnonzero(finite[:, j])
            if idx.size == 0:
                times.append(np.zeros(0, dtype=np.int64))
                points.append(np.zeros((0, 2)))
                continue
            b = (idx - idx[0]) // step
            sel = idx[np.r_[True, b[1:] != b[:-1]]]
            if sel[-1] != idx[-1]:
                sel = np.r_[sel, idx[-1]]
            pts = positions[sel, j]
            times.append(sel)
            points.append(pts)
            if sel.size > 1:
                length = np.hypot(*np.diff(pts, axis=0).T).sum()
                v0[j] = length * fps / (sel[-1] - sel[0])
        w = max((t.size for t in times), default=0)
        self.wp_time_ = np.full((m, max(w, 1)), np.inf)
        self.wp_pos_ = np.zeros((m, max(w, 1), 2))
        self.wp_count_ = np.array([t.size for t in times], dtype=np.int64)
        for j, (t, p) in enumerate(zip(times, points, strict=True)):
            self.wp_time_[j, : t.size] = t
            self.wp_pos_[j, : t.size] = p
        last = np.maximum(self.wp_count_ - 1, 0)
        self.exit_ = np.where(self.wp_count_ > 0, self.wp_time_[np.arange(m), last], -1.0)
        self.final_ = self.wp_pos_[np.arange(m), last]
        self.v0_ = v0
        self.v_max_ = np.maximum(self.max_speed_factor * v0, self.min_max_speed)
        # recorded velocities: backward difference, forward where no past, 0 where alone
        k = max(1, round(self.velocity_window * fps))
        vel = np.full_like(positions, np.nan)
        if f > k:
            vel[k:] = (positions[k:] - positions[:-k]) * (fps / k)
            fwd = (positions[k:] - positions[:-k]) * (fps / k)
            hole = np.isnan(vel[:-k, :, 0])
            vel[:-k][hole] = fwd[hole]
        vel[np.isnan(vel)] = 0.0
        self.rec_vel_ = vel

    def _activate(self, cols: np.ndarray, pos: np.ndarray, frame: int) -> None:
        self.status_[cols] = ACTIVE
        self.pos_[cols] = pos
        self.vel_[cols] = self.rec_vel_[frame, cols]
        self.switched_at_[cols] = frame

    def _enter(self, frame: int) -> None:
        """Full mode: pedestrians present in the recording at ``frame`` join the model."""
        rec = self.recording_[frame]
        cols = np.flatnonzero((self.status_ == REPLAY) & np.isfinite(rec[:, 0]))
        if cols.size:
            self._activate(cols, rec[cols], frame)

    # ------------------------------------------------------------------ running
    def _replayed(self, frame: int, sub: int) -> tuple[np.ndarray, np.ndarray]:
        """Replayed pedestrians present at ``frame``: columns and positions at the instant."""
        rec = self.recording_
        cols = np.flatnonzero((self.status_ == REPLAY) & np.isfinite(rec[frame, :, 0]))
        p = rec[frame, cols]
        if sub and frame + 1 < rec.shape[0]:
            nxt = rec[frame + 1, cols]
            a = sub / self.substeps_
            ok = np.isfinite(nxt[:, 0])
            p = p.copy()
            p[ok] = (1.0 - a) * p[ok] + a * nxt[ok]
        return cols, p

    def _preferred(self, cols: np.ndarray, t: float) -> np.ndarray:
        """Preferred velocities (m/s) of the active pedestrians ``cols`` at frame time t."""
        pos = self.pos_[cols]
        times = self.wp_time_[cols]
        count = self.wp_count_[cols]
        k = (times < t + self.lookahead_).sum(axis=1)
        over = k >= count  # within one interval of the end: head for the last waypoint
        k = np.minimum(k, count - 1)
        target = self.wp_pos_[cols, k]
        remaining = np.maximum(times[np.arange(cols.size), k] - t, self.lookahead_)
        d = target - pos
        v = d * (self.fps_ / remaining)[:, None]
        ended = over & (t >= self.exit_[cols])
        if ended.any():  # past its recording: on at the mean speed to where it left
            dist = np.hypot(d[ended, 0], d[ended, 1])
            unit = d[ended] / np.where(dist > 0, dist, 1.0)[:, None]
            v[ended] = unit * self.v0_[cols[ended], None]
        speed = np.hypot(v[:, 0], v[:, 1])
        vmax = self.v_max_[cols]
        fast = speed > vmax
        v[fast] *= (vmax[fast] / speed[fast])[:, None]
        out: np.ndarray = v
        return out

    def step(self, frame: int, sub: int, robot_pos: np.ndarray, robot_vel: np.ndarray) -> None:
        """Advance the crowd by one control instant (``1 / (fps * substeps)`` seconds).

        Parameters
        ----------
        frame, sub : int
            The instant: ``sub`` control instants after the recording's frame ``frame``.
        robot_pos, robot_vel : ndarray of shape (2,) or (R, 2)
            The robot's (or the R robots') position (m) and velocity (m/s) at that instant.
        """
        robot_pos = np.asarray(robot_pos, dtype=float).reshape(-1, 2)
        robot_vel = np.asarray(robot_vel, dtype=float).reshape(-1, 2)
        if not self.mixed and sub == 0:
            self._enter(frame)
        rep_cols, rep_pos = self._replayed(frame, sub)
        if self.mixed and rep_cols.size:
            dx = rep_pos[:, None, 0] - robot_pos[None, :, 0]
            dy = rep_pos[:, None, 1] - robot_pos[None, :, 1]
            near = np.hypot(dx, dy).min(axis=1) <= self.mixed_radius
            if near.any():
                self._activate(rep_cols[near], rep_pos[near], frame)
                rep_cols, rep_pos = rep_cols[~near], rep_pos[~near]
        act = np.flatnonzero(self.status_ == ACTIVE)
        if act.size == 0:
            return
        t = frame + sub / self.substeps_
        v_pref = self._preferred(act, t)
        other_pos = np.vstack([robot_pos, rep_pos])
        other_vel = np.vstack([robot_vel, self.rec_vel_[frame, rep_cols]])
        other_rad = np.r_[
            np.full(robot_pos.shape[0], self.robot_radius_),
            np.full(rep_cols.size, self.body_radius),
        ]
        pos, vel = self.model_.step(
            self.pos_[act],
            self.vel_[act],
            np.full(act.size, float(self.body_radius)),
            v_pref,
            self.v_max_[act],
            other_pos,
            other_vel,
            other_rad,
            self.dt_,
        )
        self.pos_[act] = pos
        self.vel_[act] = vel
        # pedestrians past their recording leave where it left them (or too late)
        t_next = t + 1.0 / self.substeps_
        ended = t_next >= self.exit_[act]
        if ended.any():
            cols = act[ended]
            arrived = np.hypot(*(self.pos_[cols] - self.final_[cols]).T) <= self.arrival_radius
            late = ~arrived & (t_next - self.exit_[cols] > self.max_delay * self.fps_)
            gone = cols[arrived | late]
            self.status_[gone] = GONE
            self.pos_[gone] = np.nan
            self.vel_[gone] = np.nan
            self.n_left_ += int(arrived.sum())
            self.n_late_ += int(late.sum())

    def frame_positions(self, frame: int) -> np.ndarray:
        """Positions (M, 2) at the recording's ``frame`` (the crowd must be there).

        Replayed pedestrians are copied from the recording (bit for bit), simulated ones
        come from the model, those who left are NaN.
        """
        out: np.ndarray = self.recording_[frame].copy()
        act = self.status_ == ACTIVE
        out[act] = self.pos_[act]
        out[self.status_ == GONE] = np.nan
        return out

    # Crowd is no registered role: its summary() reports the episode's counters instead
    # of Plugin.summary()'s one-line class description (kept: callers and tests use it)
    def summary(self) -> dict[str, Any]:  # type: ignore[override]
        """Counters of the episode so far (JSON-ready)."""
        return {
            "n_simulated": int((self.switched_at_ >= 0).sum()),
            "n_replayed_throughout": int((self.switched_at_ < 0).sum()),
            "n_left": int(self.n_left_),
            "n_late": int(self.n_late_),
        }
