"""The reactive crowds of the batch engine's episodes, stepped together.

An episode of a reactive crowd (``social_force``, ``orca`` or ``mixed``) is built as the
per-episode loop builds it: a
:class:`~conformal_control.world.reactive.ReactiveEnvironment` whose
:class:`~conformal_control.world.crowds.crowd.Crowd` is reset with the scene (its plan: each
pedestrian's waypoints, schedule, speed bound and recorded velocities; the pedestrians
present at the start frame). :class:`CrowdSlots` copies that state into one row per slot
and steps every slot's crowd with :mod:`~conformal_control.runs.engines.crowd_kernels`.

Timing, as :meth:`ReactiveEnvironment.apply
<conformal_control.world.reactive.ReactiveEnvironment.apply>` has it: the crowd and the
robot move together over each control instant, each seeing the other's state at its start.
Within an interval the robot's control does not read the pedestrians (it reads the
predictions made at the sampling time), so the engine runs the interval's control instants
first (:func:`~conformal_control.runs.engines.interval.run_interval`) and then walks the crowds
through the same instants with the robot's recorded positions and velocities; each
completed frame is written to the slot's store (which the sensor, the predictors, the
frame log's ``d_min`` and the truth read), the frame log's ``d_min`` of the interval's
frames is recomputed from it, and the frames are copied into the environment's own buffer
(what the episode's own predictor, loss and measuring code read). An episode that ends
within a frame has the frame finished with the robot holding its last state, as
:meth:`ReactiveEnvironment.reveal
<conformal_control.world.reactive.ReactiveEnvironment.reveal>` does.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...world.crowds.crowd import Crowd
from ...world.crowds.orca import ORCAModel
from ...world.crowds.social_force import SocialForceModel
from ...world.reactive import ReactiveCursor, ReactiveEnvironment
from .crowd_kernels import (
    ORCA,
    SOCIAL_FORCE,
    crowd_begin,
    crowd_end,
    relog_d_min,
    sf_acceleration,
    sf_directions,
    sf_exponents,
)

__all__ = ["CrowdSlots", "unsupported_crowd"]

#: The crowd models the engine steps (their classes exactly: a subclass may step otherwise).
MODELS: dict[str, type] = {"social_force": SocialForceModel, "orca": ORCAModel}


def unsupported_crowd(crowd: str, params: dict[str, Any]) -> str | None:
    """Why the batch engine cannot run the reactive crowd ``crowd`` with ``params`` (a
    one-line reason), or None."""
    model = params.get("model", "social_force") if crowd == "mixed" else crowd
    if model not in MODELS:
        return (
            f"crowd {crowd!r}: the batch engine steps the social_force and orca crowd "
            "models (and replays recorded crowds)"
        )
    if float(params.get("noise", 0.0) or 0.0) != 0.0:
        return "crowd noise: the batch engine steps deterministic crowds only"
    nd = params.get("neighbor_dist", 10.0)
    if isinstance(nd, (int, float)) and not math.isfinite(nd):
        return "crowd neighbor_dist=inf: the batch engine searches neighbours in cells"
    return None


def _grown(arr: np.ndarray, shape: tuple[int, ...], fill: float = 0.0) -> np.ndarray:
    """``arr`` with at least ``shape`` (the new entries ``fill``), grown geometrically."""
    if all(a >= s for a, s in zip(arr.shape, shape, strict=True)):
        return arr
    # geometric growth of the axes that grow (amortised over the scenes of a batch)
    new = tuple(a if a >= s else max(s, a + a // 2) for a, s in zip(arr.shape, shape, strict=True))
    out = np.full(new, fill, dtype=arr.dtype)
    out[tuple(slice(0, k) for k in arr.shape)] = arr
    return out


class CrowdSlots:
    """The reactive crowds of ``size`` slots (module docstring); one row per slot, the
    agent, waypoint and frame axes grown on demand."""

    def __init__(self, size: int) -> None:
        b = size
        self.active = np.zeros(b, dtype=bool)
        self.model = np.zeros(b, dtype=np.int64)
        self.mixed = np.zeros(b, dtype=bool)
        self.mixed_r = np.zeros(b)
        self.body_r = np.zeros(b)
        self.robot_r = np.zeros(b)
        self.substeps = np.ones(b, dtype=np.int64)
        self.fps = np.ones(b)
        self.dt = np.zeros(b)
        self.n_frames = np.zeros(b, dtype=np.int64)
        self.f0 = np.zeros(b, dtype=np.int64)
        self.lo = np.zeros(b, dtype=np.int64)
        self.n_cols = np.zeros(b, dtype=np.int64)
        self.lookahead = np.zeros(b)
        self.nd = np.zeros(b)
        self.kmax = np.zeros(b, dtype=np.int64)
        self.other_resp = np.zeros(b)
        self.inv_dt = np.zeros(b)
        self.inv_horizon = np.zeros(b)
        self.arrival = np.zeros(b)
        self.max_delay = np.zeros(b)
        self.frame = np.zeros(b, dtype=np.int64)
        self.sub = np.zeros(b, dtype=np.int64)
        self.n_left = np.zeros(b, dtype=np.int64)
        self.n_late = np.zeros(b, dtype=np.int64)
        self.status = np.zeros((0, 0), dtype=np.int8)
        self.pos = np.zeros((0, 0, 2))
        self.vel = np.zeros((0, 0, 2))
        self.switched = np.zeros((0, 0), dtype=np.int64)
        self.wp_count = np.zeros((0, 0), dtype=np.int64)
        self.exit = np.zeros((0, 0))
        self.final = np.zeros((0, 0, 2))
        self.v0 = np.zeros((0, 0))
        self.vmax = np.zeros((0, 0))
        self.wp_time = np.full((0, 0, 1), np.inf)
        self.wp_pos = np.zeros((0, 0, 1, 2))
        self.rec = np.zeros((0, 0, 0, 2))
        self.rec_vel = np.zeros((0, 0, 0, 2))
        #: the social force model of the slots (one run: the same parameters for all)
        self.sf: SocialForceModel | None = None

    # ------------------------------------------------------------------ slots
    def load(self, b: int, env: ReactiveEnvironment, last: int, lo: int) -> None:
        """Slot ``b`` takes the crowd of ``env`` (reset: at the episode's start frame).

        Parameters
        ----------
        b : int
            The slot.
        env : ReactiveEnvironment
            The episode's environment, reset.
        last : int
            The episode's last frame.
        lo : int
            The first frame of the slot's store.
        """
        crowd = env.crowd
        assert isinstance(crowd, Crowd)
        model = crowd.model_
        sc = env.scene
        m = sc.n_agents
        f0 = sc.start_index
        span = min(last + 2, sc.n_frames) - f0
        w = crowd.wp_time_.shape[1]
        nb = b + 1  # rows of the slots used so far (slots are filled from 0 up)
        self.status = _grown(self.status, (nb, m))
        self.switched = _grown(self.switched, (nb, m))
        self.wp_count = _grown(self.wp_count, (nb, m))
        self.exit = _grown(self.exit, (nb, m))
        self.v0 = _grown(self.v0, (nb, m))
        self.vmax = _grown(self.vmax, (nb, m))
        self.pos = _grown(self.pos, (nb, m, 2))
        self.vel = _grown(self.vel, (nb, m, 2))
        self.final = _grown(self.final, (nb, m, 2))
        self.wp_time = _grown(self.wp_time, (nb, m, w), np.inf)
        self.wp_pos = _grown(self.wp_pos, (nb, m, w, 2))
        self.rec = _grown(self.rec, (nb, span, m, 2))
        self.rec_vel = _grown(self.rec_vel, (nb, span, m, 2))
        self.status[b, :m] = crowd.status_
        self.switched[b, :m] = crowd.switched_at_
        self.pos[b, :m] = crowd.pos_
        self.vel[b, :m] = crowd.vel_
        self.wp_count[b, :m] = crowd.wp_count_
        self.exit[b, :m] = crowd.exit_
        self.v0[b, :m] = crowd.v0_
        self.vmax[b, :m] = crowd.v_max_
        self.final[b, :m] = crowd.final_
        self.wp_time[b] = np.inf
        self.wp_time[b, :m, :w] = crowd.wp_time_
        self.wp_pos[b, :m, :w] = crowd.wp_pos_
        self.rec[b, :span, :m] = crowd.recording_[f0 : f0 + span]
        self.rec_vel[b, :span, :m] = crowd.rec_vel_[f0 : f0 + span]
        self.model[b] = ORCA if isinstance(model, ORCAModel) else SOCIAL_FORCE
        self.mixed[b] = crowd.mixed
        self.mixed_r[b] = crowd.mixed_radius if crowd.mixed_radius is not None else math.nan
        self.body_r[b] = float(crowd.body_radius)
        self.robot_r[b] = crowd.robot_radius_
        self.substeps[b] = crowd.substeps_
        self.fps[b] = crowd.fps_
        self.dt[b] = crowd.dt_
        self.n_frames[b] = crowd.recording_.shape[0]
        self.f0[b] = f0
        self.lo[b] = lo
        self.n_cols[b] = m
        self.lookahead[b] = crowd.lookahead_
        self.nd[b] = float(model.neighbor_dist)  # type: ignore[attr-defined]
        if isinstance(model, ORCAModel):
            self.kmax[b] = int(model.max_neighbors)
            self.other_resp[b] = float(model.other_responsibility)
            self.inv_horizon[b] = 1.0 / model.time_horizon
        else:
            assert isinstance(model, SocialForceModel)
            self.sf = model
        self.inv_dt[b] = 1.0 / crowd.dt_
        self.arrival[b] = float(crowd.arrival_radius)
        self.max_delay[b] = float(crowd.max_delay)
        self.frame[b] = f0
        self.sub[b] = 0
        self.n_left[b] = crowd.n_left_
        self.n_late[b] = crowd.n_late_
        self.active[b] = True

    def finish(self, b: int, env: ReactiveEnvironment) -> None:
        """Hand slot ``b``'s crowd back to its environment (the counters its
        configuration reports, the state) and free the slot."""
        crowd = env.crowd
        m = int(self.n_cols[b])
        crowd.status_ = self.status[b, :m].copy()
        crowd.switched_at_ = self.switched[b, :m].copy()
        crowd.pos_ = self.pos[b, :m].copy()
        crowd.vel_ = self.vel[b, :m].copy()
        crowd.n_left_ = int(self.n_left[b])
        crowd.n_late_ = int(self.n_late[b])
        self.active[b] = False

    # ------------------------------------------------------------------ stepping
    def instant(
        self,
        slots: np.ndarray,
        rp: np.ndarray,
        rv: np.ndarray,
        store: np.ndarray,
        where: np.ndarray,
    ) -> None:
        """One control instant of the crowds of ``slots``.

        Parameters
        ----------
        slots : ndarray of int
            The slots.
        rp, rv : ndarray of shape (len(slots), 2)
            Their robots' positions (m) and velocities (m/s) at the instant's start.
        store, where : ndarray
            The engine's store and its slot table (the completed frames go there).
        """
        start, col, pvel, pref, prad, out, rows, cols, dx, dy, avel, arad, paired = crowd_begin(
            slots, rp, rv,
            self.model, self.mixed, self.mixed_r, self.body_r, self.robot_r, self.substeps,
            self.fps, self.n_frames, self.f0, self.n_cols, self.lookahead, self.nd, self.kmax,
            self.other_resp, self.inv_dt, self.inv_horizon,
            self.frame, self.sub, self.status, self.pos, self.vel, self.switched,
            self.rec, self.rec_vel, self.wp_time, self.wp_count, self.wp_pos, self.exit,
            self.v0, self.vmax,
        )  # fmt: skip
        new = out
        sf = self.sf
        if sf is not None and col.size and (self.model[slots] == SOCIAL_FORCE).any():
            # SocialForceModel.step's arithmetic on every slot's pedestrians and pairs
            dist, tx, ty, big_b, ok, ya, xa = sf_directions(
                dx, dy, rows, cols, pvel, avel, float(sf.lambda_importance), float(sf.gamma)
            )
            theta = np.arctan2(ya, xa)  # numpy's, as the model's
            ri, rj = prad[rows], arad[cols]
            expo = np.exp(sf_exponents(dist, ri - rj, big_b, ok, theta, sf.n, sf.n_prime))
            acc = sf_acceleration(
                start, paired, pref, pvel, float(sf.tau), rows, dx, dy, dist, ri, rj, tx, ty, ok,
                theta, expo, float(sf.A), float(sf.contact_stiffness),
            )  # fmt: skip
            if (self.model[slots] == ORCA).any():
                orca = np.repeat(self.model[slots] == ORCA, np.diff(start))
                acc[orca] = out[orca]
            new = acc
        crowd_end(
            slots, start, col, new,
            self.model, self.dt, self.substeps, self.fps, self.f0, self.n_cols, self.arrival,
            self.max_delay,
            self.frame, self.sub, self.status, self.pos, self.vel, self.n_left, self.n_late,
            self.rec, self.exit, self.final, self.vmax,
            store, where, self.lo,
        )  # fmt: skip

    def advance(
        self, slots: np.ndarray, pool: Any, v_start: np.ndarray, n_log0: np.ndarray
    ) -> None:
        """Walk the crowds of ``slots`` through the control instants their robots just
        ran, finish the frame of an episode that ended within one, and recompute the
        frame log's ``d_min`` of the frames logged meanwhile.

        Parameters
        ----------
        slots : ndarray of int
            The slots.
        pool : _Pool
            The engine's slots (``step``, ``rec_x``, ``rec_v``, ``decay``, ``x``, ``done``,
            ``store``, ``where``, ``log``, ``n_log``).
        v_start : ndarray of shape (len(slots), 2)
            The robots' velocities at the interval's start.
        n_log0 : ndarray of int
            The first frame-log row of the interval, per slot.
        """
        p = pool
        steps = p.step[slots]
        rv = v_start.copy()
        for s in range(int(steps.max(initial=0))):
            live = steps > s
            sl = slots[live]
            self.instant(sl, p.rec_x[sl, s], rv[live], p.store, p.where)
            # the plant's velocity after the instant (the engine's arithmetic)
            cmd = p.rec_v[sl, s]
            d = rv[live] - cmd
            rv[live] = cmd + d * p.decay[sl, None]
        ending = slots[p.done[slots] & (self.sub[slots] != 0)]
        while ending.size:  # the robot holds its last state
            self.instant(ending, p.x[ending, :2], p.x[ending, 2:4], p.store, p.where)
            ending = ending[self.sub[ending] != 0]
        relog_d_min(slots, n_log0, self.f0, p.store, p.where, p.log, p.n_log)

    def mirror(
        self, b: int, env: ReactiveEnvironment, store: np.ndarray, where: np.ndarray
    ) -> None:
        """Copy slot ``b``'s simulated frames into its environment's buffer and set the
        environment's crowd clock (its sensor, truth and measuring code read them).

        Parameters
        ----------
        b : int
            The slot.
        env : ReactiveEnvironment
            Its environment.
        store, where : ndarray
            The engine's store and its slot table.
        """
        o, _, m, n = (int(v) for v in where[b, :4])
        span = n // max(m, 1)
        lo, f0, f = int(self.lo[b]), int(self.f0[b]), int(self.frame[b])
        xy = store[o : o + 2 * n].reshape(m, span, 2)
        env.from_compiled(
            ReactiveCursor(
                frames=(f0 + 1, xy[:, f0 + 1 - lo : f + 1 - lo].transpose(1, 0, 2)),
                crowd_frame=f,
                crowd_sub=int(self.sub[b]),
            )
        )
