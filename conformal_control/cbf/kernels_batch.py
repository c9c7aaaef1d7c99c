"""One control instant of many episodes at once, compiled (the lockstep engine's hot loop).

:func:`control_step` advances every active episode of a batch by one control instant:
the fused APF step of :func:`~conformal_control.cbf.kernels2d.apf_step` (barrier, rows,
feasibility check, exact projection, lambda search) on the episode's interpolated
predictions, the ``brake`` / ``hold`` fallbacks, the record the loss reads, and the exact
step of the velocity-tracking double integrator. The per-episode path does the same work
through :meth:`~conformal_control.cbf.controller.ConformalCBFController.decide`,
:meth:`~conformal_control.cbf.filters.exact2d.Exact2DSafetyFilter.step_apf` and
:meth:`~conformal_control.cbf.dynamics.VelocityTrackingDoubleIntegrator.step`, one Python
call chain per episode and instant; here one compiled call covers the batch. The solver is
not duplicated: :func:`apf_step` is called as is. What is written here is the glue those
classes hold in Python (fallback choice, counters, the plant's closed form), with the same
floating-point operations in the same order, so the decisions are bit-identical.

The reference velocity is computed by the caller: its speed saturation uses Python's
``math.hypot`` (correctly rounded, unlike the C library's ``hypot`` numba calls), and the
engine must reproduce it bit for bit.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .kernels2d import (
    INFEASIBLE,
    NONFINITE,
    OPTIMAL,
    SEARCH_VERTEX,
    UNCONSTRAINED,
    apf_step,
)

__all__ = ["BRAKE", "HOLD", "SEARCH", "control_step", "gap_maxima", "reference_velocities"]

#: Fallback codes of :func:`control_step` (``lambda_search`` runs inside ``apf_step``).
SEARCH, BRAKE, HOLD = 0, 1, 2

jit = numba.njit(cache=True, nogil=True)


@jit
def control_step(
    slots: np.ndarray,
    x: np.ndarray,
    ref: np.ndarray,
    speed: np.ndarray,
    v_ref_max: np.ndarray,
    goal: np.ndarray,
    lam: np.ndarray,
    step: np.ndarray,
    n_agents: np.ndarray,
    xp: np.ndarray,
    vp: np.ndarray,
    prm: np.ndarray,
    poly: np.ndarray,
    poly_len: np.ndarray,
    fallback: np.ndarray,
    work: np.ndarray,
    last: np.ndarray,
    dt: np.ndarray,
    decay: np.ndarray,
    gain: np.ndarray,
    k_acc: np.ndarray,
    t: np.ndarray,
    rec_x: np.ndarray,
    rec_v: np.ndarray,
    rec_lam: np.ndarray,
    counts: np.ndarray,
) -> int:
    """Advance the episodes ``slots`` by one control instant; returns -1, or the first slot
    whose rows, lambda or nominal velocity were not finite (nothing is applied for it).

    The ``i``-th slot ``b = slots[i]`` has the unsaturated reference velocity ``ref[:, i]``
    (:func:`reference_velocities`) of speed ``speed[i]``, saturated here at
    ``v_ref_max[b]``; on return ``ref[:, i]`` holds the robot's offset from its goal
    ``goal[b]`` (for the goal check). Per slot (arrays indexed by slot): state ``x[b]`` =
    (x, y, vx, vy), ``lam[b]``, control instant ``step[b]`` of the interval, the
    ``n_agents[b]`` sensed agents' predictions ``xp[b, step[b], :n]`` / ``vp[b, ...]``, the
    filter's parameter vector ``prm[b]`` and speed polygon ``poly[b, :poly_len[b]]`` (the
    layout of :func:`apf_step`), its fallback code (:data:`SEARCH`, :data:`BRAKE`,
    :data:`HOLD`) and previous decision ``last[b]``; the plant's step ``dt[b]``,
    ``decay[b] = exp(-K dt)``, ``gain[b] = -expm1(-K dt)`` and ``k_acc[b] = K``. Writes the
    record ``rec_x[b, step]`` (ego position), ``rec_v[b, step]`` (decision) and
    ``rec_lam[b, step]`` (lambda applied, NaN for brake / hold), advances ``x``, ``t`` and
    ``step`` and adds to ``counts[b]`` = (solves, infeasible, fallback, lambda-search
    vertex, control instants). ``work`` is :func:`apf_step`'s buffer for ``prm[b, 11]``
    agents (the same for every slot).
    """
    for i in range(slots.shape[0]):
        b: int = slots[i]  # an annotation only: no bytecode, numba types it from slots
        s = step[b]
        n = n_agents[b]
        x0 = x[b, 0]
        x1 = x[b, 1]
        n0 = ref[0, i]
        n1 = ref[1, i]
        if speed[i] > v_ref_max[b]:  # AttractiveField: v *= v_max / speed
            f = v_ref_max[b] / speed[i]
            n0 *= f
            n1 *= f
        code, v0, v1, lam_used, solves = apf_step(
            x0, x1, xp[b, s, :n], vp[b, s, :n], n0, n1, lam[b], prm[b],
            poly[b, : poly_len[b]], work,
        )  # fmt: skip
        if code == NONFINITE:
            return b
        counts[b, 0] += solves
        applied = lam[b]
        if code == UNCONSTRAINED:
            v0 = n0
            v1 = n1
        elif code == OPTIMAL:
            pass
        elif code == INFEASIBLE:  # brake / hold decide
            counts[b, 1] += 1
            counts[b, 2] += 1
            applied = math.nan
            if fallback[b] == HOLD:
                v0 = last[b, 0]
                v1 = last[b, 1]
            else:
                v0 = 0.0
                v1 = 0.0
        else:  # lambda search (the projection at lambda* + margin, or the LP's vertex)
            counts[b, 1] += 1
            counts[b, 2] += 1
            if code == SEARCH_VERTEX:
                counts[b, 3] += 1
            applied = lam_used
        last[b, 0] = v0
        last[b, 1] = v1
        rec_x[b, s, 0] = x0
        rec_x[b, s, 1] = x1
        rec_v[b, s, 0] = v0
        rec_v[b, s, 1] = v1
        rec_lam[b, s] = applied
        counts[b, 4] += 1
        # the velocity-tracking double integrator, integrated exactly over dt
        h = dt[b]
        d0 = x[b, 2] - v0
        d1 = x[b, 3] - v1
        g = gain[b]
        k = k_acc[b]
        x[b, 0] = x0 + v0 * h + d0 * g / k
        x[b, 1] = x1 + v1 * h + d1 * g / k
        x[b, 2] = v0 + d0 * decay[b]
        x[b, 3] = v1 + d1 * decay[b]
        t[b] += h
        step[b] = s + 1
        ref[0, i] = x[b, 0] - goal[b, 0]
        ref[1, i] = x[b, 1] - goal[b, 1]
    return -1


@jit
def reference_velocities(
    slots: np.ndarray, x: np.ndarray, goal: np.ndarray, neg_k_att: np.ndarray, out: np.ndarray
) -> None:
    """The attractive field ``-K_att (X - X_goal)`` of each slot, unsaturated, into
    ``out[:, i]`` (its speed is taken with Python's ``math.hypot`` by the caller)."""
    for i in range(slots.shape[0]):
        b = slots[i]
        k = neg_k_att[b]
        out[0, i] = k * (x[b, 0] - goal[b, 0])
        out[1, i] = k * (x[b, 1] - goal[b, 1])


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
    d = math.hypot(d0, d1)
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


@jit
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
) -> None:
    """The gap loss's maxima for the interval that ends now, per slot.

    The ``i``-th slot ``b`` has ``n_agents[b]`` sensed agents whose true positions at the
    interval's frames are rows ``truth[offsets[i] + a]`` (NaN where unobserved); it ran
    ``step[b]`` control instants. As :class:`~conformal_control.cbf.loss.CBFGapLoss`: the
    truth is interpolated at the control instants like the prediction
    (:func:`~conformal_control.cbf.interp.interpolate_at_substeps`), the gap is the
    constraint on the prediction minus the constraint on the truth (with the ego's recorded
    position and decision), pairs without truth are left out. Writes the largest gap
    ``top[b]``, the largest gap plus the lambda applied (``lam[b]`` where brake / hold
    applied none) ``top_applied[b]`` and the number of pairs with a truth ``n_pairs[b]``.
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
                if gap + la > best_applied:
                    best_applied = gap + la
        top[b] = best
        top_applied[b] = best_applied
        n_pairs[b] = count
