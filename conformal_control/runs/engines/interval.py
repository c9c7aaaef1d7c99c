"""Every control instant of an interval, for every live episode of a batch, in one call.

The lockstep engine (:mod:`conformal_control.runs.engines.batch`) calls :func:`run_interval` once
per interval: for each slot it runs the interval's control instants back to back --
the attractive field's reference velocity, the fused APF step of the exact 2-D filter
(:func:`~conformal_control.families.cbf.kernels2d.apf_step`; for the ``acp`` family with the
barrier's
collision distance raised per horizon step and no slack), the ``brake`` / ``hold``
fallbacks (any other fallback pauses the slot: the engine lets the episode's own fallback
object decide in Python and calls again), the velocity-tracking plant, the goal check
(with the scene's waypoints), the frame clock and the per-frame log with the nearest
agent's distance -- and stops the slot at its interval's end or at its episode's end. It is
the work of
:meth:`ConformalCBFController.decide
<conformal_control.families.cbf.controller.ConformalCBFController.decide>`,
:meth:`ReplayEnvironment.apply <conformal_control.world.replay.ReplayEnvironment.apply>`
and the dynamics' ``step``, with the same floating-point operations in the same order:
the distances the Python code takes with ``math.hypot`` (the reference's speed, the goal
check) are taken with :func:`~conformal_control.families.cbf.pyhypot.py_hypot`, those it takes with
``numpy.hypot`` (the frame log) with numba's ``math.hypot`` (the C library's, as numpy's).
"""

from __future__ import annotations

import math

import numpy as np

from ...core.jit import kernel
from ...families.cbf.kernels2d import (
    ESCAPED,
    INFEASIBLE,
    NONFINITE,
    OPTIMAL,
    SEARCH_VERTEX,
    UNCONSTRAINED,
    apf_step,
    escape_guard,
)
from ...families.cbf.pyhypot import py_hypot
from .gap_kernels import HOLD, PYTHON
from .kernels import d_min

__all__ = ["ACTIVE", "FALLBACK", "FREE", "run_interval"]

#: Status codes written to ``rec_code`` (those of the animation record): the reference
#: was safe, the filter changed it, the fallback decided.
FREE, ACTIVE, FALLBACK = 0, 1, 2

jit = kernel(cache=True, nogil=True)


@jit
def run_interval(
    slots: np.ndarray,
    x: np.ndarray,
    t: np.ndarray,
    step: np.ndarray,
    n_ctrl: np.ndarray,
    tau: np.ndarray,
    done: np.ndarray,
    # reference and goals
    goal: np.ndarray,
    goal_idx: np.ndarray,
    goals: np.ndarray,
    n_goals: np.ndarray,
    goal_radius: np.ndarray,
    t_goal: np.ndarray,
    neg_k_att: np.ndarray,
    v_ref_max: np.ndarray,
    # filter
    lam: np.ndarray,
    n_agents: np.ndarray,
    xp: np.ndarray,
    vp: np.ndarray,
    prm: np.ndarray,
    poly: np.ndarray,
    poly_len: np.ndarray,
    fallback: np.ndarray,
    work: np.ndarray,
    last: np.ndarray,
    counts: np.ndarray,
    # plant
    dt: np.ndarray,
    decay: np.ndarray,
    gain: np.ndarray,
    k_acc: np.ndarray,
    # the interval's record (the loss reads it) and the status codes
    rec_x: np.ndarray,
    rec_v: np.ndarray,
    rec_lam: np.ndarray,
    rec_code: np.ndarray,
    # frame clock and log
    store: np.ndarray,
    where: np.ndarray,
    substeps: np.ndarray,
    fi: np.ndarray,
    last_frame: np.ndarray,
    log: np.ndarray,
    n_log: np.ndarray,
    # per-instant record of the whole episode (kept if keep)
    keep: bool,
    st_t: np.ndarray,
    st_x: np.ndarray,
    st_cmd: np.ndarray,
    n_st: np.ndarray,
    # the acp family: per slot, whether lambda is the regions' level (no slack), and the
    # barrier's d_c and delta at each horizon step
    acp: np.ndarray,
    acp_dc: np.ndarray,
    acp_delta: np.ndarray,
    acp_h: np.ndarray,
    # a fallback decided in Python: the decision given for a paused slot, and the paused
    # step's (nominal x, nominal y, lambda) out
    forced: np.ndarray,
    forced_v: np.ndarray,
    paused: np.ndarray,
    # lambda run per agent: per slot, whether, and each agent's offset above lam[b]
    vec: np.ndarray,
    lam_off: np.ndarray,
) -> tuple[int, int]:
    """Run the control instants of the current interval of each slot ``b`` in ``slots``
    (at least one, then until ``step[b] >= n_ctrl[b]`` or ``done[b]``); returns -1, or the
    first slot whose rows, lambda or nominal velocity were not finite (that slot stops
    there, nothing applied). An interval that starts here (``step[b] == 0``) has
    ``n_ctrl[b]`` set to its control instants: ``tau[b]`` frames or those left before
    ``last_frame[b]``, times ``substeps[b]`` (the environment's ``control_instants``).

    Per slot (arrays indexed by slot): state ``x[b]`` = (x, y, vx, vy), time ``t[b]``,
    control instant ``step[b]`` of the interval. The reference is ``-K_att (X - goal)``
    (``neg_k_att[b] = -K_att``) saturated at speed ``v_ref_max[b]``; the goal is waypoint
    ``goal_idx[b]`` of ``goals[b, :n_goals[b]]`` (``goal[b]``, its coordinates), reached
    within ``goal_radius[b]`` (the last one: ``t_goal[b]``, ``done[b]``). The filter
    (layout of :func:`apf_step`): ``lam[b]``, the ``n_agents[b]`` sensed agents'
    predictions ``xp[b, step]`` / ``vp[b, step]``, ``prm[b]``, ``poly[b, :poly_len[b]]``,
    the fallback code ``fallback[b]`` and the previous decision ``last[b]``; ``counts[b]``
    gets (solves, infeasible, fallback, lambda-search vertex, control instants, edge rule
    deciding alone, brake / hold moved into its escape polygon). The
    plant: ``dt[b]``, ``decay[b] = exp(-K dt)``, ``gain[b] = -expm1(-K dt)``, ``k_acc[b]
    = K``. The interval's record: ``rec_x`` (ego position), ``rec_v`` (decision),
    ``rec_lam`` (lambda applied, NaN for brake / hold), ``rec_code`` (:data:`FREE`,
    :data:`ACTIVE`, :data:`FALLBACK`), at index ``step``. The frame clock: every
    ``substeps[b]`` instants the frame ``fi[b]`` advances; at ``last_frame[b]`` the
    episode ends, else the frame is logged to ``log[b, n_log[b]]`` = (t, x, y, vx, vy,
    d_min) with the slot's recording in ``store`` / ``where``. With ``keep``, each
    instant's (t, x, command) goes to ``st_t[b, n_st[b]]``, ``st_x``, ``st_cmd``.

    The ``acp`` family (``acp[b]``): the rows get no slack (lambda 0) and the barrier's
    ``d_c`` and ``delta`` (``prm[b, 2:4]``) at instant s are ``acp_dc[b, h]`` and
    ``acp_delta[b, h]``, h = min(s // substeps, acp_h[b] - 1).

    Returns ``(bad, paused)``: ``bad`` as above; ``paused`` is -1, or the position in
    ``slots`` of a slot whose step was infeasible with a fallback decided in Python
    (``fallback[b] == PYTHON``): its rows are in ``work`` (as :func:`apf_step` leaves them),
    ``paused`` holds (nominal x, nominal y, lambda given), nothing is applied and the
    slots after it are not run. The caller decides, sets ``forced[b]`` and ``forced_v[b]``
    = (v_x, v_y, lambda applied), and calls again from that slot: the step then applies
    the given decision.

    With lambda run per agent (``vec[b]``), agent a's row has the slack ``lam[b] +
    lam_off[b, a]`` (:func:`apf_step`'s offsets; ``lam[b]`` is the smallest entry).
    """
    for i in range(slots.shape[0]):
        b: int = slots[i]  # an annotation only: no bytecode, numba types it from slots
        n = n_agents[b]
        la = lam[b]
        p = prm[b]
        pl = poly[b, : poly_len[b]]
        h = dt[b]
        g = gain[b]
        k = k_acc[b]
        dec = decay[b]
        kneg = neg_k_att[b]
        vmax = v_ref_max[b]
        radius = goal_radius[b]
        sub = substeps[b]
        regions = acp[b]
        if regions:
            la = 0.0
        off = lam_off[b, :n] if vec[b] else lam_off[b, :0]
        if step[b] == 0:  # the interval's control instants, as ReplayEnvironment says
            n_ctrl[b] = max(min(tau[b], last_frame[b] - fi[b]), 0) * sub
        while True:
            s = step[b]
            x0 = x[b, 0]
            x1 = x[b, 1]
            # AttractiveField: -K_att (X - X_goal), saturated at v_max (Python's hypot)
            n0 = kneg * (x0 - goal[b, 0])
            n1 = kneg * (x1 - goal[b, 1])
            speed = py_hypot(n0, n1)
            if speed > vmax:
                f = vmax / speed
                n0 *= f
                n1 *= f
            if forced[b]:  # the decision of the fallback decided in Python
                forced[b] = False
                code = INFEASIBLE
                v0 = forced_v[b, 0]
                v1 = forced_v[b, 1]
                lam_used = forced_v[b, 2]
                solves = 0
            else:
                if regions and n > 0:
                    hh = min(s // sub, acp_h[b] - 1)
                    p[2] = acp_dc[b, hh]
                    p[3] = acp_delta[b, hh]
                code, v0, v1, lam_used, solves = apf_step(
                    x0, x1, xp[b, s, :n], vp[b, s, :n], n0, n1, la, p, pl, work, off
                )
                if code == NONFINITE:
                    return b, -1
                if code == INFEASIBLE and fallback[b] == PYTHON:
                    counts[b, 0] += solves
                    paused[0] = n0
                    paused[1] = n1
                    paused[2] = la
                    return -1, i
            counts[b, 0] += solves
            applied = la
            status = FALLBACK
            if code == UNCONSTRAINED:
                v0 = n0
                v1 = n1
                status = FREE
            elif code == OPTIMAL:
                status = ACTIVE
            elif code == INFEASIBLE:
                if fallback[b] == PYTHON:  # decided (and counted) by the episode's fallback
                    applied = lam_used
                else:  # brake / hold decide
                    counts[b, 1] += 1
                    counts[b, 2] += 1
                    applied = math.nan
                    if fallback[b] == HOLD:
                        v0 = last[b, 0]
                        v1 = last[b, 1]
                    else:
                        v0 = 0.0
                        v1 = 0.0
                    # within the edge rule's escape polygon, if the step had one
                    ns = pl.shape[0] // 5
                    moved, v0, v1 = escape_guard(
                        v0, v1, work[10 * int(p[11]) + 3 * ns :], int(p[11]), p[6]
                    )
                    if moved:
                        counts[b, 6] += 1
            elif code == ESCAPED:  # the edge rule decided alone
                counts[b, 1] += 1
                counts[b, 2] += 1
                counts[b, 5] += 1
                applied = math.nan
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
            rec_code[b, s] = status
            counts[b, 4] += 1
            # the velocity-tracking double integrator, integrated exactly over dt
            d0 = x[b, 2] - v0
            d1 = x[b, 3] - v1
            x0 = x0 + v0 * h + d0 * g / k
            x1 = x1 + v1 * h + d1 * g / k
            x[b, 0] = x0
            x[b, 1] = x1
            x[b, 2] = v0 + d0 * dec
            x[b, 3] = v1 + d1 * dec
            t[b] += h
            s += 1
            step[b] = s
            if keep:
                j = n_st[b]
                st_t[b, j] = t[b]
                for c in range(4):
                    st_x[b, j, c] = x[b, c]
                st_cmd[b, j, 0] = v0
                st_cmd[b, j, 1] = v1
                n_st[b] = j + 1
            # the goal check at every control instant (Python's hypot, as the environment)
            if py_hypot(x0 - goal[b, 0], x1 - goal[b, 1]) <= radius:
                q = goal_idx[b] + 1
                while (
                    q < n_goals[b] and py_hypot(x0 - goals[b, q, 0], x1 - goals[b, q, 1]) <= radius
                ):
                    q += 1
                if q >= n_goals[b]:
                    q = n_goals[b] - 1
                    t_goal[b] = t[b]
                    done[b] = True
                goal_idx[b] = q
                goal[b, 0] = goals[b, q, 0]
                goal[b, 1] = goals[b, q, 1]
            # the frame clock: a closed frame starts the next one, logged if the episode
            # goes on (it ends at frame last_frame)
            if s % sub == 0:
                fi[b] += 1
                if fi[b] >= last_frame[b]:
                    done[b] = True
                if not done[b]:
                    r = n_log[b]
                    log[b, r, 0] = t[b]
                    for c in range(4):
                        log[b, r, 1 + c] = x[b, c]
                    log[b, r, 5] = d_min(store, where, b, fi[b], x0, x1)
                    n_log[b] = r + 1
            if done[b] or s >= n_ctrl[b]:
                break
    return -1, -1
