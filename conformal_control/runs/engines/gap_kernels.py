"""The gap loss of many episodes at once, compiled (the lockstep engine's interval end).

:func:`gap_maxima` scores the intervals that end at a sampling time for every episode of a
batch: the largest gap between the APF constraint on the predicted and on the true agents
(:class:`~conformal_control.families.cbf.loss.CBFGapLoss`, with
:meth:`~conformal_control.families.cbf.constraint.ConformalConstraint.value`'s arithmetic), agent by
agent and instant by instant. The control instants themselves run in
:func:`~conformal_control.runs.engines.interval.run_interval`, which calls the exact 2-D
filter's fused APF step (:func:`~conformal_control.families.cbf.kernels2d.apf_step`) as is.
:data:`SEARCH`, :data:`BRAKE`, :data:`HOLD` and :data:`PYTHON` are the fallback codes the engine
gives it.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.jit import kernel
from ...families.cbf.pyhypot import c_hypot

__all__ = ["BRAKE", "HOLD", "PYTHON", "SEARCH", "gap_maxima"]

#: Fallback codes of the engine (``lambda_search`` runs inside ``apf_step``; ``PYTHON``: a
#: fallback the episode's own object decides, e.g. ``relax``).
SEARCH, BRAKE, HOLD, PYTHON = 0, 1, 2, 3

jit = kernel(cache=True, nogil=True)


@jit
def _apf_value(
    ex: float,
    ey: float,
    evx: float,
    evy: float,
    ax: float,
    ay: float,
    avx: float,
    avy: float,
    prm: np.ndarray,
) -> float:
    """``dh/dx . v + dh/dx_j . v_j + a h`` for the APF barrier of ``prm`` (the arithmetic
    of :meth:`APFBarrier.evaluate` and :meth:`ConformalConstraint.value`)."""
    K = prm[0]
    rho0 = prm[1]
    d0 = ex - ax
    d1 = ey - ay
    d = c_hypot(d0, d1)
    rho = d - prm[2] if prm[4] != 0.0 else d
    r = min(max(rho, 0.0), rho0)
    q = 1.0 - r / rho0
    r2 = r * r
    inv_d = 1.0 / (2.0 * r2 + K * q * q)
    h = 2.0 * r2 * inv_d - prm[3]
    scale = 4.0 * K * q * r * inv_d * inv_d / max(d, 1e-300)
    g0 = scale * d0
    g1 = scale * d1
    value: float = (g0 * evx + g1 * evy) + ((-g0) * avx + (-g1) * avy) + prm[5] * h
    return value


def _apf_values(
    ex: np.ndarray,
    ey: np.ndarray,
    evx: np.ndarray,
    evy: np.ndarray,
    ax: np.ndarray,
    ay: np.ndarray,
    avx: np.ndarray,
    avy: np.ndarray,
    prm: np.ndarray,
) -> np.ndarray:
    """:func:`_apf_value` on arrays, element by element: the same operations in the same
    order (``min`` and ``max`` as Python's, which return their first argument on a tie)."""
    K = prm[0]
    rho0 = prm[1]
    d0 = ex - ax
    d1 = ey - ay
    d = np.hypot(d0, d1)  # c_hypot interpreted
    rho = d - prm[2] if prm[4] != 0.0 else d
    r = np.where(0.0 > rho, 0.0, rho)
    r = np.where(rho0 < r, rho0, r)
    q = 1.0 - r / rho0
    r2 = r * r
    inv_d = 1.0 / (2.0 * r2 + K * q * q)
    h = 2.0 * r2 * inv_d - prm[3]
    scale = 4.0 * K * q * r * inv_d * inv_d / np.where(1e-300 > d, 1e-300, d)
    g0 = scale * d0
    g1 = scale * d1
    value: np.ndarray = (g0 * evx + g1 * evy) + ((-g0) * avx + (-g1) * avy) + prm[5] * h
    return value


def _gap_maxima_numpy(
    slots: np.ndarray,
    offsets: np.ndarray,
    n_agents: np.ndarray,
    step: np.ndarray,
    truth: np.ndarray,
    dt_frame: np.ndarray,
    substeps: np.ndarray,
    rec_x: np.ndarray,
    rec_v: np.ndarray,
    rec_lam: np.ndarray,
    xp: np.ndarray,
    vp: np.ndarray,
    lam: np.ndarray,
    prm: np.ndarray,
    top: np.ndarray,
    top_applied: np.ndarray,
    n_pairs: np.ndarray,
    vec: np.ndarray,
    lam_off: np.ndarray,
    agent_top: np.ndarray,
) -> None:
    """:func:`gap_maxima`'s interpreted form: each slot's (instant, agent) pairs as arrays
    (the same IEEE operations pair by pair, so the same numbers; the maxima of the same
    values). A single run keeps its kernels interpreted (:mod:`conformal_control.core.jit`):
    the scalar loop would be its largest cost."""
    for i in range(slots.shape[0]):
        b = int(slots[i])
        o = int(offsets[i])
        n = int(n_agents[b])
        s = int(step[b])
        sub = int(substeps[b])
        top[b] = -math.inf
        top_applied[b] = -math.inf
        n_pairs[b] = 0
        if vec[b]:
            agent_top[o : o + n] = -math.inf
        if n == 0 or s == 0:
            continue
        k = np.arange(s)
        j = k // sub
        frac = (k % sub) / sub
        la = rec_lam[b, :s].copy()
        la[~np.isfinite(la)] = lam[b]
        rows = truth[o : o + n]
        px0 = rows[:, j, 0]  # (agents, instants)
        py0 = rows[:, j, 1]
        dx = rows[:, j + 1, 0] - px0
        dy = rows[:, j + 1, 1] - py0
        tx = px0 + frac * dx
        ty = py0 + frac * dy
        dt = dt_frame[b]
        tvx = dx / dt
        tvy = dy / dt
        ok = np.isfinite(tx) & np.isfinite(ty) & np.isfinite(tvx) & np.isfinite(tvy)
        count = int(ok.sum())
        if count:
            ex = rec_x[b, :s, 0]
            ey = rec_x[b, :s, 1]
            evx = rec_v[b, :s, 0]
            evy = rec_v[b, :s, 1]
            p = prm[b]
            pred = _apf_values(
                ex, ey, evx, evy, xp[b, :s, :n, 0].T, xp[b, :s, :n, 1].T, vp[b, :s, :n, 0].T,
                vp[b, :s, :n, 1].T, p,
            )  # fmt: skip
            gap = pred - _apf_values(ex, ey, evx, evy, tx, ty, tvx, tvy, p)
            g = gap[ok]
            if vec[b]:  # each agent's row: the lambda applied plus its offset
                g_applied = (gap + (la[None, :] + lam_off[b, :n, None]))[ok]
                per = np.where(ok, gap, -math.inf)
                per = np.where(np.isnan(per), -math.inf, per)
                agent_top[o : o + n] = per.max(axis=1)
            else:
                g_applied = (gap + la)[ok]
            # the loop's `>` never takes a NaN
            if g.size and not np.isnan(g).all():
                top[b] = float(np.nanmax(g))
            if g_applied.size and not np.isnan(g_applied).all():
                top_applied[b] = float(np.nanmax(g_applied))
        n_pairs[b] = count


@kernel(cache=True, nogil=True, python=_gap_maxima_numpy)
def gap_maxima(
    slots: np.ndarray,
    offsets: np.ndarray,
    n_agents: np.ndarray,
    step: np.ndarray,
    truth: np.ndarray,
    dt_frame: np.ndarray,
    substeps: np.ndarray,
    rec_x: np.ndarray,
    rec_v: np.ndarray,
    rec_lam: np.ndarray,
    xp: np.ndarray,
    vp: np.ndarray,
    lam: np.ndarray,
    prm: np.ndarray,
    top: np.ndarray,
    top_applied: np.ndarray,
    n_pairs: np.ndarray,
    vec: np.ndarray,
    lam_off: np.ndarray,
    agent_top: np.ndarray,
) -> None:
    """The gap loss's maxima for the interval that ends now, per slot.

    The ``i``-th slot ``b`` has ``n_agents[b]`` sensed agents whose true positions at the
    interval's frames are rows ``truth[offsets[i] + a]`` (NaN where unobserved); it ran
    ``step[b]`` control instants. As :class:`~conformal_control.families.cbf.loss.CBFGapLoss`: the
    truth is interpolated at the control instants like the prediction
    (:func:`~conformal_control.families.cbf.interp.interpolate_at_substeps`), the gap is the
    constraint on the prediction minus the constraint on the truth (with the ego's recorded
    position and decision), pairs without truth are left out. Writes the largest gap
    ``top[b]``, the largest gap plus the lambda applied (``lam[b]`` where brake / hold
    applied none) ``top_applied[b]`` and the number of pairs with a truth ``n_pairs[b]``.

    With lambda run per agent (``vec[b]``) agent a's row had the lambda applied plus
    ``lam_off[b, a]``, and agent a's largest gap goes to ``agent_top[offsets[i] + a]``
    (-inf without a pair).
    """
    for i in range(slots.shape[0]):
        b = slots[i]
        o = offsets[i]
        sub = substeps[b]
        dt = dt_frame[b]
        p = prm[b]
        best = -math.inf
        best_applied = -math.inf
        count = 0
        per = vec[b]
        if per:
            for a in range(n_agents[b]):
                agent_top[o + a] = -math.inf
        for k in range(step[b]):
            j = k // sub
            frac = (k % sub) / sub
            la = rec_lam[b, k]
            if not math.isfinite(la):
                la = lam[b]
            ex = rec_x[b, k, 0]
            ey = rec_x[b, k, 1]
            evx = rec_v[b, k, 0]
            evy = rec_v[b, k, 1]
            for a in range(n_agents[b]):
                px0 = truth[o + a, j, 0]
                py0 = truth[o + a, j, 1]
                dx = truth[o + a, j + 1, 0] - px0
                dy = truth[o + a, j + 1, 1] - py0
                tx = px0 + frac * dx
                ty = py0 + frac * dy
                tvx = dx / dt
                tvy = dy / dt
                if not (
                    math.isfinite(tx)
                    and math.isfinite(ty)
                    and math.isfinite(tvx)
                    and math.isfinite(tvy)
                ):
                    continue
                pred = _apf_value(
                    ex, ey, evx, evy, xp[b, k, a, 0], xp[b, k, a, 1], vp[b, k, a, 0],
                    vp[b, k, a, 1], p,
                )  # fmt: skip
                gap = pred - _apf_value(ex, ey, evx, evy, tx, ty, tvx, tvy, p)
                count += 1
                if gap > best:
                    best = gap
                if per:
                    if gap > agent_top[o + a]:
                        agent_top[o + a] = gap
                    v = gap + (la + lam_off[b, a])
                else:
                    v = gap + la
                if v > best_applied:
                    best_applied = v
        top[b] = best
        top_applied[b] = best_applied
        n_pairs[b] = count
