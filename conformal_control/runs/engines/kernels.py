"""The replay environment's bookkeeping for many episodes at once, compiled.

What :class:`~conformal_control.world.replay.ReplayEnvironment` does per episode in Python
-- the sensor's range test, the history / truth windows it cuts from the recording, the
per-frame log (the frame clock itself runs in
:func:`~conformal_control.runs.engines.interval.run_interval`) -- written as loops over the
episodes of a batch (:mod:`conformal_control.runs.engines.batch`), with the same floating-point
operations (numba's ``math.hypot`` is the C library's, the one ``numpy.hypot`` calls).
Each episode reads its own recording, stored sparsely as the scene holds it
(:class:`~conformal_control.data.scene.SparseTracks`: memory proportional to the
observations, not to frames x agents). The recordings of the live episodes lie in one flat
float64 buffer ``store`` (plain arrays compile once and are cached, a typed list of arrays
would be compiled anew in every process); slot ``b``'s starts at ``o`` with ``(o, F, M, N,
K) = where[b]`` (frames, agents, stored samples, present samples) and holds, in order
(:func:`pack`): the ``N`` samples ``(x, y)``, then each agent's first frame, span and
first sample row, the ``F + 1`` frame pointers and the ``K`` columns present at each frame
(the index tables as float64, exact below 2**53). :func:`sample` reads one agent at one
frame, :func:`frame_range` the agents present at a frame.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ...core.jit import kernel
from ...families.cbf.pyhypot import c_hypot
from .recorded_kernels import find_issue, forecast_agent, snap_times

if TYPE_CHECKING:
    from ...data.scene import SparseTracks

__all__ = [
    "CONSTANT_VELOCITY",
    "DELAYED",
    "DROPOUT",
    "NOISY",
    "NO_SHIFT",
    "ORACLE",
    "RECORDED",
    "SCALED",
    "count_sensed",
    "d_min",
    "dropout_draw",
    "frame_range",
    "gather_windows",
    "log_frames",
    "pack",
    "predict_interpolate",
    "sample",
    "slot_size",
]

jit = kernel(cache=True, nogil=True)


def pack(tracks: SparseTracks) -> np.ndarray:
    """One episode's recording laid out as the engine's kernels read it (module docstring)."""
    return np.concatenate(
        [
            tracks.xy.ravel(),
            tracks.start,
            tracks.length,
            tracks.offset,
            tracks.frame_ptr,
            tracks.frame_cols,
        ]
    ).astype(np.float64, copy=False)


def slot_size(frames: int, agents: int, samples: int, present: int) -> int:
    """Floats of :func:`pack`'s layout for these counts.

    Parameters
    ----------
    frames : int
        Frames of the recording (the per-frame index has ``frames + 1`` entries).
    agents : int
        Agents of the recording (start, length and offset of each).
    samples : int
        Observations (one position, two floats, each).
    present : int
        Entries of the per-frame index of the agents present.
    """
    return 2 * samples + 3 * agents + frames + 1 + present


@jit
def sample(store: np.ndarray, where: np.ndarray, b: int, f: int, j: int) -> tuple[float, float]:
    """Agent ``j``'s position at frame ``f`` in slot ``b``'s recording (NaN outside its
    span: the dense array's value)."""
    m = where[b, 2]
    s0 = where[b, 0] + 2 * where[b, 3]  # the index tables
    k = f - int(store[s0 + j])
    if k < 0 or k >= int(store[s0 + m + j]):
        return math.nan, math.nan
    r = where[b, 0] + 2 * (int(store[s0 + 2 * m + j]) + k)
    return store[r], store[r + 1]


@jit
def frame_range(store: np.ndarray, where: np.ndarray, b: int, f: int) -> tuple[int, int]:
    """``(lo, hi)``: the agents present (finite x) at frame ``f`` of slot ``b`` are
    ``int(store[lo])`` .. ``int(store[hi - 1])``, in column order."""
    m = where[b, 2]
    ptr = where[b, 0] + 2 * where[b, 3] + 3 * m + f
    cols = where[b, 0] + 2 * where[b, 3] + 3 * m + where[b, 1] + 1
    return cols + int(store[ptr]), cols + int(store[ptr + 1])


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
        f = fi[b]
        x0 = x[b, 0]
        x1 = x[b, 1]
        r = radius[b]
        c = 0
        lo, hi = frame_range(store, where, b, f)
        for q in range(lo, hi):
            j = int(store[q])
            px, py = sample(store, where, b, f, j)
            if c_hypot(px - x0, py - x1) <= r:
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
        o = offsets[i]
        for a in range(counts[b]):
            j = sensed[b, a]
            for k in range(length):
                px, py = sample(store, where, b, lo[b] + k, j)
                out[o + a, k, 0] = px
                out[o + a, k, 1] = py


@jit
def d_min(store: np.ndarray, where: np.ndarray, b: int, f: int, x0: float, x1: float) -> float:
    """Smallest centre distance to the agents present (finite x) at frame ``f`` of slot
    ``b``'s recording; NaN if none (or if a present agent's distance is NaN, as
    ``ndarray.min`` would say)."""
    best = math.inf
    seen = False
    lo, hi = frame_range(store, where, b, f)
    for q in range(lo, hi):
        px, py = sample(store, where, b, f, int(store[q]))
        d = c_hypot(px - x0, py - x1)
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
        log[b, k, 5] = d_min(store, where, b, fi[b], x[b, 0], x[b, 1])
        n_log[b] = k + 1


#: Predictor codes of :func:`predict_interpolate`.
CONSTANT_VELOCITY, ORACLE, RECORDED = 0, 1, 2
#: Shift codes of :func:`predict_interpolate` (:mod:`conformal_control.predictors.shift`):
#: none, ``delayed``, ``noisy``, ``scaled``, ``dropout``.
NO_SHIFT, DELAYED, NOISY, SCALED, DROPOUT = 0, 1, 2, 3, 4

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)


def _dropout_draw_python(seed: int, scene: int, agent: int, block: int) -> float:
    from ...predictors.shift import hash_uniform

    return float(hash_uniform(seed, scene, agent, block, 2)[0])


@kernel(cache=True, nogil=True, inline="always")
def _mix(x: np.uint64) -> np.uint64:
    """SplitMix64's finaliser (wrapping uint64 arithmetic), as
    :func:`~conformal_control.predictors.shift.hash_uniform` folds its keys."""
    x = x + _GOLDEN
    x = (x ^ (x >> _S30)) * _M1
    x = (x ^ (x >> _S27)) * _M2
    out: np.uint64 = x ^ (x >> _S31)
    return out


@kernel(cache=True, nogil=True, inline="always", python=_dropout_draw_python)
def dropout_draw(seed: int, scene: int, agent: int, block: int) -> float:
    """``hash_uniform(seed, scene, agent, block, 2)``: the uniform number
    :meth:`DropoutPredictor.missing <conformal_control.predictors.shift.DropoutPredictor.missing>`
    draws for an agent and a block (the same 53 bits of the same hash of the keys' int64
    bit patterns).

    Parameters
    ----------
    seed, scene, agent, block : int
        The keys (the predictor's seed, the scene's key, the agent's id, the block).
    """
    h = _mix(np.uint64(seed))
    h = _mix(h ^ np.uint64(scene))
    h = _mix(h ^ np.uint64(agent))
    h = _mix(h ^ np.uint64(block))
    h = _mix(h ^ np.uint64(2))
    return float(h >> _S11) * 2.0**-53


@jit
def _seen(
    store: np.ndarray,
    where: np.ndarray,
    b: int,
    g: int,
    j: int,
    dropout: bool,
    seed: int,
    scene: int,
    agent: int,
    first: int,
    dt: float,
    dur: float,
    p: float,
) -> tuple[float, float]:
    """Agent ``j``'s sample at frame ``g`` as its predictor sees it: the recording's, NaN
    where a ``dropout`` shift removed the detection (its block drawn missing)."""
    gx, gy = sample(store, where, b, g, j)
    if dropout and math.isfinite(gx) and math.isfinite(gy):
        block = math.floor(float(first + g) * dt / dur + 1e-9)
        if dropout_draw(seed, scene, agent, block) < p:
            return math.nan, math.nan
    return gx, gy


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
    shift: np.ndarray,
    shift_k: np.ndarray,
    shift_x: np.ndarray,
    seeds: np.ndarray,
    scene_keys: np.ndarray,
    first_frame: np.ndarray,
    agent_id: np.ndarray,
    noise: np.ndarray,
    shift_counts: np.ndarray,
    rec: np.ndarray,
    rec_at: np.ndarray,
    rec_step: np.ndarray,
    rec_counts: np.ndarray,
) -> None:
    """The controller's predictions at a sampling time, for each slot ``b``: its sensed
    agents' forecast over ``tau[b]`` frames, sanitised and interpolated at the interval's
    control instants into ``xp[b, :, :n]`` / ``vp[b, :, :n]``.

    The forecast is, agent by agent, that of the episode's predictor (``predictor[b]``):
    :class:`~conformal_control.predictors.constant_velocity.ConstantVelocityPredictor`
    with ``window[b]`` on the last ``history[b]`` frames (``n_short[b]``: agents predicted
    to stand still for want of a second sample), or the recording's future
    (:class:`~conformal_control.predictors.oracle.OraclePredictor`), or the forecasts of a
    predictions file (``RECORDED``:
    :class:`~conformal_control.predictors.recorded.RecordedPredictor`, slot ``b``'s block
    of :func:`~conformal_control.runs.engines.recorded_kernels.pack` at ``rec_at[b]`` in ``rec``,
    step length ``rec_step[b]`` seconds, the agents' ids ``agent_id[b]``, frame numbers
    from ``first_frame[b]``; an agent without a recorded forecast predicted at constant
    velocity with ``window[b]``; ``rec_counts[b]``: agents without one (missing), missing
    steps, agents extrapolated, agents without a finite current position), under the episode's
    predictor shift (``shift[b]``, :mod:`~conformal_control.predictors.shift`, with the
    same arithmetic and the same fallbacks):

    * ``DELAYED`` by ``shift_k[b]`` frames: the forecast made at frame ``f - k`` from the
      history up to it (an agent not seen then: from its last earlier sample, counted
      ``shift_counts[b, 0]`` (stale), or standing at its first sample of the history,
      ``shift_counts[b, 1]`` (unseen)), used as current; the oracle's is the recording
      from frame ``f - k + 1``;
    * ``NOISY``: the forecast displaced by ``noise[b, a]`` (the agent's draw, computed
      by the caller with the predictor's own hash);
    * ``SCALED`` by ``shift_x[b, 0]``: the displacement from the current position scaled
      (0: every agent stands where it is, the wrapped predictor not asked);
    * ``DROPOUT`` with probability ``shift_x[b, 0]`` in blocks of ``shift_x[b, 1]``
      seconds (seed ``seeds[b]``, scene key ``scene_keys[b]``, the agents' ids
      ``agent_id[b]``, frame numbers from ``first_frame[b]``): missing samples removed
      from the history; an agent whose current detection is missing
      (``shift_counts[b, 2]``) is predicted from its last detection (stale) or stands at
      its first sample (unseen).

    As the controller does, the current positions are prepended, non-finite samples are
    replaced by the last finite one (``n_bad[b]``: agents concerned;
    :func:`~conformal_control.families.cbf.interp.forward_fill`) and the samples are interpolated
    (:func:`~conformal_control.families.cbf.interp.interpolate_at_substeps`). ``samples`` is a
    buffer of at least ``tau + 1`` rows.
    """
    for i in range(slots.shape[0]):
        b = slots[i]
        n_frames = where[b, 1]
        f = fi[b]
        dt = dt_frame[b]
        horizon = tau[b]
        sub = substeps[b]
        kind = shift[b]
        delay = shift_k[b] if kind == DELAYED else 0
        dropout = kind == DROPOUT
        lo = f - history[b] + 1  # the history window's first frame
        short = 0
        bad = 0
        code = predictor[b]
        o = rec_at[b]
        t_q = float(first_frame[b] + f) * dt
        issue = -1
        steps = 0
        times = np.empty(horizon if code == RECORDED else 0)
        if code == RECORDED:  # the issue the query's time reads, and its requested times
            issue = find_issue(rec, o, t_q)
            if issue >= 0:
                snap_times(rec, o, issue, t_q, dt, rec_step[b], times)
                steps = int(rec[o + 1 + 2 * int(rec[o]) + issue])
        knot_t = np.empty(steps + 1)
        knot_x = np.empty(steps + 1)
        knot_y = np.empty(steps + 1)
        for a in range(n_agents[b]):
            j = sensed[b, a]
            agent = agent_id[b, j]
            cx, cy = sample(store, where, b, f, j)
            samples[0, 0] = cx
            samples[0, 1] = cy
            frozen = kind == SCALED and shift_x[b, 0] == 0.0
            use = code
            if code == RECORDED:
                if not (math.isfinite(cx) and math.isfinite(cy)):  # NaN, not predicted
                    rec_counts[b, 3] += 1
                    use = -1
                    for h in range(horizon):
                        samples[h + 1, 0] = math.nan
                        samples[h + 1, 1] = math.nan
                elif forecast_agent(rec, o, issue, agent, cx, cy, t_q, rec_step[b], times,
                                    samples, knot_t, knot_x, knot_y, rec_counts[b]):  # fmt: skip
                    use = -1
                else:  # no recorded forecast: the fallback's
                    rec_counts[b, 0] += 1
                    use = CONSTANT_VELOCITY
            if use < 0:
                pass
            elif frozen:  # every agent stands where it is: the predictor is not asked
                for h in range(horizon):
                    samples[h + 1, 0] = cx
                    samples[h + 1, 1] = cy
            else:
                # the frame the predictor takes for current, and its sample there
                fc = f - delay
                ax, ay = _seen(store, where, b, fc, j, dropout, seeds[b], scene_keys[b],
                               agent, first_frame[b], dt, shift_x[b, 1], shift_x[b, 0])  # fmt: skip
                unseen = False
                cut = not (math.isfinite(ax) and math.isfinite(ay))
                if cut and (delay > 0 or dropout):  # not seen at fc: cut or dropped
                    if dropout:
                        shift_counts[b, 2] += 1
                    g = fc - 1
                    while g >= lo:
                        ax, ay = _seen(store, where, b, g, j, dropout, seeds[b], scene_keys[b],
                                       agent, first_frame[b], dt, shift_x[b, 1],
                                       shift_x[b, 0])  # fmt: skip
                        if math.isfinite(ax) and math.isfinite(ay):
                            break
                        g -= 1
                    if g >= lo:  # its last sample before: taken for current
                        fc = g
                        shift_counts[b, 0] += 1
                    else:  # none: it stands at its first sample of the history
                        unseen = True
                        shift_counts[b, 1] += 1
                        for g in range(lo, f + 1):
                            ax, ay = sample(store, where, b, g, j)
                            if math.isfinite(ax) and math.isfinite(ay):
                                break
                if use == CONSTANT_VELOCITY:
                    # trailing run of finite samples in the history window up to fc
                    # (frames lo .. fc), counted up to window + 1 (longer runs give the
                    # same k)
                    run = 1
                    if not unseen:
                        run = 0
                        for back in range(min(fc - lo + 1, window[b] + 1)):
                            g = fc - back
                            if g < 0 or g >= n_frames:
                                break
                            gx, gy = _seen(store, where, b, g, j, dropout, seeds[b],
                                           scene_keys[b], agent, first_frame[b], dt,
                                           shift_x[b, 1], shift_x[b, 0])  # fmt: skip
                            if not (math.isfinite(gx) and math.isfinite(gy)):
                                break
                            run += 1
                    k = min(run - 1, window[b])
                    if k < 0:
                        k = 0
                    vx = 0.0
                    vy = 0.0
                    if k > 0:
                        kx, ky = sample(store, where, b, fc - k, j)
                        vx = (ax - kx) / (k * dt)
                        vy = (ay - ky) / (k * dt)
                    else:
                        short += 1
                    for h in range(horizon):
                        lead = (h + 1.0) * dt
                        samples[h + 1, 0] = ax + vx * lead
                        samples[h + 1, 1] = ay + vy * lead
                else:  # the recording's future of the frame taken for current
                    for h in range(horizon):
                        g = f - delay + 1 + h
                        if g < n_frames:
                            samples[h + 1, 0], samples[h + 1, 1] = sample(store, where, b, g, j)
                        else:
                            samples[h + 1, 0] = math.nan
                            samples[h + 1, 1] = math.nan
                if kind == NOISY:
                    for h in range(horizon):
                        samples[h + 1, 0] = samples[h + 1, 0] + noise[b, a, 0]
                        samples[h + 1, 1] = samples[h + 1, 1] + noise[b, a, 1]
                elif kind == SCALED:
                    s = shift_x[b, 0]
                    for h in range(horizon):
                        samples[h + 1, 0] = cx + s * (samples[h + 1, 0] - cx)
                        samples[h + 1, 1] = cy + s * (samples[h + 1, 1] - cy)
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
