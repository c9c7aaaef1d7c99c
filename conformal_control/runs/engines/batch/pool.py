"""The batch engine's slots: :class:`Pool`, one row per live episode of every array the
compiled kernels read and write, and the compiled steps run on them (sense, predict, the
interval's control instants, the gap loss at an interval's end).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ....data.scene import SparseTracks
from ....families.cbf import kernels2d
from ....predictors.shift import noise_offsets
from .. import kernels as bk
from ..gap_kernels import gap_maxima
from ..interval import run_interval


class Pool:
    """The state of ``size`` episode slots, one row per slot (grown on demand).

    Every array's first axis is the slot. The per-slot scalars are float64 (times, lambda,
    the plant's and the reference's constants, the loss scale, the wall time) or int64
    (step and frame counters, sizes, codes of the fallback and the predictor).
    """

    size: int
    t: np.ndarray  # float64 (size,)
    lam: np.ndarray  # float64 (size,)
    dt: np.ndarray  # float64 (size,)
    dt_frame: np.ndarray  # float64 (size,)
    decay: np.ndarray  # float64 (size,)
    gain: np.ndarray  # float64 (size,)
    k_acc: np.ndarray  # float64 (size,)
    neg_k_att: np.ndarray  # float64 (size,)
    v_ref_max: np.ndarray  # float64 (size,)
    goal_radius: np.ndarray  # float64 (size,)
    radius: np.ndarray  # float64 (size,)
    t_goal: np.ndarray  # float64 (size,)
    scale: np.ndarray  # float64 (size,)
    sq: np.ndarray  # int64 (size,): the slot's loss squashing, its index in squash
    wall: np.ndarray  # float64 (size,)
    step: np.ndarray  # int64 (size,)
    n_ctrl: np.ndarray  # int64 (size,)
    n_agents: np.ndarray  # int64 (size,)
    fi: np.ndarray  # int64 (size,)
    last_frame: np.ndarray  # int64 (size,)
    k_start: np.ndarray  # int64 (size,)
    substeps: np.ndarray  # int64 (size,)
    tau: np.ndarray  # int64 (size,)
    history: np.ndarray  # int64 (size,)
    goal_idx: np.ndarray  # int64 (size,)
    n_log: np.ndarray  # int64 (size,)
    poly_len: np.ndarray  # int64 (size,)
    fallback: np.ndarray  # int64 (size,)
    predictor: np.ndarray  # int64 (size,)
    window: np.ndarray  # int64 (size,)
    n_short: np.ndarray  # int64 (size,)
    n_short_total: np.ndarray  # int64 (size,)
    n_predicted: np.ndarray  # int64 (size,)
    n_bad: np.ndarray  # int64 (size,)
    n_bad_total: np.ndarray  # int64 (size,)
    x: np.ndarray  # (size, 4): position, velocity
    goal: np.ndarray  # (size, 2)
    last: np.ndarray  # (size, 2): the previous decision (the filter's output)
    active: np.ndarray  # bool (size,)
    done: np.ndarray  # bool (size,)
    need_begin: np.ndarray  # bool (size,)
    prm: np.ndarray  # (size, len(kernels2d.PARAMS))
    poly: np.ndarray  # (size, 5 * sides): the speed polygon
    counts: np.ndarray  # int64 (size, 7): solves, infeasible, fallback, vertex, steps, escape,
    # escape_projected
    sensed: np.ndarray  # int64 (size, columns)
    xp: np.ndarray  # (size, steps, cap, 2): predicted positions
    vp: np.ndarray  # (size, steps, cap, 2): predicted velocities
    rec_x: np.ndarray  # (size, steps, 2)
    rec_v: np.ndarray  # (size, steps, 2)
    rec_lam: np.ndarray  # (size, steps)
    log: np.ndarray  # (size, frames, 6)
    samples: np.ndarray  # (>= tau + 1, 2): one agent's predicted samples, scratch
    cap: int  # agents per slot that xp / vp and the work buffer hold
    sides: int  # sides of the largest speed polygon
    work: np.ndarray  # the compiled filter's work buffer
    store: np.ndarray  # the live episodes' recordings, flat (see kernels)
    where: np.ndarray  # int64 (size, 5): slot -> (offset, frames, agents, samples, present)
    goals: np.ndarray  # (size, waypoints, 2): each slot's goals
    n_goals: np.ndarray  # int64 (size,)
    rec_code: np.ndarray  # int8 (size, steps): status of each control instant (FREE, ...)
    keep: bool  # whether st_* keep every control instant of the episodes
    st_t: np.ndarray  # (size, instants): time after each control instant
    st_x: np.ndarray  # (size, instants, 4): state after it
    st_cmd: np.ndarray  # (size, instants, 2): the command applied
    n_st: np.ndarray  # int64 (size,)
    used: int  # floats of store in use
    acp: np.ndarray  # bool (size,): the acp family (lambda is the regions' level)
    acp_dc: np.ndarray  # (size, horizon): the barrier's d_c at each horizon step
    acp_delta: np.ndarray  # (size, horizon): its delta
    acp_h: np.ndarray  # int64 (size,): horizon steps of the interval's regions
    forced: np.ndarray  # bool (size,): a decision given for the paused step
    forced_v: np.ndarray  # (size, 3): that decision (v_x, v_y, lambda applied)
    paused: np.ndarray  # (3,): the paused step's nominal decision and lambda
    reactive: np.ndarray  # bool (size,): a reactive crowd (engines.reactive)
    mirror: np.ndarray  # bool (size,): its environment's buffer is read during the run
    vec: np.ndarray  # bool (size,): lambda run per agent
    lam_off: np.ndarray  # (size, cap): per agent, its lambda minus the slot's lam (vec)
    shift: np.ndarray  # int64 (size,): the predictor shift (kernels' NO_SHIFT, DELAYED, ...)
    shift_k: np.ndarray  # int64 (size,): a delay in frames
    shift_x: np.ndarray  # (size, 2): the scale, or dropout's probability and block length
    noise_sigma: np.ndarray  # (size,): the noisy shift's standard deviation (m)
    seeds: np.ndarray  # int64 (size,): the shift's seed
    scene_keys: np.ndarray  # int64 (size,): its key of the scene's name
    first_frame: np.ndarray  # int64 (size,): the scene's first frame number
    agent_id: np.ndarray  # int64 (size, columns): the id of each agent of the recording
    noise: np.ndarray  # (size, cap, 2): each sensed agent's noisy displacement
    shift_counts: np.ndarray  # int64 (size, 3): stale, unseen, dropped (totals)
    rec: np.ndarray  # the recorded forecasts of the live episodes that replay them, flat
    rec_at: np.ndarray  # int64 (size,): where slot b's block starts in rec
    rec_len: np.ndarray  # int64 (size,): its length (0: none)
    rec_used: int  # floats of rec in use
    rec_step: np.ndarray  # (size,): the forecasts' step length (s)
    rec_counts: np.ndarray  # int64 (size, 4): missing, missing steps, extrapolated,
    # non-finite current (totals)
    # (loss class, loss scale) -> (its index in sq, the squashing of such a loss)
    squash: dict[tuple[type, float], tuple[int, Any]]

    def __init__(self, size: int) -> None:
        b = self.size = size
        self.t = np.zeros(b)
        self.lam = np.zeros(b)
        self.dt = np.zeros(b)
        self.dt_frame = np.zeros(b)
        self.decay = np.zeros(b)
        self.gain = np.zeros(b)
        self.k_acc = np.zeros(b)
        self.neg_k_att = np.zeros(b)
        self.v_ref_max = np.zeros(b)
        self.goal_radius = np.zeros(b)
        self.radius = np.zeros(b)
        self.t_goal = np.zeros(b)
        self.scale = np.zeros(b)
        self.sq = np.zeros(b, dtype=np.int64)  # the slot's squashing (index in squash)
        self.wall = np.zeros(b)
        self.step = np.zeros(b, dtype=np.int64)
        self.n_ctrl = np.zeros(b, dtype=np.int64)
        self.n_agents = np.zeros(b, dtype=np.int64)
        self.fi = np.zeros(b, dtype=np.int64)
        self.last_frame = np.zeros(b, dtype=np.int64)
        self.k_start = np.zeros(b, dtype=np.int64)
        self.substeps = np.zeros(b, dtype=np.int64)
        self.tau = np.zeros(b, dtype=np.int64)
        self.history = np.zeros(b, dtype=np.int64)
        self.goal_idx = np.zeros(b, dtype=np.int64)
        self.n_log = np.zeros(b, dtype=np.int64)
        self.poly_len = np.zeros(b, dtype=np.int64)
        self.fallback = np.zeros(b, dtype=np.int64)
        self.predictor = np.zeros(b, dtype=np.int64)
        self.window = np.zeros(b, dtype=np.int64)
        self.n_short = np.zeros(b, dtype=np.int64)
        self.n_short_total = np.zeros(b, dtype=np.int64)
        self.n_predicted = np.zeros(b, dtype=np.int64)
        self.n_bad = np.zeros(b, dtype=np.int64)
        self.n_bad_total = np.zeros(b, dtype=np.int64)
        self.x = np.zeros((b, 4))
        self.goal = np.zeros((b, 2))
        self.last = np.zeros((b, 2))
        self.active = np.zeros(b, dtype=bool)
        self.done = np.zeros(b, dtype=bool)
        self.need_begin = np.zeros(b, dtype=bool)
        self.prm = np.zeros((b, len(kernels2d.PARAMS)))
        self.poly = np.zeros((b, 0))
        self.counts = np.zeros((b, 7), dtype=np.int64)
        self.sensed = np.zeros((b, 0), dtype=np.int64)
        self.xp = np.zeros((b, 0, 0, 2))
        self.vp = np.zeros((b, 0, 0, 2))
        self.rec_x = np.zeros((b, 0, 2))
        self.rec_v = np.zeros((b, 0, 2))
        self.rec_lam = np.zeros((b, 0))
        self.log = np.zeros((b, 0, 6))
        self.samples = np.zeros((1, 2))
        self.cap = 0  # agents per slot that xp / vp and the work buffer hold
        self.sides = 0
        self.work = np.zeros(0)
        self.store = np.zeros(0)  # the live episodes' recordings, flat (see kernels)
        # slot -> (offset, frames, agents, samples, present samples)
        self.where = np.zeros((b, 5), dtype=np.int64)
        self.used = 0
        self.goals = np.zeros((b, 1, 2))
        self.n_goals = np.zeros(b, dtype=np.int64)
        self.rec_code = np.zeros((b, 0), dtype=np.int8)
        self.keep = False
        self.st_t = np.zeros((b, 0))
        self.st_x = np.zeros((b, 0, 4))
        self.st_cmd = np.zeros((b, 0, 2))
        self.n_st = np.zeros(b, dtype=np.int64)
        self.acp = np.zeros(b, dtype=bool)
        self.acp_dc = np.zeros((b, 1))
        self.acp_delta = np.zeros((b, 1))
        self.acp_h = np.ones(b, dtype=np.int64)
        self.forced = np.zeros(b, dtype=bool)
        self.forced_v = np.zeros((b, 3))
        self.paused = np.zeros(3)
        self.reactive = np.zeros(b, dtype=bool)
        self.mirror = np.zeros(b, dtype=bool)
        self.vec = np.zeros(b, dtype=bool)
        self.lam_off = np.zeros((b, 0))
        self.shift = np.zeros(b, dtype=np.int64)
        self.shift_k = np.zeros(b, dtype=np.int64)
        self.shift_x = np.zeros((b, 2))
        self.noise_sigma = np.zeros(b)
        self.seeds = np.zeros(b, dtype=np.int64)
        self.scene_keys = np.zeros(b, dtype=np.int64)
        self.first_frame = np.zeros(b, dtype=np.int64)
        self.agent_id = np.zeros((b, 0), dtype=np.int64)
        self.noise = np.zeros((b, 0, 2))
        self.shift_counts = np.zeros((b, 3), dtype=np.int64)
        self.rec = np.zeros(0)
        self.rec_at = np.zeros(b, dtype=np.int64)
        self.rec_len = np.zeros(b, dtype=np.int64)
        self.rec_used = 0
        self.rec_step = np.zeros(b)
        self.rec_counts = np.zeros((b, 4), dtype=np.int64)
        self.squash = {}

    @staticmethod
    def grown(arr: np.ndarray, axis: int, n: int) -> np.ndarray:
        if arr.shape[axis] >= n:
            return arr
        shape = list(arr.shape)
        shape[axis] = n
        out = np.zeros(shape, dtype=arr.dtype)
        out[tuple(slice(0, k) for k in arr.shape)] = arr
        return out

    def load(self, b: int, tracks: SparseTracks) -> None:
        """Copy slot ``b``'s recording (sparse,
        :func:`~conformal_control.runs.engines.kernels.pack`)
        into the store (compacting or growing it)."""
        counts = (tracks.n_frames, tracks.n_agents, tracks.xy.shape[0], tracks.frame_cols.size)
        self.put(b, bk.pack(tracks), counts)

    def put(self, b: int, data: np.ndarray, counts: tuple[int, int, int, int]) -> None:
        """Copy slot ``b``'s recording laid out as
        :func:`~conformal_control.runs.engines.kernels.pack`
        lays it out, with ``counts`` = (frames, agents, samples, present), into the store."""
        n = data.size
        if self.used + n > self.store.size:
            self._compact()
            if self.used + n > self.store.size:  # doubled: amortised, and no room reserved
                # for slots that may never fill (a long scene and batch_size 256 asked for
                # 256 copies of it)
                grown = np.empty(max(2 * self.store.size, self.used + n))
                grown[: self.used] = self.store[: self.used]
                self.store = grown
        self.store[self.used : self.used + n] = data
        self.where[b] = (self.used, *counts)
        self.used += n

    def _compact(self) -> None:
        """Move the live slots' recordings to the front of the store, in place."""
        live = np.flatnonzero(self.active)
        end = 0
        for b in live[np.argsort(self.where[live, 0])].tolist():
            o, f, m, ns, k = self.where[b].tolist()
            n = bk.slot_size(f, m, ns, k)
            if o != end:
                self.store[end : end + n] = self.store[o : o + n]  # numpy copies overlaps safely
                self.where[b, 0] = end
            end += n
        self.used = end

    def put_recorded(self, b: int, block: np.ndarray) -> None:
        """Copy slot ``b``'s recorded forecasts (a block of
        :func:`~conformal_control.runs.engines.recorded_kernels.pack`; empty: none) into ``rec``
        (the live slots' blocks moved to the front first when it is full, then grown)."""
        n = block.size
        self.rec_len[b] = 0
        if self.rec_used + n > self.rec.size:
            end = 0
            live = np.flatnonzero(self.active & (self.rec_len > 0))
            for s in live[np.argsort(self.rec_at[live])].tolist():
                o, k = int(self.rec_at[s]), int(self.rec_len[s])
                if o != end:
                    self.rec[end : end + k] = self.rec[o : o + k]
                    self.rec_at[s] = end
                end += k
            self.rec_used = end
            if self.rec_used + n > self.rec.size:
                grown = np.empty(max(2 * self.rec.size, self.rec_used + n))
                grown[: self.rec_used] = self.rec[: self.rec_used]
                self.rec = grown
        self.rec[self.rec_used : self.rec_used + n] = block
        self.rec_at[b] = self.rec_used
        self.rec_len[b] = n
        self.rec_used += n

    def prepare(self, b: int, goals: np.ndarray, instants: int) -> None:
        """Slot ``b``'s goals, and room for its ``instants`` control instants if kept."""
        if goals.shape[0] > self.goals.shape[1]:
            self.goals = self.grown(self.goals, 1, goals.shape[0])
        self.goals[b, : goals.shape[0]] = goals
        self.n_goals[b] = goals.shape[0]
        self.n_st[b] = 0
        if self.keep and instants > self.st_t.shape[1]:
            g = self.grown
            self.st_t = g(self.st_t, 1, instants)
            self.st_x, self.st_cmd = g(self.st_x, 1, instants), g(self.st_cmd, 1, instants)

    def ensure(
        self, *, steps: int = 0, agents: int = 0, columns: int = 0, frames: int = 0, sides: int = 0
    ) -> None:
        """Room (arrays grown where they are too small) for what the parameters say.

        Parameters
        ----------
        steps : int
            Control instants per interval.
        agents : int
            Sensed agents per slot.
        columns : int
            Agents in a recording.
        frames : int
            Logged frames.
        sides : int
            Sides of a speed polygon.
        """
        g = self.grown
        if steps > self.xp.shape[1]:
            self.xp, self.vp = g(self.xp, 1, steps), g(self.vp, 1, steps)
            self.rec_x, self.rec_v = g(self.rec_x, 1, steps), g(self.rec_v, 1, steps)
            self.rec_lam = g(self.rec_lam, 1, steps)
            self.rec_code = g(self.rec_code, 1, steps)
            self.samples = g(self.samples, 0, steps + 1)  # >= tau + 1 rows
        if agents > self.cap or sides > self.sides:
            if agents > self.cap:
                self.cap = max(agents, 2 * self.cap, 16)
                self.xp, self.vp = g(self.xp, 2, self.cap), g(self.vp, 2, self.cap)
                self.lam_off = g(self.lam_off, 1, self.cap)
                self.noise = g(self.noise, 1, self.cap)
                self.prm[:, 11] = self.cap
            if sides > self.sides:
                self.sides = sides
                self.poly = g(self.poly, 1, 5 * sides)
            self.work = np.zeros(kernels2d.work_size(self.cap, self.sides))
        if columns > self.sensed.shape[1]:
            self.sensed = g(self.sensed, 1, columns)
            self.agent_id = g(self.agent_id, 1, columns)
        if frames > self.log.shape[1]:
            self.log = g(self.log, 1, frames)

    # ------------------------------------------------------------------ the compiled steps
    def sense(self, slots: np.ndarray) -> None:
        """The agents each of ``slots`` senses now (``sensed``, ``n_agents``)."""
        bk.count_sensed(
            slots, self.store, self.where, self.fi, self.x, self.radius, self.sensed, self.n_agents
        )

    def predict(self, slots: np.ndarray) -> None:
        """The compiled prediction of ``slots`` (their predictor and its shift), interpolated
        at the interval's control instants into ``xp`` / ``vp``; the counters added up."""
        noisy = slots[self.shift[slots] == bk.NOISY]
        if noisy.size:
            self.draw_noise(noisy)
        p = self
        bk.predict_interpolate(
            slots, p.store, p.where, p.fi, p.sensed, p.n_agents, p.predictor, p.window,
            p.history, p.tau, p.substeps, p.dt_frame, p.samples, p.xp, p.vp, p.n_short,
            p.n_bad, p.shift, p.shift_k, p.shift_x, p.seeds, p.scene_keys, p.first_frame,
            p.agent_id, p.noise, p.shift_counts, p.rec, p.rec_at, p.rec_step, p.rec_counts,
        )  # fmt: skip
        p.n_predicted[slots] += 1
        p.n_bad_total[slots] += p.n_bad[slots]
        p.n_short_total[slots] += p.n_short[slots]

    def draw_noise(self, slots: np.ndarray) -> None:
        """The ``noisy`` shift's displacement of each sensed agent of ``slots`` at this
        sampling time, drawn for all of them at once as the predictor draws its own
        (:func:`~conformal_control.predictors.shift.noise_offsets`)."""
        p = self
        n = p.n_agents[slots]
        m = int(n.max())
        i, a = np.nonzero(np.arange(m)[None, :] < n[:, None])  # (slot, agent), slot-major
        rows = slots[i]
        ids = p.agent_id[rows, p.sensed[rows, a]]
        frames = p.first_frame[rows] + p.fi[rows]
        p.noise[rows, a] = noise_offsets(
            p.noise_sigma[rows], p.seeds[rows], p.scene_keys[rows], frames, ids
        )

    def run_interval(self, todo: np.ndarray) -> tuple[int, int]:
        """The control instants of ``todo`` up to their interval's end (or a pause), in one
        compiled call (:func:`~conformal_control.runs.engines.interval.run_interval`):
        (the slot with non-finite input or -1, the position of a paused slot or -1)."""
        p = self
        bad, paused = run_interval(
            todo, p.x, p.t, p.step, p.n_ctrl, p.tau, p.done,
            p.goal, p.goal_idx, p.goals, p.n_goals, p.goal_radius, p.t_goal, p.neg_k_att,
            p.v_ref_max,
            p.lam, p.n_agents, p.xp, p.vp, p.prm, p.poly, p.poly_len, p.fallback, p.work,
            p.last, p.counts,
            p.dt, p.decay, p.gain, p.k_acc,
            p.rec_x, p.rec_v, p.rec_lam, p.rec_code,
            p.store, p.where, p.substeps, p.fi, p.last_frame, p.log, p.n_log,
            p.keep, p.st_t, p.st_x, p.st_cmd, p.n_st,
            p.acp, p.acp_dc, p.acp_delta, p.acp_h, p.forced, p.forced_v, p.paused,
            p.vec, p.lam_off,
        )  # fmt: skip
        return int(bad), int(paused)

    def score_gaps(
        self, scored: np.ndarray, scores: tuple[np.ndarray, ...]
    ) -> tuple[np.ndarray, dict[int, int]]:
        """The compiled gap loss of the intervals of ``scored`` ending now: the largest gap
        (and at the lambda applied), the pairs scored, the loss and the loss at the lambda
        applied written into ``scores`` (top, top_applied, n_pairs, loss, applied; the
        caller reset them); returns each agent's largest gap (lambda run per agent) and
        where each scored slot's agents start in it."""
        p = self
        top, top_applied, n_pairs, loss, applied = scores
        agent_top = np.zeros(0)  # per agent of each scored slot (lambda run per agent)
        where: dict[int, int] = {}  # scored slot -> its agents' offset in agent_top
        if not scored.size:
            return agent_top, where
        counts = p.n_agents[scored]
        offsets = np.zeros(scored.size, dtype=np.int64)
        if scored.size > 1:
            np.cumsum(counts[:-1], out=offsets[1:])
        agent_top = np.full(int(counts.sum()), -np.inf)
        where = dict(zip(scored.tolist(), offsets.tolist(), strict=True))
        frames = -(-p.step[scored] // p.substeps[scored])  # frames the interval ran
        truth = np.empty((int(counts.sum()), int(frames.max()) + 1, 2))
        bk.gather_windows(scored, p.store, p.where, p.k_start, p.sensed, p.n_agents, offsets, truth)
        gap_maxima(
            scored, offsets, p.n_agents, p.step, truth, p.dt_frame, p.substeps, p.rec_x,
            p.rec_v, p.rec_lam, p.xp, p.vp, p.lam, p.prm, top, top_applied, n_pairs,
            p.vec, p.lam_off, agent_top,
        )  # fmt: skip
        for i, squash in self.squash.values():
            # one loss (class and scale) in the engine: every scored slot has it
            sel = scored if len(self.squash) == 1 else scored[p.sq[scored] == i]
            if sel.size:  # the loss's own squashing (the gap loss: arctan(r / c) / pi)
                loss[sel] = squash(top[sel] + p.lam[sel])
                applied[sel] = squash(top_applied[sel])
        return agent_top, where
