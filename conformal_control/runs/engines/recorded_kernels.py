"""Recorded forecasts (the ``recorded`` predictor) replayed for many episodes at once, compiled.

:class:`~conformal_control.predictors.recorded.RecordedPredictor` answers a query from the
forecasts of a predictions file: the latest forecast issued at or before the query's time,
anchored at the agent's current position and interpolated at the requested times
(``numpy.interp``), its last segment's velocity held beyond its last step; an agent without
one is predicted by its fallback. The batch engine runs that arithmetic here, agent by agent,
with the same floating-point operations in the same order: :func:`interp` is ``numpy.interp``'s
algorithm (numpy's ``arr_interp``: the same bracket, the same slope formula, the same
returns at and beyond the knots, its two-sided retry on NaN), so that every forecast is the
predictor's to the bit (``tests/runs/engines/test_batch_recorded.py``; written by hand because
numba's own ``np.interp`` is a separate implementation this module would have to trust).

An episode's forecasts lie in one flat float64 block (:func:`pack`), of the issue frames
its sampling times can read: ``K``, then the ``K`` issue times, then per issue its number
of agents, its number of steps, the offset of its agents' ids and the offset of its points
(offsets from the block's start), then the ids (exact below 2**53: the reader refuses
larger ones) and the points ``(agents, steps, 2)`` (NaN where the file has no row).
"""

from __future__ import annotations

import math

import numpy as np

from ...core.jit import kernel

__all__ = ["EPS", "find_issue", "forecast_agent", "interp", "pack", "snap_times"]

jit = kernel(cache=True, nogil=True)

#: The clocks' rounding tolerance of the predictor (s): a time within it of another is
#: that time.
EPS = 1e-9


def pack(times: np.ndarray, ids: list[np.ndarray], points: list[np.ndarray]) -> np.ndarray:
    """One episode's forecasts laid out as the kernels read them (module docstring).

    Parameters
    ----------
    times : ndarray of shape (K,)
        The issue times (s), increasing.
    ids : list of ndarray
        Per issue, its agents' ids (sorted).
    points : list of ndarray
        Per issue, the forecast positions ``(agents, steps, 2)``.
    """
    k = int(times.size)
    head = 1 + 5 * k
    offsets = np.zeros((2, k))
    at = head
    for i in range(k):
        offsets[0, i] = at
        at += ids[i].size
    for i in range(k):
        offsets[1, i] = at
        at += points[i].size
    parts = [
        np.array([float(k)]),
        np.asarray(times, dtype=float),
        np.array([a.size for a in ids], dtype=float),
        np.array([p.shape[1] for p in points], dtype=float),
        offsets[0],
        offsets[1],
        *(np.asarray(a, dtype=float) for a in ids),
        *(np.asarray(p, dtype=float).ravel() for p in points),
    ]
    return np.concatenate(parts)


@jit
def find_issue(rec: np.ndarray, o: int, t_q: float) -> int:
    """The index of the latest forecast of the block at ``o`` issued at or before
    ``t_q`` (within :data:`EPS`), -1 if none: ``numpy.searchsorted(times, t_q + EPS,
    side="right") - 1``."""
    k = int(rec[o])
    key = t_q + EPS
    lo = 0
    hi = k
    while lo < hi:  # the first index whose time is above the key
        mid = (lo + hi) // 2
        if rec[o + 1 + mid] <= key:
            lo = mid + 1
        else:
            hi = mid
    return lo - 1


@jit
def snap_times(
    rec: np.ndarray, o: int, k: int, t_q: float, dt: float, step_s: float, out: np.ndarray
) -> None:
    """The requested times ``t_q + dt, ..., t_q + len(out) dt`` of issue ``k``'s forecast,
    each one within :data:`EPS` of one of its knots ``t_f + step_s, ...`` replaced by the
    first such knot (the predictor returns the file's values exactly there)."""
    steps = int(rec[o + 1 + 2 * int(rec[o]) + k])
    t_f = rec[o + 1 + k]
    for h in range(out.shape[0]):
        t = t_q + dt * float(h + 1)
        out[h] = t
        for s in range(steps):
            knot = t_f + step_s * float(s + 1)
            if abs(t - knot) < EPS:
                out[h] = knot
                break


@jit
def interp(x: float, xp: np.ndarray, fp: np.ndarray, n: int) -> float:
    """``numpy.interp(x, xp[:n], fp[:n])`` for one finite ``x`` (``n >= 2``, ``xp``
    increasing): numpy's algorithm, operation for operation (module docstring)."""
    if x < xp[0]:
        return float(fp[0])
    if x >= xp[n - 1]:
        return float(fp[n - 1])
    lo = 0
    hi = n - 1
    while hi - lo > 1:  # xp[lo] <= x < xp[hi]
        mid = (lo + hi) // 2
        if xp[mid] <= x:
            lo = mid
        else:
            hi = mid
    j = lo
    if xp[j] == x:
        return float(fp[j])
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    r = slope * (x - xp[j]) + fp[j]
    if math.isnan(r):  # numpy tries the other side
        r = slope * (x - xp[j + 1]) + fp[j + 1]
        if math.isnan(r) and fp[j] == fp[j + 1]:
            r = fp[j]
    return float(r)


@jit
def forecast_agent(
    rec: np.ndarray,
    o: int,
    k: int,
    agent: int,
    cx: float,
    cy: float,
    t_q: float,
    step_s: float,
    times: np.ndarray,
    samples: np.ndarray,
    kt: np.ndarray,
    kx: np.ndarray,
    ky: np.ndarray,
    counts: np.ndarray,
) -> bool:
    """Agent ``agent``'s forecast from issue ``k`` of the block at ``o`` (current position
    ``(cx, cy)``, finite, at ``t_q``), at the (snapped) ``times``, into
    ``samples[1:]``, as :meth:`RecordedPredictor.predict
    <conformal_control.predictors.recorded.RecordedPredictor.predict>` computes it;
    False if the issue has no forecast of the agent, or none with a finite point after
    ``t_q`` (the fallback predicts it then). Counts, as the predictor's ``info``:
    ``counts[1]`` the forecast's missing steps (an agent of the issue),
    ``counts[2]`` agents extrapolated beyond their forecast's last step. ``kt``, ``kx``
    and ``ky`` are scratch buffers of at least ``steps + 1`` entries (the knots' times
    and positions)."""
    if k < 0:
        return False
    n_issues = int(rec[o])
    head = o + 1 + n_issues
    n_k = int(rec[head + k])
    steps = int(rec[head + n_issues + k])
    io = o + int(rec[head + 2 * n_issues + k])
    po = o + int(rec[head + 3 * n_issues + k])
    lo = 0
    hi = n_k
    key = float(agent)
    while lo < hi:  # the first id >= the agent's
        mid = (lo + hi) // 2
        if rec[io + mid] < key:
            lo = mid + 1
        else:
            hi = mid
    if lo >= n_k or rec[io + lo] != key:
        return False
    row = po + lo * steps * 2
    t_f = rec[o + 1 + k]
    kt[0] = t_q
    kx[0] = cx
    ky[0] = cy
    m = 1
    missing = 0
    for s in range(steps):
        px = rec[row + 2 * s]
        py = rec[row + 2 * s + 1]
        if not (math.isfinite(px) and math.isfinite(py)):
            missing += 1
            continue
        knot = t_f + step_s * float(s + 1)
        if knot > t_q + EPS:
            kt[m] = knot
            kx[m] = px
            ky[m] = py
            m += 1
    counts[1] += missing
    if m == 1:
        return False
    last = kt[m - 1]
    vx = (kx[m - 1] - kx[m - 2]) / (kt[m - 1] - kt[m - 2])
    vy = (ky[m - 1] - ky[m - 2]) / (kt[m - 1] - kt[m - 2])
    beyond = False
    for h in range(times.shape[0]):
        t = times[h]
        if t > last + EPS:  # the last segment's velocity held
            samples[h + 1, 0] = kx[m - 1] + (t - last) * vx
            samples[h + 1, 1] = ky[m - 1] + (t - last) * vy
            beyond = True
        else:
            samples[h + 1, 0] = interp(t, kt, kx, m)
            samples[h + 1, 1] = interp(t, kt, ky, m)
    if beyond:
        counts[2] += 1
    return True
