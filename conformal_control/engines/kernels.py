"""The replay environment's bookkeeping for many episodes at once, compiled.

What :class:`~conformal_control.world.replay.ReplayEnvironment` does per episode in Python
-- the sensor's range test, the history / truth windows it cuts from the recording, the
per-frame log (the frame clock itself runs in
:func:`~conformal_control.engines.interval.run_interval`) -- written as loops over the
episodes of a batch (:mod:`conformal_control.engines.batch`), with the same floating-point
operations (numba's ``math.hypot`` is the C library's, the one ``numpy.hypot`` calls).
Each episode reads its own recording: the recordings of the live episodes lie in one flat
buffer ``store``; slot ``b``'s is ``store[o : o + F * M * 2]`` seen as ``(F, M, 2)`` with
``(o, F, M) = where[b]`` (plain arrays compile once and are cached, a typed list of arrays
would be compiled anew in every process).
"""

from __future__ import annotations

import math

import numpy as np

from ..compiled import njit

__all__ = [
    "CONSTANT_VELOCITY",
    "ORACLE",
    "count_sensed",
    "d_min",
    "gather_windows",
    "log_frames",
    "predict_interpolate",
    "recording",
]

jit = njit(nogil=True)


@jit
def recording(store: np.ndarray, where: np.ndarray, b: int) -> np.ndarray:
    """Slot ``b``'s recording, ``(F, M, 2)`` (a view of ``store``)."""
    o = where[b, 0]
    return store[o : o + where[b, 1] * where[b, 2] * 2].reshape((where[b, 1], where[b, 2], 2))


@jit
def count_sensed(
    slots: np.ndarray,
    store: np.ndarray,
    where: np.ndarray,
    fi: np.ndarray,
    x: np.ndarray,
    radius: np.ndarray,
    sensed: np.ndarray,
    counts: np.ndarray,
) -> None:
    """The sensor at a sampling time: for each slot ``b`` the agents present at frame
    ``fi[b]`` within ``radius[b]`` (centre distance) of the robot, in column order, written
    to ``sensed[b]``; their number to ``counts[b]``."""
    for i in range(slots.shape[0]):
        b = slots[i]
        pos = recording(store, where, b)
        f = fi[b]
        x0 = x[b, 0]
        x1 = x[b, 1]
        r = radius[b]
        c = 0
        for j in range(pos.shape[1]):
            px = pos[f, j, 0]
            if not math.isfinite(px):
                continue
            if math.hypot(px - x0, pos[f, j, 1] - x1) <= r:
                sensed[b, c] = j
                c += 1
        counts[b] = c


@jit
def gather_windows(
    slots: np.ndarray,
    store: np.ndarray,
    where: np.ndarray,
    lo: np.ndarray,
    sensed: np.ndarray,
    counts: np.ndarray,
    offsets: np.ndarray,
    out: np.ndarray,
) -> None:
    """``recording[lo[b] : lo[b] + L, sensed[b, :counts[b]]]`` of each slot as rows
    ``out[offsets[i] : offsets[i] + counts[b]]`` of shape ``(L, 2)`` (``L = out.shape[1]``),
    NaN outside the recording (the environment's ``_window``)."""
    length = out.shape[1]
    for i in range(slots.shape[0]):
        b = slots[i]
        pos = recording(store, where, b)
        n_frames = pos.shape[0]
        o = offsets[i]
        for a in range(counts[b]):
            j = sensed[b, a]
            for k in range(length):
                f = lo[b] + k
                if 0 <= f < n_frames:
                    out[o + a, k, 0] = pos[f, j, 0]
                    out[o + a, k, 1] = pos[f, j, 1]
                else:
                    out[o + a, k, 0] = math.nan
                    out[o + a, k, 1] = math.nan


@jit
def d_min(pos: np.ndarray, f: int, x0: float, x1: float) -> float:
    """Smallest centre distance to the agents present (finite x) at frame ``f``; NaN if
    none (or if a present agent's distance is NaN, as ``ndarray.min`` would say)."""
    best = math.inf
    seen = False
    for j in range(pos.shape[1]):
        px = pos[f, j, 0]
        if not math.isfinite(px):
            continue
        d = math.hypot(px - x0, pos[f, j, 1] - x1)
        if math.isnan(d):
            return math.nan
        seen = True
        if d < best:
            best = d
    return best if seen else math.nan


@jit
def log_frames(
    slots: np.ndarray,
    store: np.ndarray,
    where: np.ndarray,
    fi: np.ndarray,
    x: np.ndarray,
    t: np.ndarray,
    log: np.ndarray,
    n_log: np.ndarray,
) -> None:
    """Append the frame record ``(t, x, y, vx, vy, d_min)`` of each slot to
    ``log[b, n_log[b]]``."""
    for i in range(slots.shape[0]):
        b = slots[i]
        k = n_log[b]
        log[b, k, 0] = t[b]
        for c in range(4):
            log[b, k, 1 + c] = x[b, c]
        log[b, k, 5] = d_min(recording(store, where, b), fi[b], x[b, 0], x[b, 1])
        n_log[b] = k + 1


#: Predictor codes of :func:`predict_interpolate`.
CONSTANT_VELOCITY, ORACLE = 0, 1


@jit
def predict_interpolate(
    slots: np.ndarray,
    store: np.ndarray,
    where: np.ndarray,
    fi: np.ndarray,
    sensed: np.ndarray,
    n_agents: np.ndarray,
    predictor: np.ndarray,
    window: np.ndarray,
    history: np.ndarray,
    tau: np.ndarray,
    substeps: np.ndarray,
    dt_frame: np.ndarray,
    samples: np.ndarray,
    xp: np.ndarray,
    vp: np.ndarray,
    n_short: np.ndarray,
    n_bad: np.ndarray,
) -> None:
    """The controller's predictions at a sampling time, for each slot ``b``: its sensed
    agents' forecast over ``tau[b]`` frames, sanitised and interpolated at the interval's
    control instants into ``xp[b, :, :n]`` / ``vp[b, :, :n]``.

    The forecast is, agent by agent, that of the episode's predictor (``predictor[b]``):
    :class:`~conformal_control.predictors.constant_velocity.ConstantVelocityPredictor`
    with ``window[b]`` on the last ``history[b]`` frames (``n_short[b]``: agents predicted
    to stand still for want of a second sample), or the recording's future
    (:class:`~conformal_control.predictors.oracle.OraclePredictor`). As the controller does,
    the current positions are prepended, non-finite samples are replaced by the last
    finite one (``n_bad[b]``: agents concerned;
    :func:`~conformal_control.cbf.interp.forward_fill`) and the samples are interpolated
    (:func:`~conformal_control.cbf.interp.interpolate_at_substeps`). ``samples`` is a
    buffer of at least ``tau + 1`` rows.
    """
    for i in range(slots.shape[0]):
        b = slots[i]
        pos = recording(store, where, b)
        n_frames = pos.shape[0]
        f = fi[b]
        dt = dt_frame[b]
        horizon = tau[b]
        sub = substeps[b]
        short = 0
        bad = 0
        for a in range(n_agents[b]):
            j = sensed[b, a]
            cx = pos[f, j, 0]
            cy = pos[f, j, 1]
            samples[0, 0] = cx
            samples[0, 1] = cy
            if predictor[b] == CONSTANT_VELOCITY:
                # trailing run of finite samples in the history window (frames f-H+1 .. f),
                # counted up to window + 1 (longer runs give the same k)
                run = 0
                for back in range(min(history[b], window[b] + 1)):
                    g = f - back
                    if g < 0 or g >= n_frames:
                        break
                    if not (math.isfinite(pos[g, j, 0]) and math.isfinite(pos[g, j, 1])):
                        break
                    run += 1
                k = min(run - 1, window[b])
                if k < 0:
                    k = 0
                vx = 0.0
                vy = 0.0
                if k > 0:
                    vx = (cx - pos[f - k, j, 0]) / (k * dt)
                    vy = (cy - pos[f - k, j, 1]) / (k * dt)
                else:
                    short += 1
                for h in range(horizon):
                    lead = (h + 1.0) * dt
                    samples[h + 1, 0] = cx + vx * lead
                    samples[h + 1, 1] = cy + vy * lead
            else:
                for h in range(horizon):
                    g = f + 1 + h
                    if g < n_frames:
                        samples[h + 1, 0] = pos[g, j, 0]
                        samples[h + 1, 1] = pos[g, j, 1]
                    else:
                        samples[h + 1, 0] = math.nan
                        samples[h + 1, 1] = math.nan
            had_bad = False
            for h in range(1, horizon + 1):
                if not (math.isfinite(samples[h, 0]) and math.isfinite(samples[h, 1])):
                    samples[h, 0] = samples[h - 1, 0]
                    samples[h, 1] = samples[h - 1, 1]
                    had_bad = True
            if had_bad:
                bad += 1
            for s in range(horizon * sub):
                q = s // sub
                frac = (s % sub) / sub
                d0 = samples[q + 1, 0] - samples[q, 0]
                d1 = samples[q + 1, 1] - samples[q, 1]
                xp[b, s, a, 0] = samples[q, 0] + frac * d0
                xp[b, s, a, 1] = samples[q, 1] + frac * d1
                vp[b, s, a, 0] = d0 / dt
                vp[b, s, a, 1] = d1 / dt
        n_short[b] = short
        n_bad[b] = bad
