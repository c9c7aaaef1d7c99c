"""Reactive crowds of many episodes stepped together, compiled.

What :meth:`Crowd.step <conformal_control.world.crowds.crowd.Crowd.step>` and its model do for
one episode at one control instant -- pedestrians entering (the full crowd) or switching
from the recording (the mixed crowd), the replayed pedestrians interpolated between
frames, the preferred velocities towards the recorded waypoints, the neighbour search, the
model's step, the pedestrians leaving the scene, the frame the environment stores when it
is complete -- written as loops over the episodes of a batch
(:mod:`conformal_control.runs.engines.batch`), with the same floating-point operations in the
same order (numba compiles without fast-math; ``math.hypot`` is the C library's, the one
``numpy.hypot`` calls). ORCA's step is the model's own compiled functions
(:mod:`~conformal_control.world.crowds.orca_compiled`) called per episode;
the social force's pairwise interaction is computed by the model's own numpy code on the
pairs of every episode laid side by side (an elementwise computation: one call on the
concatenation is the same arithmetic as one call per episode), between
:func:`crowd_begin` (everything before it) and :func:`crowd_end` (everything after).

State of slot ``b`` (arrays indexed by slot, then by the recording's column ``j``):
``status`` (:data:`~conformal_control.world.crowds.crowd.REPLAY`, ``ACTIVE``, ``GONE``),
``pos`` / ``vel`` (m, m/s; NaN unless active), ``switched`` (frame of the switch, -1),
the plan the crowd made at its reset (``wp_time`` padded with inf, ``wp_pos``,
``wp_count``, ``exit_``, ``final``, ``v0``, ``vmax``) and the recording and its recorded
velocities over the episode's frames (``rec``, ``rec_vel``: frame ``f`` at row
``f - f0[b]``). The crowd's clock is ``frame[b]`` and ``sub[b]``.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.jit import kernel
from ...families.cbf.pyhypot import c_hypot
from ...world.crowds.crowd import ACTIVE, GONE, REPLAY
from ...world.crowds.neighbors import cell_pairs
from ...world.crowds.orca_compiled import orca_lines_compiled, solve_orca_lp_compiled
from .kernels import d_min

__all__ = ["ORCA", "SOCIAL_FORCE", "crowd_begin", "crowd_end", "relog_d_min"]

jit = kernel(cache=True, nogil=True)

#: Model codes of a slot.
SOCIAL_FORCE, ORCA = 0, 1


@jit
def _grow_f(a: np.ndarray, n: int) -> np.ndarray:
    out = np.empty(max(n, 2 * a.shape[0]))
    out[: a.shape[0]] = a
    return out


@jit
def _grow_i(a: np.ndarray, n: int) -> np.ndarray:
    out = np.empty(max(n, 2 * a.shape[0]), dtype=np.int64)
    out[: a.shape[0]] = a
    return out


@jit
def crowd_begin(
    slots: np.ndarray,
    rp: np.ndarray,
    rv: np.ndarray,
    # the slots' constants
    model: np.ndarray,
    mixed: np.ndarray,
    mixed_r: np.ndarray,
    body_r: np.ndarray,
    robot_r: np.ndarray,
    substeps: np.ndarray,
    fps: np.ndarray,
    n_frames: np.ndarray,
    f0: np.ndarray,
    n_cols: np.ndarray,
    lookahead: np.ndarray,
    nd: np.ndarray,
    kmax: np.ndarray,
    other_resp: np.ndarray,
    inv_dt: np.ndarray,
    inv_horizon: np.ndarray,
    # the crowds' state
    frame: np.ndarray,
    sub: np.ndarray,
    status: np.ndarray,
    pos: np.ndarray,
    vel: np.ndarray,
    switched: np.ndarray,
    # the plans and the recordings
    rec: np.ndarray,
    rec_vel: np.ndarray,
    wp_time: np.ndarray,
    wp_count: np.ndarray,
    wp_pos: np.ndarray,
    exit_: np.ndarray,
    v0: np.ndarray,
    vmax: np.ndarray,
) -> tuple[
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
]:
    """One control instant of each slot's crowd, up to the model's step.

    The robot of slot ``slots[i]`` is at ``rp[i]`` with velocity ``rv[i]``. Returns
    ``(start, col, ped_vel, pref, ped_rad, out, rows, cols, dx, dy, all_vel, all_rad,
    paired)``: the active pedestrians of ``slots[i]`` are rows ``start[i] : start[i + 1]``
    (their columns ``col``, velocities, preferred velocities, radii); ``out`` holds the
    new velocities of the ORCA slots; ``rows`` / ``cols`` / ``dx`` / ``dy`` are the
    neighbour pairs of the social-force slots (``rows`` into the pedestrians, ``cols``
    into ``all_vel`` / ``all_rad``: each slot's pedestrians, then its robot and its
    replayed pedestrians); ``paired[i]`` whether slot ``i`` has a pair.
    """
    ns = slots.shape[0]
    total = 0
    for i in range(ns):
        total += n_cols[slots[i]]
    start = np.zeros(ns + 1, dtype=np.int64)
    col = np.empty(total, dtype=np.int64)
    ped_pos = np.empty((total, 2))
    ped_vel = np.empty((total, 2))
    pref = np.empty((total, 2))
    ped_rad = np.empty(total)
    out = np.zeros((total, 2))
    all_vel = np.empty((total + ns, 2))
    all_rad = np.empty(total + ns)
    paired = np.zeros(ns, dtype=np.bool_)
    rows = np.empty(64, dtype=np.int64)
    cols = np.empty(64, dtype=np.int64)
    pdx = np.empty(64)
    pdy = np.empty(64)
    n_pairs = 0
    a_off = 0  # the slot's first row of all_*
    rep_cols = np.empty(0, dtype=np.int64)
    rep_pos = np.empty((0, 2))
    for i in range(ns):
        b = slots[i]
        m = n_cols[b]
        f = frame[b]
        s = sub[b]
        sb = substeps[b]
        r = f - f0[b]
        start[i + 1] = start[i]
        # full crowd: the pedestrians present in the recording at the frame join
        if not mixed[b] and s == 0:
            for j in range(m):
                if status[b, j] == REPLAY and math.isfinite(rec[b, r, j, 0]):
                    status[b, j] = ACTIVE
                    pos[b, j, 0] = rec[b, r, j, 0]
                    pos[b, j, 1] = rec[b, r, j, 1]
                    vel[b, j, 0] = rec_vel[b, r, j, 0]
                    vel[b, j, 1] = rec_vel[b, r, j, 1]
                    switched[b, j] = f
        # the replayed pedestrians present at the frame, at the instant
        if rep_cols.shape[0] < m:
            rep_cols = np.empty(m, dtype=np.int64)
            rep_pos = np.empty((m, 2))
        nr = 0
        a = s / sb
        interp = s != 0 and f + 1 < n_frames[b]
        for j in range(m):
            if status[b, j] == REPLAY and math.isfinite(rec[b, r, j, 0]):
                px = rec[b, r, j, 0]
                py = rec[b, r, j, 1]
                if interp and math.isfinite(rec[b, r + 1, j, 0]):
                    px = (1.0 - a) * px + a * rec[b, r + 1, j, 0]
                    py = (1.0 - a) * py + a * rec[b, r + 1, j, 1]
                rep_cols[nr] = j
                rep_pos[nr, 0] = px
                rep_pos[nr, 1] = py
                nr += 1
        # mixed crowd: those the robot comes close to switch to the model
        if mixed[b] and nr:
            keep = 0
            for q in range(nr):
                j = rep_cols[q]
                px = rep_pos[q, 0]
                py = rep_pos[q, 1]
                if c_hypot(px - rp[i, 0], py - rp[i, 1]) <= mixed_r[b]:
                    status[b, j] = ACTIVE
                    pos[b, j, 0] = px
                    pos[b, j, 1] = py
                    vel[b, j, 0] = rec_vel[b, r, j, 0]
                    vel[b, j, 1] = rec_vel[b, r, j, 1]
                    switched[b, j] = f
                else:
                    rep_cols[keep] = j
                    rep_pos[keep, 0] = px
                    rep_pos[keep, 1] = py
                    keep += 1
            nr = keep
        # the active pedestrians and their preferred velocities
        n = 0
        p0 = start[i]
        t = f + s / sb
        la = lookahead[b]
        for j in range(m):
            if status[b, j] != ACTIVE:
                continue
            g = p0 + n
            col[g] = j
            x = pos[b, j, 0]
            y = pos[b, j, 1]
            ped_pos[g, 0] = x
            ped_pos[g, 1] = y
            ped_vel[g, 0] = vel[b, j, 0]
            ped_vel[g, 1] = vel[b, j, 1]
            ped_rad[g] = body_r[b]
            cnt = wp_count[b, j]
            k = 0  # waypoints recorded before t + la (their times increase; inf after cnt)
            while k < cnt and wp_time[b, j, k] < t + la:
                k += 1
            over = k >= cnt
            k = min(k, cnt - 1)
            tx = wp_pos[b, j, k, 0]
            ty = wp_pos[b, j, k, 1]
            remaining = max(wp_time[b, j, k] - t, la)
            dx = tx - x
            dy = ty - y
            c = fps[b] / remaining
            vx = dx * c
            vy = dy * c
            if over and t >= exit_[b, j]:  # past its recording: on at the mean speed
                dist = c_hypot(dx, dy)
                den = dist if dist > 0 else 1.0
                vx = dx / den * v0[b, j]
                vy = dy / den * v0[b, j]
            speed = c_hypot(vx, vy)
            vm = vmax[b, j]
            if speed > vm:
                c = vm / speed
                vx *= c
                vy *= c
            pref[g, 0] = vx
            pref[g, 1] = vy
            n += 1
        start[i + 1] = p0 + n
        if n == 0:
            continue
        # every agent the pedestrians see: themselves, the robot, the replayed ones
        ma = n + 1 + nr
        ap = np.empty((ma, 2))
        if all_vel.shape[0] < a_off + ma:
            grown = np.empty((max(a_off + ma, 2 * all_vel.shape[0]), 2))
            grown[: all_vel.shape[0]] = all_vel
            all_vel = grown
            all_rad = _grow_f(all_rad, a_off + ma)
        for q in range(n):
            ap[q, 0] = ped_pos[p0 + q, 0]
            ap[q, 1] = ped_pos[p0 + q, 1]
            all_vel[a_off + q, 0] = ped_vel[p0 + q, 0]
            all_vel[a_off + q, 1] = ped_vel[p0 + q, 1]
            all_rad[a_off + q] = body_r[b]
        ap[n, 0] = rp[i, 0]
        ap[n, 1] = rp[i, 1]
        all_vel[a_off + n, 0] = rv[i, 0]
        all_vel[a_off + n, 1] = rv[i, 1]
        all_rad[a_off + n] = robot_r[b]
        for q in range(nr):
            j = rep_cols[q]
            ap[n + 1 + q, 0] = rep_pos[q, 0]
            ap[n + 1 + q, 1] = rep_pos[q, 1]
            all_vel[a_off + n + 1 + q, 0] = rec_vel[b, r, j, 0]
            all_vel[a_off + n + 1 + q, 1] = rec_vel[b, r, j, 1]
            all_rad[a_off + n + 1 + q] = body_r[b]
        pp = ped_pos[p0 : p0 + n]
        ok, pr, pc, px_, py_ = cell_pairs(pp, ap, nd[b], kmax[b] if model[b] == ORCA else -1)
        if not ok:
            raise ValueError(
                "a crowd's coordinates span too far for the cell search of the batch "
                "engine; use run_episode"
            )
        if model[b] == ORCA:
            point, direction, valid = orca_lines_compiled(
                n, kmax[b], pr, pc, px_, py_, ped_vel[p0 : p0 + n],
                all_vel[a_off : a_off + ma], ped_rad[p0 : p0 + n],
                all_rad[a_off : a_off + ma], other_resp[b], inv_dt[b], inv_horizon[b],
            )  # fmt: skip
            v, _ = solve_orca_lp_compiled(
                point, direction, valid, pref[p0 : p0 + n].copy(), vmax_of(vmax, b, col, p0, n)
            )
            out[p0 : p0 + n] = v
        else:
            np_ = pr.shape[0]
            if np_:
                paired[i] = True
                if rows.shape[0] < n_pairs + np_:
                    rows = _grow_i(rows, n_pairs + np_)
                    cols = _grow_i(cols, n_pairs + np_)
                    pdx = _grow_f(pdx, n_pairs + np_)
                    pdy = _grow_f(pdy, n_pairs + np_)
                for q in range(np_):
                    rows[n_pairs + q] = p0 + pr[q]
                    cols[n_pairs + q] = a_off + pc[q]
                    pdx[n_pairs + q] = px_[q]
                    pdy[n_pairs + q] = py_[q]
                n_pairs += np_
        a_off += ma
    m_tot = start[ns]
    return (
        start,
        col[:m_tot],
        ped_vel[:m_tot],
        pref[:m_tot],
        ped_rad[:m_tot],
        out[:m_tot],
        rows[:n_pairs],
        cols[:n_pairs],
        pdx[:n_pairs],
        pdy[:n_pairs],
        all_vel[:a_off],
        all_rad[:a_off],
        paired,
    )


@jit
def vmax_of(vmax: np.ndarray, b: int, col: np.ndarray, p0: int, n: int) -> np.ndarray:
    """The speed bounds of the active pedestrians ``col[p0 : p0 + n]`` of slot ``b``."""
    out = np.empty(n)
    for q in range(n):
        out[q] = vmax[b, col[p0 + q]]
    return out


@jit
def crowd_end(
    slots: np.ndarray,
    start: np.ndarray,
    col: np.ndarray,
    new: np.ndarray,
    # the slots' constants
    model: np.ndarray,
    dt: np.ndarray,
    substeps: np.ndarray,
    fps: np.ndarray,
    f0: np.ndarray,
    n_cols: np.ndarray,
    arrival: np.ndarray,
    max_delay: np.ndarray,
    # the crowds' state
    frame: np.ndarray,
    sub: np.ndarray,
    status: np.ndarray,
    pos: np.ndarray,
    vel: np.ndarray,
    n_left: np.ndarray,
    n_late: np.ndarray,
    rec: np.ndarray,
    exit_: np.ndarray,
    final: np.ndarray,
    vmax: np.ndarray,
    # the environment's store (the frame completed is written there)
    store: np.ndarray,
    where: np.ndarray,
    lo: np.ndarray,
) -> None:
    """The rest of the control instant :func:`crowd_begin` started, per slot.

    ``new`` holds, per active pedestrian, the social force's acceleration (slots of
    :data:`SOCIAL_FORCE`: integrated and capped here as the model does) or ORCA's new
    velocity. Positions move by ``v dt``; pedestrians past their recording leave; the
    crowd's clock advances and a completed frame is written to the slot's store (laid out
    by :func:`dense_layout`: every column over the frames ``lo[b]`` onwards).
    """
    for i in range(slots.shape[0]):
        b = slots[i]
        f = frame[b]
        s = sub[b]
        sb = substeps[b]
        h = dt[b]
        if start[i + 1] > start[i]:
            t_next = (f + s / sb) + 1.0 / sb
            for g in range(start[i], start[i + 1]):
                j = col[g]
                if model[b] == ORCA:
                    vx = new[g, 0]
                    vy = new[g, 1]
                else:
                    vx = vel[b, j, 0] + h * new[g, 0]
                    vy = vel[b, j, 1] + h * new[g, 1]
                    speed = c_hypot(vx, vy)
                    if speed > vmax[b, j]:
                        c = vmax[b, j] / speed
                        vx *= c
                        vy *= c
                x = pos[b, j, 0] + h * vx
                y = pos[b, j, 1] + h * vy
                pos[b, j, 0] = x
                pos[b, j, 1] = y
                vel[b, j, 0] = vx
                vel[b, j, 1] = vy
                if t_next >= exit_[b, j]:
                    arrived = c_hypot(x - final[b, j, 0], y - final[b, j, 1]) <= arrival[b]
                    late = not arrived and (t_next - exit_[b, j] > max_delay[b] * fps[b])
                    if arrived or late:
                        status[b, j] = GONE
                        pos[b, j, 0] = math.nan
                        pos[b, j, 1] = math.nan
                        vel[b, j, 0] = math.nan
                        vel[b, j, 1] = math.nan
                        n_left[b] += arrived
                        n_late[b] += late
        s += 1
        if s == sb:
            f += 1
            s = 0
            _write_frame(b, f, n_cols[b], status, pos, rec, f0, store, where, lo)
        frame[b] = f
        sub[b] = s


@jit
def _write_frame(
    b: int,
    f: int,
    m: int,
    status: np.ndarray,
    pos: np.ndarray,
    rec: np.ndarray,
    f0: np.ndarray,
    store: np.ndarray,
    where: np.ndarray,
    lo: np.ndarray,
) -> None:
    """Slot ``b``'s frame ``f`` as the crowd's ``frame_positions`` gives it, into the
    store: replayed pedestrians from the recording, simulated ones where the model put
    them, those who left absent."""
    o = where[b, 0]
    n_frames = where[b, 1]
    span = where[b, 3] // max(m, 1)  # frames stored per column
    tables = o + 2 * where[b, 3]
    ptr = tables + 3 * m
    cols = ptr + n_frames + 1
    r = f - f0[b]
    k = int(store[ptr + f])
    for j in range(m):
        st = status[b, j]
        if st == ACTIVE:
            x = pos[b, j, 0]
            y = pos[b, j, 1]
        elif st == REPLAY:
            x = rec[b, r, j, 0]
            y = rec[b, r, j, 1]
        else:
            x = math.nan
            y = math.nan
        q = o + 2 * (j * span + f - lo[b])
        store[q] = x
        store[q + 1] = y
        if math.isfinite(x):
            store[cols + k] = j
            k += 1
    # the frame's end (the later frames' entries are written with them; until then each
    # reads as no agent: an end at or before its start)
    store[ptr + f + 1] = k


@jit
def relog_d_min(
    slots: np.ndarray,
    first: np.ndarray,
    start_frame: np.ndarray,
    store: np.ndarray,
    where: np.ndarray,
    log: np.ndarray,
    n_log: np.ndarray,
) -> None:
    """``d_min`` of the frame-log rows ``first[i]`` onwards of slot ``slots[i]`` (row ``r``
    is the frame ``start_frame[b] + r``), from the store once the crowd has walked there."""
    for i in range(slots.shape[0]):
        b = slots[i]
        for r in range(first[i], n_log[b]):
            log[b, r, 5] = d_min(store, where, b, start_frame[b] + r, log[b, r, 1], log[b, r, 2])


def dense_layout(positions: np.ndarray, lo: int, upto: int, n_frames: int) -> np.ndarray:
    """A slot's store for a reactive crowd: :func:`~conformal_control.runs.engines.kernels.pack`'s
    layout with every column stored over frames ``lo .. lo + L - 1`` (``positions`` of
    shape ``(L, M, 2)``: the environment's buffer over those frames), room for every
    column present at every frame, and the frames up to ``upto`` indexed (the later ones
    are written as the crowd walks, :func:`crowd_end`).

    Parameters
    ----------
    positions : ndarray of shape (L, M, 2)
        The environment's buffer over frames ``lo .. lo + L - 1`` (m).
    lo : int
        The first frame stored.
    upto : int
        The last frame known (the start frame).
    n_frames : int
        Frames of the scene.

    Returns
    -------
    ndarray
        The slot's floats.
    """
    span, m = positions.shape[0], positions.shape[1]
    xy = np.full((m, span, 2), np.nan)
    known = upto - lo + 1
    xy[:, :known] = positions[:known].transpose(1, 0, 2)
    start = np.full(m, lo, dtype=np.float64)
    length = np.full(m, span, dtype=np.float64)
    offset = np.arange(m, dtype=np.float64) * span
    present = np.isfinite(positions[:known, :, 0])
    counts = present.sum(axis=1)
    ptr = np.zeros(n_frames + 1)
    ptr[lo + 1 : upto + 2] = np.cumsum(counts)
    ptr[upto + 2 :] = ptr[upto + 1]
    cols = np.zeros(span * m)
    f_idx, c_idx = np.nonzero(present)  # frame-major, columns in order within a frame
    cols[: c_idx.size] = c_idx
    del f_idx
    return np.concatenate([xy.ravel(), start, length, offset, ptr, cols])


# ------------------------------------------------------------------------------ social force
# SocialForceModel.step's arithmetic on the pairs of every social-force slot, split where
# the model calls numpy's arctan2 and exp (numpy's own implementations, which numba's math
# functions do not reproduce bit for bit): the caller computes those two on the arrays
# these kernels return, and the rest runs here, the operations in the model's order.


@jit
def sf_directions(
    dx: np.ndarray,
    dy: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    pvel: np.ndarray,
    avel: np.ndarray,
    lam: float,
    gamma: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per pair: the centre distance, ``t`` (the interaction direction), ``B`` and whether
    it is defined, and the two arguments of ``arctan2`` giving the angle from ``t`` to ``e``
    (:meth:`SocialForceModel.pair_forces
    <conformal_control.world.crowds.social_force.SocialForceModel.pair_forces>`)."""
    n = dx.shape[0]
    dists = np.empty(n)
    tx = np.empty(n)
    ty = np.empty(n)
    big_b = np.empty(n)
    ok = np.empty(n, dtype=np.bool_)
    ya = np.empty(n)
    xa = np.empty(n)
    for q in range(n):
        rx = dx[q]
        ry = dy[q]
        dist = c_hypot(rx, ry)
        dists[q] = dist
        inv = 1.0 / dist if dist > 0.0 else 0.0
        ex = rx * inv
        ey = ry * inv
        i = rows[q]
        j = cols[q]
        bx = lam * (pvel[i, 0] - avel[j, 0]) + ex
        by = lam * (pvel[i, 1] - avel[j, 1]) + ey
        dn = c_hypot(bx, by)
        good = dn > 0.0
        inv_d = 1.0 / dn if good else 0.0
        x = bx * inv_d
        y = by * inv_d
        tx[q] = x
        ty[q] = y
        ok[q] = good
        big_b[q] = gamma * dn
        ya[q] = x * ey - y * ex
        xa[q] = x * ex + y * ey
    return dists, tx, ty, big_b, ok, ya, xa


@jit
def sf_exponents(
    dist: np.ndarray,
    shift: np.ndarray,
    big_b: np.ndarray,
    ok: np.ndarray,
    theta: np.ndarray,
    n_turn: float,
    n_brake: float,
) -> np.ndarray:
    """The arguments of the model's three exponentials, rows 0 (distance), 1 (braking),
    2 (turning), per pair."""
    n = dist.shape[0]
    out = np.empty((3, n))
    for q in range(n):
        d = dist[q] + shift[q]
        d_eq = d if (d >= 0.0 or d != d) else 0.0  # np.maximum(d, 0.0)
        b = big_b[q]
        inv_b = 1.0 / b if ok[q] else 0.0
        out[0, q] = -d_eq * inv_b
        u = n_brake * b * theta[q]
        out[1, q] = -(u * u)
        w = n_turn * b * theta[q]
        out[2, q] = -(w * w)
    return out


@jit
def sf_acceleration(
    start: np.ndarray,
    paired: np.ndarray,
    pref: np.ndarray,
    pvel: np.ndarray,
    tau: float,
    rows: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    dists: np.ndarray,
    ri: np.ndarray,
    rj: np.ndarray,
    tx: np.ndarray,
    ty: np.ndarray,
    ok: np.ndarray,
    theta: np.ndarray,
    expo: np.ndarray,
    strength: float,
    stiffness: float,
) -> np.ndarray:
    """Each pedestrian's acceleration: the driving term plus the sum of its pairs'
    interaction and body force (summed in the pairs' order from 0, as ``np.bincount``)."""
    n = pref.shape[0]
    acc = np.empty((n, 2))
    for g in range(n):
        acc[g, 0] = (pref[g, 0] - pvel[g, 0]) / tau
        acc[g, 1] = (pref[g, 1] - pvel[g, 1]) / tau
    sx = np.zeros(n)
    sy = np.zeros(n)
    neg_a = -strength
    for q in range(rows.shape[0]):
        base = neg_a * expo[0, q] if ok[q] else 0.0
        brake = base * expo[1, q]
        th = theta[q]
        sign = 1.0 if th > 0.0 else (-1.0 if th < 0.0 else th)  # np.sign
        turn = base * sign * expo[2, q]
        fx = brake * tx[q] - turn * ty[q]
        fy = brake * ty[q] + turn * tx[q]
        if stiffness > 0:
            dist = dists[q]
            o = ri[q] + rj[q] - dist
            push = stiffness * (o if (o >= 0.0 or o != o) else 0.0)
            push = push / dist if dist > 0 else 0.0
            fx = fx - push * dx[q]
            fy = fy - push * dy[q]
        i = rows[q]
        sx[i] += fx
        sy[i] += fy
    for s in range(paired.shape[0]):
        if paired[s]:  # (a slot without pairs: its accelerations as the driving term)
            for g in range(start[s], start[s + 1]):
                acc[g, 0] += sx[g]
                acc[g, 1] += sy[g]
    return acc
