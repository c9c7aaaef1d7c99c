"""The sampling MPC's inner loop, compiled: cost and clearance of every sampled plan.

For N sampled plans of H steps and M predicted agents, the clearance of plan n is::

    c_n = min over steps h = 1..H and agents j of ( dist_njh - r_nh )

with ``r_nh`` the safe distance at step h and ``dist_njh`` either the distance between
the plan's position ``p_nh`` and agent j's predicted position ``y_jh`` at the end of the
step (``continuous=False``, the discrete check of the published sampling MPCs), or the
smallest distance between the two over the whole step, both moving linearly from their
positions at step h - 1 (``continuous=True``): a robot and a pedestrian crossing at
3 m/s cover 1.2 m in a 0.4 s step, more than a collision distance, so end points alone
can miss a collision between them. A plan is safe when ``c_n >= 0``. The minimum over
agents is taken on squared distances: one square root per (plan, step).

The cost of plan n (goal g, commands u, ``u_-1`` the command applied last)::

    w_goal sum_{h=1}^{H-1} |p_nh - g|^2 + w_terminal |p_nH - g|^2
        + w_effort sum_h |u_nh|^2 + w_comfort sum_h |u_nh - u_n(h-1)|^2

The violation of plan n is ``sum_h max(r_nh - dist_nh, 0)`` with ``dist_nh`` the step's
smallest distance over agents: how far, in total, the plan intrudes (the fallback
``least_violation`` minimises it).

**The exact cut.** Before the plans are evaluated, each plan step h drops the agents that
cannot be the nearest one of any candidate at that step (:func:`_kept_agents`): with ``U_h``
an upper bound, over every candidate, on the distance to the agent that is nearest in the
worst case (the farthest corner of the candidates' box at the step's end from that agent's
predicted position at the step's end), an agent whose lower bound ``L_jh`` (the distance
between the box the candidates' step can sweep and the box of the agent's step) exceeds
``U_h`` is farther than some other agent for EVERY candidate, so it is never the minimum
of the step: the minimum (a selection, not a sum) is the same number, bit for bit, and so
are the clearance and the violation built from it; the cost has no agent term. The bounds
are compared with a margin far above the rounding of the squared distances (see
:func:`_kept_agents`). With one safe distance per agent (``offsets``) nothing is cut.
``evaluate(..., cut=False)`` evaluates every agent at every step (the reference the
equality tests compare with).

Written as plain loops for numba; :func:`evaluate_numpy` is the same arithmetic in numpy
(the reference the tests compare with).
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

from ...core.jit import kernel
from ..cbf.pyhypot import c_hypot

__all__ = [
    "agent_rows",
    "choose_safe",
    "evaluate",
    "evaluate_many",
    "evaluate_numpy",
    "plan_choice",
    "plan_predictions",
    "positions_of",
    "predicted_at",
    "substep_states",
]

jit = kernel(cache=True, nogil=True)


#: The cut's margin, relative to ``1 + S^2`` (S the largest coordinate of the problem, m):
#: a squared distance of coordinates below S computed in float64 is within a few units in
#: the last place of ``S^2`` (~1e-15 S^2) of the exact value; 1e-9 is a million times that.
CUT_MARGIN = 1e-9


@jit
def _kept_agents(
    pos: np.ndarray,
    p0: np.ndarray,
    ex: np.ndarray,
    ey: np.ndarray,
    sx: np.ndarray,
    sy: np.ndarray,
    continuous: bool,
    n0: int,
    n1: int,
    a0: int,
    a1: int,
    cut: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The agents ``a0:a1`` that plan step h evaluates for the plans ``n0:n1``: their
    coordinates packed at the start of row h of ``(H, M)`` arrays (``ex``, ``ey``, ``sx``,
    ``sy`` order, the agents' own order kept) and their number per step. With ``cut`` False
    every agent at every step.

    Why a dropped agent never changes a number (the exact cut). For candidate n at step h
    the kernel's squared distance to agent j, ``es_nj`` (the step's end, or the smallest
    over the step with robot and agent moving linearly), is

    * at most the squared end distance ``|p_nh - e_jh|^2`` (the closest approach over the
      step is no farther than its end; ``start`` is ``min(end, start)``), and that is at
      most ``U_jh``, the squared distance from ``e_jh`` to the farthest corner of the box
      of every candidate's end position at step h;
    * at least ``L_jh``, the squared distance between the box the robot's step can sweep
      (the boxes of the candidates' positions at the step's start -- p0 for the first --
      and end) and the box of the agent's step (its start and end; its end alone for the
      end-point check): both move linearly inside those boxes.

    With ``U_h = min_k U_kh``: an agent with ``L_jh > U_h`` has, for every candidate,
    ``es_nj > U_h >= es_nk`` for the agent k attaining ``U_h``, so it is never the nearest
    agent of step h, and the minimum over the kept agents is the minimum over all of them
    (the same float: a minimum selects, it does not add). In float64 each computed squared
    distance is within a few ulps of ``S^2`` of the exact one (S the largest coordinate,
    every difference below 2S); the comparison is ``L_jh > U_h + 2 CUT_MARGIN (1 + S^2)``,
    so the inequalities hold for the computed numbers too. An agent with a non-finite bound
    is kept (a comparison with NaN is false)."""
    horizon = pos.shape[1]
    m = a1 - a0
    kx = np.empty((horizon, m))
    ky = np.empty((horizon, m))
    ksx = np.empty((horizon, m))
    ksy = np.empty((horizon, m))
    cnt = np.full(horizon, m, dtype=np.int64)
    if not cut or m < 2 or n1 <= n0:
        for h in range(horizon):
            for j in range(m):
                kx[h, j] = ex[h, a0 + j]
                ky[h, j] = ey[h, a0 + j]
                ksx[h, j] = sx[h, a0 + j]
                ksy[h, j] = sy[h, a0 + j]
        return kx, ky, ksx, ksy, cnt
    # the box of the candidates' end positions at every step
    lox = np.full(horizon, np.inf)
    hix = np.full(horizon, -np.inf)
    loy = np.full(horizon, np.inf)
    hiy = np.full(horizon, -np.inf)
    for n in range(n0, n1):
        for h in range(horizon):
            x = pos[n, h, 0]
            y = pos[n, h, 1]
            lox[h] = min(lox[h], x)
            hix[h] = max(hix[h], x)
            loy[h] = min(loy[h], y)
            hiy[h] = max(hiy[h], y)
    big = max(abs(p0[0]), abs(p0[1]))
    for h in range(horizon):
        big = max(big, abs(lox[h]), abs(hix[h]), abs(loy[h]), abs(hiy[h]))
        for j in range(a0, a1):
            big = max(big, abs(ex[h, j]), abs(ey[h, j]), abs(sx[h, j]), abs(sy[h, j]))
    tol = 2.0 * CUT_MARGIN * (1.0 + big * big)
    for h in range(horizon):
        # U_h: the farthest corner of the end box from each agent's end, the least of them
        top = np.inf
        for j in range(a0, a1):
            fx = max(hix[h] - ex[h, j], ex[h, j] - lox[h])
            fy = max(hiy[h] - ey[h, j], ey[h, j] - loy[h])
            u = fx * fx + fy * fy
            if u < top:
                top = u
        # the box the robot's step sweeps: this step's end box and the last one's (p0)
        rlx, rhx, rly, rhy = lox[h], hix[h], loy[h], hiy[h]
        if continuous:
            if h == 0:
                rlx, rhx = min(rlx, p0[0]), max(rhx, p0[0])
                rly, rhy = min(rly, p0[1]), max(rhy, p0[1])
            else:
                rlx, rhx = min(rlx, lox[h - 1]), max(rhx, hix[h - 1])
                rly, rhy = min(rly, loy[h - 1]), max(rhy, hiy[h - 1])
        k = 0
        for j in range(a0, a1):
            alx, ahx, aly, ahy = ex[h, j], ex[h, j], ey[h, j], ey[h, j]
            if continuous:
                alx, ahx = min(alx, sx[h, j]), max(ahx, sx[h, j])
                aly, ahy = min(aly, sy[h, j]), max(ahy, sy[h, j])
            gx = max(0.0, alx - rhx, rlx - ahx)
            gy = max(0.0, aly - rhy, rly - ahy)
            if gx * gx + gy * gy > top + tol:
                continue  # never the nearest agent of this step (see above)
            kx[h, k] = ex[h, j]
            ky[h, k] = ey[h, j]
            ksx[h, k] = sx[h, j]
            ksy[h, k] = sy[h, j]
            k += 1
        cnt[h] = k
    return kx, ky, ksx, ksy, cnt


@jit
def _evaluate_range(
    pos: np.ndarray,
    cmds: np.ndarray,
    p0: np.ndarray,
    ex: np.ndarray,
    ey: np.ndarray,
    sx: np.ndarray,
    sy: np.ndarray,
    radius: np.ndarray,
    goal: np.ndarray,
    weights: np.ndarray,
    last: np.ndarray,
    continuous: bool,
    n0: int,
    n1: int,
    a0: int,
    a1: int,
    cost: np.ndarray,
    clear: np.ndarray,
    viol: np.ndarray,
    aoff: np.ndarray,
    cut: bool,
) -> None:
    """Plans ``n0:n1`` of ``pos``/``cmds``/``radius`` against agents ``a0:a1`` (columns of
    ``ex``, ``ey``, ``sx``, ``sy``), written into ``cost``, ``clear``, ``viol`` at ``n0:n1``:
    the body of :func:`_evaluate` and of :func:`_evaluate_many` (one body, so one plan's
    numbers are the same whichever call evaluates it). ``aoff`` is empty, or holds one
    number per agent (columns ``a0:a1``) added to the safe distance of that agent only
    (lambda run per agent). ``cut``: each step evaluates only the agents that can be its
    nearest (:func:`_kept_agents`; the same numbers); never with ``aoff``."""
    # ex, ey (H, M): the agents' predicted positions at the end of each step; sx, sy: at
    # its start. Agent-major rows and separate coordinates, and the closest approach chosen
    # by selects rather than branches: the agent loop compiles to vector instructions
    # (several times faster than the branching loop on (M, H, 2) arrays; the same numbers)
    horizon = pos.shape[1]
    n_agents = a1 - a0
    per_agent = n_agents > 0 and aoff.shape[0] > 0
    kx, ky, ksx, ksy, cnt = _kept_agents(
        pos, p0, ex, ey, sx, sy, continuous, n0, n1, a0, a1, cut and not per_agent
    )
    w_goal, w_term, w_eff, w_comf = weights[0], weights[1], weights[2], weights[3]
    es = np.empty(n_agents)
    for n in range(n0, n1):
        c = 0.0
        best = np.inf
        v = 0.0
        ax = p0[0]
        ay = p0[1]
        ux = last[0]
        uy = last[1]
        for h in range(horizon):
            px = pos[n, h, 0]
            py = pos[n, h, 1]
            gx = px - goal[0]
            gy = py - goal[1]
            c += (w_term if h == horizon - 1 else w_goal) * (gx * gx + gy * gy)
            vx = cmds[n, h, 0]
            vy = cmds[n, h, 1]
            c += w_eff * (vx * vx + vy * vy)
            c += w_comf * ((vx - ux) * (vx - ux) + (vy - uy) * (vy - uy))
            ux = vx
            uy = vy
            m = cnt[h]
            if continuous:
                for j in range(m):
                    bx = px - kx[h, j]
                    by = py - ky[h, j]
                    e = bx * bx + by * by  # at the step's end
                    rx = ax - ksx[h, j]
                    ry = ay - ksy[h, j]
                    dx = bx - rx
                    dy = by - ry
                    dd = dx * dx + dy * dy
                    # the closest approach at s in (0, 1); before the step (s <= 0) its
                    # start; after it (s >= 1) or with no relative motion its end
                    s = -(rx * dx + ry * dy) / (dd if dd > 0.0 else 1.0)
                    qx = rx + s * dx
                    qy = ry + s * dy
                    within = qx * qx + qy * qy
                    start = min(e, rx * rx + ry * ry)
                    moving = dd > 0.0
                    es[j] = (
                        within
                        if moving & (0.0 < s) & (s < 1.0)
                        else (start if moving & (s <= 0.0) else e)
                    )
            else:
                for j in range(m):
                    bx = px - kx[h, j]
                    by = py - ky[h, j]
                    es[j] = bx * bx + by * by
            d2 = np.inf
            for j in range(m):
                if es[j] < d2:
                    d2 = es[j]
            if per_agent:  # each agent its own safe distance (nothing cut: m == n_agents)
                cl = np.inf
                for j in range(m):
                    cj = math.sqrt(es[j]) - (radius[n, h] + aoff[a0 + j])
                    if cj < cl:
                        cl = cj
                if cl < best:
                    best = cl
                if cl < 0.0:
                    v -= cl
            elif n_agents:
                cl = math.sqrt(d2) - radius[n, h]
                if cl < best:
                    best = cl
                if cl < 0.0:
                    v -= cl
            ax = px
            ay = py
        cost[n] = c
        clear[n] = best
        viol[n] = v


@jit
def _evaluate(
    pos: np.ndarray,
    cmds: np.ndarray,
    p0: np.ndarray,
    ex: np.ndarray,
    ey: np.ndarray,
    sx: np.ndarray,
    sy: np.ndarray,
    radius: np.ndarray,
    goal: np.ndarray,
    weights: np.ndarray,
    last: np.ndarray,
    continuous: bool,
    aoff: np.ndarray,
    cut: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n_plans = pos.shape[0]
    cost = np.zeros(n_plans)
    clear = np.full(n_plans, np.inf)
    viol = np.zeros(n_plans)
    _evaluate_range(
        pos, cmds, p0, ex, ey, sx, sy, radius, goal, weights, last, continuous,
        0, n_plans, 0, ex.shape[1], cost, clear, viol, aoff, cut,
    )  # fmt: skip
    return cost, clear, viol


@jit
def _evaluate_steps(
    pos: np.ndarray,
    cmds: np.ndarray,
    p0: np.ndarray,
    ex: np.ndarray,
    ey: np.ndarray,
    sx: np.ndarray,
    sy: np.ndarray,
    radius: np.ndarray,
    goal: np.ndarray,
    weights: np.ndarray,
    last: np.ndarray,
    continuous: bool,
    cut: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_evaluate_range` of every plan against every agent (no ``aoff``), step by step
    instead of plan by plan: the cost is summed plan by plan (a plan's steps read in memory
    order), which also copies every step's positions and safe distances into contiguous
    rows; then the agents' loop runs step by step with the innermost loop over the PLANS
    (hundreds) rather than over the agents (a handful after the cut), so it compiles to
    vector instructions. Every
    number is the same arithmetic in the same order per plan (each plan's cost and
    violation are summed over the steps in step order, the minima over agents and steps
    select with the same comparisons in the same order), so the results are
    :func:`_evaluate_range`'s bit for bit (``tests/families/mpc/test_cut.py`` compares them)."""
    n_plans = pos.shape[0]
    horizon = pos.shape[1]
    n_agents = ex.shape[1]
    kx, ky, ksx, ksy, cnt = _kept_agents(
        pos, p0, ex, ey, sx, sy, continuous, 0, n_plans, 0, n_agents, cut
    )
    w_goal, w_term, w_eff, w_comf = weights[0], weights[1], weights[2], weights[3]
    g0 = goal[0]
    g1 = goal[1]
    cost = np.empty(n_plans)
    best = np.full(n_plans, np.inf)
    viol = np.zeros(n_plans)
    # row h + 1: every plan's position at the end of step h (row 0: p0, where step 1
    # starts); row h of rr: every plan's safe distance at step h
    px = np.empty((horizon + 1, n_plans))
    py = np.empty((horizon + 1, n_plans))
    rr = np.empty((horizon, n_plans))
    # the cost plan by plan (its sums in step order; the plan's rows read in memory order)
    for n in range(n_plans):
        c = 0.0
        ux = last[0]
        uy = last[1]
        px[0, n] = p0[0]
        py[0, n] = p0[1]
        for h in range(horizon):
            wh = w_term if h == horizon - 1 else w_goal
            x = pos[n, h, 0]
            y = pos[n, h, 1]
            px[h + 1, n] = x
            py[h + 1, n] = y
            rr[h, n] = radius[n, h]
            gx = x - g0
            gy = y - g1
            c += wh * (gx * gx + gy * gy)
            vx = cmds[n, h, 0]
            vy = cmds[n, h, 1]
            c += w_eff * (vx * vx + vy * vy)
            c += w_comf * ((vx - ux) * (vx - ux) + (vy - uy) * (vy - uy))
            ux = vx
            uy = vy
        cost[n] = c
    if n_agents == 0:
        return cost, best, viol
    d2 = np.empty(n_plans)
    for h in range(horizon):
        bxr = px[h + 1]
        byr = py[h + 1]
        axr = px[h]
        ayr = py[h]
        rh = rr[h]
        for n in range(n_plans):
            d2[n] = np.inf
        for j in range(cnt[h]):
            ejx = kx[h, j]
            ejy = ky[h, j]
            sjx = ksx[h, j]
            sjy = ksy[h, j]
            if continuous:
                for n in range(n_plans):
                    bx = bxr[n] - ejx
                    by = byr[n] - ejy
                    e = bx * bx + by * by  # at the step's end
                    rx = axr[n] - sjx
                    ry = ayr[n] - sjy
                    dx = bx - rx
                    dy = by - ry
                    dd = dx * dx + dy * dy
                    s = -(rx * dx + ry * dy) / (dd if dd > 0.0 else 1.0)
                    qx = rx + s * dx
                    qy = ry + s * dy
                    within = qx * qx + qy * qy
                    start = min(e, rx * rx + ry * ry)
                    moving = dd > 0.0
                    es = (
                        within
                        if moving & (0.0 < s) & (s < 1.0)
                        else (start if moving & (s <= 0.0) else e)
                    )
                    d2[n] = es if es < d2[n] else d2[n]
            else:
                for n in range(n_plans):
                    bx = bxr[n] - ejx
                    by = byr[n] - ejy
                    es = bx * bx + by * by
                    d2[n] = es if es < d2[n] else d2[n]
        for n in range(n_plans):
            cl = math.sqrt(d2[n]) - rh[n]
            best[n] = cl if cl < best[n] else best[n]
            viol[n] = viol[n] - cl if cl < 0.0 else viol[n]
    return cost, best, viol


@jit
def predicted_at(samples: np.ndarray, dt: float, offsets: np.ndarray) -> np.ndarray:
    """Positions (M, K, 2) of the agents at ``offsets`` (K,) seconds after their first
    sample, from ``samples`` (M, F + 1, 2) ``dt`` seconds apart: linear between samples, a
    sample's own value within 1e-9 of its time, the last sample held beyond them
    (:meth:`SamplingMPC.predicted_at
    <conformal_control.families.mpc.controller.SamplingMPC.predicted_at>`; the numpy form it
    replaced clipped, rounded and interpolated with the same operations, element by
    element).

    Parameters
    ----------
    samples : ndarray of shape (M, F + 1, 2)
        The agents' predicted positions at the sampling time and the F samples after it (m;
        finite).
    dt : float
        Seconds between samples.
    offsets : ndarray of shape (K,)
        Seconds after the sampling time.
    """
    m = samples.shape[0]
    last = samples.shape[1] - 1
    k = offsets.shape[0]
    top = max(last - 1, 0)
    out = np.empty((m, k, 2))
    for i in range(k):
        f = offsets[i] / dt
        if f < 0.0:
            f = 0.0
        if f > last:
            f = float(last)
        r = np.rint(f)
        if abs(f - r) < 1e-9:  # a sample time is that sample, exactly
            f = r
        i0 = min(math.floor(f), top)
        i1 = min(i0 + 1, last)
        w = f - i0
        for j in range(m):
            for c in range(2):
                a = samples[j, i0, c]
                out[j, i, c] = a + w * (samples[j, i1, c] - a)
    return out


@jit
def plan_predictions(
    samples: np.ndarray, dt: float, t_off: float, dt_plan: float, horizon: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What a plan reads of the predictions, in one call: the agents' positions at the
    plan's steps ``t_off + dt_plan * (1..H)`` (``pred``, (M, H, 2)) and now (``y0``, (M,
    2)) as :func:`predicted_at` gives them, and the evaluation's rows of them
    (:func:`agent_rows`: ``ex``, ``ey``, ``sx``, ``sy``, each (H, M)).

    Parameters
    ----------
    samples : ndarray of shape (M, F + 1, 2)
        As for :func:`predicted_at`.
    dt : float
        Seconds between samples.
    t_off : float
        The plan's start, seconds after the sampling time.
    dt_plan : float
        Seconds per plan step.
    horizon : int
        Plan steps H.
    """
    offsets = np.empty(horizon + 1)
    for i in range(horizon + 1):
        offsets[i] = t_off + dt_plan * float(i)
    both = predicted_at(samples, dt, offsets)
    m = samples.shape[0]
    pred = np.empty((m, horizon, 2))
    y0 = np.empty((m, 2))
    ex = np.empty((horizon, m))
    ey = np.empty((horizon, m))
    sx = np.empty((horizon, m))
    sy = np.empty((horizon, m))
    for j in range(m):
        y0[j, 0] = both[j, 0, 0]
        y0[j, 1] = both[j, 0, 1]
        for h in range(horizon):
            pred[j, h, 0] = both[j, h + 1, 0]
            pred[j, h, 1] = both[j, h + 1, 1]
            ex[h, j] = both[j, h + 1, 0]
            ey[h, j] = both[j, h + 1, 1]
            sx[h, j] = both[j, h, 0]
            sy[h, j] = both[j, h, 1]
    return pred, y0, ex, ey, sx, sy


@jit
def choose_safe(
    cost: np.ndarray,
    clear: np.ndarray,
    pos: np.ndarray,
    x: np.ndarray,
    pred: np.ndarray,
    y0: np.ndarray,
    d_c: float,
    dt_plan: float,
    edge: bool,
    allowed: np.ndarray,
) -> tuple[int, int, bool]:
    """The sampling MPC's choice among evaluated candidates in one compiled call (no peers'
    lines): the edge rule's check and the cheapest safe plan, the same numbers as the numpy
    form it replaces (``SamplingMPC.edge_closing`` and ``SamplingMPC.plan_end``).

    With ``edge`` and an agent within ``d_c`` now (``|x - y0_j| < d_c``, C library's hypot
    as ``numpy.hypot``), candidate n's closing rate is ``max_j (|x - y0_j| - |p_n1 -
    y_j1|) / dt_plan`` over those agents (NaN if any term is NaN, as ``numpy.max``); the
    plans closing at most 1e-9 m/s are allowed, or, when none is, those within 1e-9 of the
    smallest rate (none when a rate is NaN, as ``numpy.min``). A candidate is safe when
    ``clear >= 0`` and it is allowed; the choice is the first cheapest safe one, a NaN cost
    first (as ``numpy.argmin``).

    Parameters
    ----------
    cost, clear : ndarray of shape (N,)
        The candidates' cost and clearance (:func:`evaluate`).
    pos : ndarray of shape (N, H, 2)
        The candidates' positions (m).
    x : ndarray of shape (>= 2,)
        The robot's position now (m), first two entries.
    pred, y0 : ndarrays of shape (M, H, 2), (M, 2)
        The agents' predicted positions at the plan steps and now (m).
    d_c : float
        The collision distance (m).
    dt_plan : float
        The plan step (s).
    edge : bool
        Whether the edge rule applies (``edge="escape"``).
    allowed : ndarray of bool, shape (N,)
        Written with the edge rule's allowed plans when it applies.

    Returns
    -------
    i : int
        The chosen candidate, -1 when none is safe.
    n_safe : int
        The number of safe candidates.
    applied : bool
        Whether the edge rule applied (an agent within ``d_c``).
    """
    n = cost.shape[0]
    m = y0.shape[0]
    applied = False
    if edge and m > 0:
        near = np.empty(m, dtype=np.int64)
        d0 = np.empty(m)
        k = 0
        for j in range(m):
            d = c_hypot(x[0] - y0[j, 0], x[1] - y0[j, 1])
            if d < d_c:
                near[k] = j
                d0[k] = d
                k += 1
        if k > 0:
            applied = True
            closing = np.empty(n)
            some = False
            low = np.inf
            low_nan = False
            for i in range(n):
                top = -np.inf
                top_nan = False
                for q in range(k):
                    j = near[q]
                    d1 = c_hypot(pos[i, 0, 0] - pred[j, 0, 0], pos[i, 0, 1] - pred[j, 0, 1])
                    v = (d0[q] - d1) / dt_plan
                    if v != v:
                        top_nan = True
                    elif v > top:
                        top = v
                c = np.nan if top_nan else top
                closing[i] = c
                ok = c <= 1e-9
                allowed[i] = ok
                some = some or ok
                if c != c:
                    low_nan = True
                elif c < low:
                    low = c
            if not some:
                bound = np.nan if low_nan else low + 1e-9
                for i in range(n):
                    allowed[i] = closing[i] <= bound
    n_safe = 0
    best = -1
    best_cost = np.inf
    for i in range(n):
        if clear[i] >= 0.0 and (not applied or allowed[i]):
            n_safe += 1
            v = cost[i]
        else:
            v = np.inf
        if best >= 0 and best_cost != best_cost:
            continue  # numpy.argmin: the first NaN
        if best < 0 or v < best_cost or v != v:
            best, best_cost = i, v
    return (best if n_safe > 0 else -1), n_safe, applied


@jit
def substep_states(
    samples: np.ndarray, dt: float, substeps: int, n_steps: int
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~conformal_control.families.cbf.interp.interpolate_at_substeps` compiled (the
    same operations: ``frac = (s % substeps) / substeps``, ``p0 + frac * (p1 - p0)`` and
    ``(p1 - p0) / dt``), without numpy's gathers and transposes; the caller checks that
    ``n_steps <= (F) * substeps``.

    Parameters
    ----------
    samples : ndarray of shape (N, F + 1, 2)
        Positions at times ``0, dt, ..., F dt`` (NaN where unknown).
    dt : float
        Sample spacing (s).
    substeps : int
        Control instants per sample interval.
    n_steps : int
        Control instants wanted.

    Returns
    -------
    pos, vel : ndarrays of shape (n_steps, N, 2)
    """
    n = samples.shape[0]
    pos = np.empty((n_steps, n, 2))
    vel = np.empty((n_steps, n, 2))
    for s in range(n_steps):
        i = s // substeps
        frac = (s % substeps) / substeps
        for a in range(n):
            for c in range(2):
                p0 = samples[a, i, c]
                d = samples[a, i + 1, c] - p0
                pos[s, a, c] = p0 + frac * d
                vel[s, a, c] = d / dt
    return pos, vel


def _positions_numpy(states: np.ndarray) -> np.ndarray:
    out: np.ndarray = np.ascontiguousarray(states[..., :2])
    return out


@kernel(cache=True, nogil=True, python=_positions_numpy)
def positions_of(states: np.ndarray) -> np.ndarray:
    """The positions ``states[..., :2]`` of rolled-out states (N, H, D) as a C-contiguous
    (N, H, 2) copy (numpy's strided copy of two numbers at a time is several times slower).

    Parameters
    ----------
    states : ndarray of shape (N, H, D)
        Plant states, position first.
    """
    n, h = states.shape[0], states.shape[1]
    out = np.empty((n, h, 2))
    for i in range(n):
        for j in range(h):
            out[i, j, 0] = states[i, j, 0]
            out[i, j, 1] = states[i, j, 1]
    return out


@jit
def plan_choice(
    states: np.ndarray,
    cmds: np.ndarray,
    x: np.ndarray,
    samples: np.ndarray,
    dt: float,
    t_off: float,
    dt_plan: float,
    radius: float,
    goal: np.ndarray,
    weights: np.ndarray,
    last: np.ndarray,
    continuous: bool,
    d_c: float,
    edge: bool,
) -> tuple[int, int, bool, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One plan's compiled work after the rollout, in one call (``SamplingMPC.plan`` with
    one safe distance shared by every plan and agent, no peers' lines): the candidates'
    positions (:func:`positions_of`), the predictions at the plan's steps
    (:func:`plan_predictions`), the evaluation (:func:`evaluate`'s step-by-step kernel, the
    exact cut on) and the choice (:func:`choose_safe`), each kernel called on the arguments
    the Python steps between them formed (the shared radius repeated per plan): the same
    numbers.

    Parameters
    ----------
    states : ndarray of shape (N, H, D)
        The rolled-out plant states, position first.
    cmds : ndarray of shape (N, H, 2)
        The candidates' commands.
    x : ndarray of shape (>= 2,)
        The robot's state now (its position first).
    samples : ndarray of shape (M, F + 1, 2)
        The interval's forecast samples (M = 0: no agent).
    dt : float
        Seconds between samples.
    t_off : float
        The plan's start, seconds after the sampling time.
    dt_plan : float
        Seconds per plan step.
    radius : float
        The safe distance of every plan step (m).
    goal : ndarray of shape (2,)
    weights : ndarray of shape (4,)
        ``(w_goal, w_terminal, w_effort, w_comfort)``.
    last : ndarray of shape (2,)
        The command applied last.
    continuous : bool
        Check the whole of every step.
    d_c : float
        The collision distance (m; the edge rule's).
    edge : bool
        Whether the edge rule applies.

    Returns
    -------
    i, n_safe, applied
        :func:`choose_safe`'s.
    pos, cost, clear, viol, allowed
        The candidates' positions (N, H, 2), their evaluation and the edge rule's allowed
        plans (written when it applied).
    """
    pos = positions_of(states)
    horizon = pos.shape[1]
    pred, y0, ex, ey, sx, sy = plan_predictions(samples, dt, t_off, dt_plan, horizon)
    r = np.full((pos.shape[0], horizon), radius)
    cost, clear, viol = _evaluate_steps(
        pos, cmds, x, ex, ey, sx, sy, r, goal, weights, last, continuous, True
    )
    allowed = np.empty(pos.shape[0], dtype=np.bool_)
    i, n_safe, applied = choose_safe(cost, clear, pos, x, pred, y0, d_c, dt_plan, edge, allowed)
    return i, n_safe, applied, pos, cost, clear, viol, allowed


@jit
def _evaluate_many(
    pos: np.ndarray,
    cmds: np.ndarray,
    p0: np.ndarray,
    ex: np.ndarray,
    ey: np.ndarray,
    sx: np.ndarray,
    sy: np.ndarray,
    radius: np.ndarray,
    goal: np.ndarray,
    weights: np.ndarray,
    last: np.ndarray,
    continuous: np.ndarray,
    plans: np.ndarray,
    agents: np.ndarray,
    aoff: np.ndarray,
    cut: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Problem ``i`` is plans ``plans[i]:plans[i + 1]`` against agents ``agents[i]:agents[i
    + 1]``, with its own ``p0[i]``, ``goal[i]``, ``weights[i]``, ``last[i]``,
    ``continuous[i]``; ``aoff`` is empty or one number per agent of every problem."""
    n_plans = pos.shape[0]
    cost = np.zeros(n_plans)
    clear = np.full(n_plans, np.inf)
    viol = np.zeros(n_plans)
    for i in range(plans.shape[0] - 1):
        _evaluate_range(
            pos, cmds, p0[i], ex, ey, sx, sy, radius, goal[i], weights[i], last[i],
            continuous[i], plans[i], plans[i + 1], agents[i], agents[i + 1], cost, clear, viol,
            aoff, cut,
        )  # fmt: skip
    return cost, clear, viol


def evaluate(
    pos: np.ndarray,
    cmds: np.ndarray,
    p0: np.ndarray,
    pred: np.ndarray,
    y0: np.ndarray,
    radius: np.ndarray,
    goal: np.ndarray,
    weights: tuple[float, float, float, float],
    last: np.ndarray,
    continuous: bool = True,
    offsets: np.ndarray | None = None,
    *,
    cut: bool = True,
    by_plan: bool = False,
    rows: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cost, clearance (m) and violation (m) of every plan.

    Parameters
    ----------
    pos : ndarray of shape (N, H, 2)
        Planned positions at the end of steps 1..H (m).
    cmds : ndarray of shape (N, H, 2)
        The commands of each step.
    p0 : ndarray of shape (2,)
        The robot's position now (the start of step 1).
    pred : ndarray of shape (M, H, 2)
        Predicted agent positions at the end of steps 1..H (m; finite).
    y0 : ndarray of shape (M, 2)
        Their predicted positions now.
    radius : ndarray of shape (N, H) or (H,)
        Safe centre distance at each step (m), per plan or shared by all plans.
    goal : ndarray of shape (2,)
    weights : (w_goal, w_terminal, w_effort, w_comfort)
    last : ndarray of shape (2,)
        The command applied last (for the comfort term).
    continuous : bool
        Check the whole of every step (True) or its end points only.
    offsets : ndarray of shape (M,), optional
        Added to the safe distance of each agent (m; lambda run per agent: agent j's
        safe distance is ``radius + offsets[j]``); None: ``radius`` for every agent.
    cut : bool
        Evaluate at each step only the agents that can be the nearest one of some
        candidate (the module's exact cut: the same numbers, bit for bit); False evaluates
        every agent at every step (the reference).
    by_plan : bool
        Evaluate plan by plan (the loop :func:`evaluate_many` and lambda per agent use)
        instead of step by step over all plans at once (faster; the same numbers, bit for
        bit). With ``offsets`` always plan by plan.
    rows : (ex, ey, sx, sy), optional
        :func:`agent_rows` of ``pred`` and ``y0`` when the caller has them already
        (:func:`plan_predictions`); else computed here.

    Returns
    -------
    cost, clearance, violation : ndarrays of shape (N,)
        The clearance is ``inf`` when there is no agent; the violation is the sum over
        steps of how far the step's smallest distance falls short of its safe distance
        (0 for a safe plan).
    """
    r = np.asarray(radius, dtype=np.float64)
    if r.ndim == 1 and r.shape[0] == np.shape(pos)[1]:  # one row per plan (repeat: a fast copy)
        r = np.repeat(r.reshape(1, -1), np.shape(pos)[0], axis=0)
    elif r.ndim == 1:
        r = np.broadcast_to(r, pos.shape[:2])  # (raises: the shapes differ)
    c = np.ascontiguousarray
    ex, ey, sx, sy = agent_rows(pred, y0) if rows is None else rows
    # the arguments both kernels take first (the per-plan one adds the agents' offsets)
    args = (
        c(pos, dtype=np.float64),
        c(cmds, dtype=np.float64),
        c(p0, dtype=np.float64),
        ex,
        ey,
        sx,
        sy,
        c(r),
        c(goal, dtype=np.float64),
        np.asarray(weights, dtype=np.float64),
        c(last, dtype=np.float64),
        bool(continuous),
    )
    if offsets is None and not by_plan:
        return _evaluate_steps(*args, bool(cut))
    cost, clear, viol = _evaluate(*args, _offsets(offsets), bool(cut))
    return cost, clear, viol


def _offsets(offsets: Any) -> np.ndarray:
    """The kernels' ``aoff``: the agents' safe-distance offsets as float64, or empty."""
    if offsets is None:
        return np.zeros(0)
    return np.ascontiguousarray(offsets, dtype=np.float64).ravel()


def evaluate_many(
    problems: list[tuple[Any, ...]], *, cut: bool = True
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """:func:`evaluate` of several problems in ONE compiled call (the lockstep episodes of a
    batch: every episode's samples at once), each problem's numbers the same as
    :func:`evaluate`'s on it alone (the same compiled body, plan by plan).

    Parameters
    ----------
    problems : list of tuples
        Each ``(pos, cmds, p0, pred, y0, radius, goal, weights, last, continuous[,
        offsets])``, the arguments of :func:`evaluate`; every ``pos`` with the same
        horizon H.
    cut : bool
        As for :func:`evaluate` (problem by problem).

    Returns
    -------
    list of (cost, clearance, violation)
        One per problem, as :func:`evaluate` returns them.
    """
    if not problems:
        return []
    horizon = {int(np.shape(p[0])[1]) for p in problems}
    if len(horizon) != 1:
        raise ValueError(f"evaluate_many needs one horizon, got {sorted(horizon)}")
    f64 = np.float64
    pos = np.concatenate([np.asarray(p[0], dtype=f64) for p in problems])
    cmds = np.concatenate([np.asarray(p[1], dtype=f64) for p in problems])
    rows = [agent_rows(p[3], p[4]) for p in problems]
    ex, ey, sx, sy = (np.ascontiguousarray(np.concatenate([r[k] for r in rows], axis=1))
                      for k in range(4))  # fmt: skip
    radius = np.concatenate(
        [np.broadcast_to(np.asarray(p[5], dtype=f64), np.shape(p[0])[:2]) for p in problems]
    )
    sizes = np.array([np.shape(p[0])[0] for p in problems], dtype=np.int64)
    plans = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    agents = np.concatenate([[0], np.cumsum([r[0].shape[1] for r in rows])]).astype(np.int64)
    offs = [_offsets(p[10] if len(p) > 10 else None) for p in problems]
    if any(o.size for o in offs):  # per agent for every problem (0 where it has none)
        offs = [o if o.size else np.zeros(r[0].shape[1]) for o, r in zip(offs, rows, strict=True)]
    aoff = np.concatenate(offs) if offs else np.zeros(0)
    cost, clear, viol = _evaluate_many(
        np.ascontiguousarray(pos),
        np.ascontiguousarray(cmds),
        np.array([np.asarray(p[2], dtype=f64) for p in problems]).reshape(-1, 2),
        ex,
        ey,
        sx,
        sy,
        np.ascontiguousarray(radius),
        np.array([np.asarray(p[6], dtype=f64) for p in problems]).reshape(-1, 2),
        np.array([np.asarray(p[7], dtype=f64) for p in problems]).reshape(-1, 4),
        np.array([np.asarray(p[8], dtype=f64) for p in problems]).reshape(-1, 2),
        np.array([bool(p[9]) if len(p) > 9 else True for p in problems]),
        plans,
        agents,
        aoff,
        bool(cut),
    )
    return [(cost[a:b], clear[a:b], viol[a:b]) for a, b in itertools.pairwise(plans)]


def agent_rows(
    pred: np.ndarray, y0: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The kernel's layout of the predictions: x and y of every agent at the end of each
    step, and at its start (``y0`` for the first step), each of shape (H, M)."""
    end = np.asarray(pred, dtype=np.float64).transpose(1, 0, 2)  # (H, M, 2)
    first = np.asarray(y0, dtype=np.float64).reshape(1, -1, 2)
    start = np.concatenate([first, end[:-1]], axis=0) if end.shape[0] else end
    c = np.ascontiguousarray
    return c(end[..., 0]), c(end[..., 1]), c(start[..., 0]), c(start[..., 1])


def evaluate_numpy(
    pos: np.ndarray,
    cmds: np.ndarray,
    p0: np.ndarray,
    pred: np.ndarray,
    y0: np.ndarray,
    radius: np.ndarray,
    goal: np.ndarray,
    weights: tuple[float, float, float, float],
    last: np.ndarray,
    continuous: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`evaluate` in numpy (reference; allocates (N, H, M) arrays).

    Parameters
    ----------
    pos : ndarray of shape (N, H, 2)
        Planned positions at the end of steps 1..H (m).
    cmds : ndarray of shape (N, H, 2)
        The commands of each step.
    p0 : ndarray of shape (2,)
        The robot's position now (the start of step 1).
    pred : ndarray of shape (M, H, 2)
        Predicted agent positions at the end of steps 1..H (m; finite).
    y0 : ndarray of shape (M, 2)
        Their predicted positions now.
    radius : ndarray of shape (N, H) or (H,)
        Safe centre distance at each step (m), per plan or shared by all plans.
    goal : ndarray of shape (2,)
        The goal (m).
    weights : (w_goal, w_terminal, w_effort, w_comfort)
        The cost weights.
    last : ndarray of shape (2,)
        The command applied last (for the comfort term).
    continuous : bool
        Check the whole of every step (True) or its end points only.

    Returns
    -------
    cost, clearance, violation : ndarrays of shape (N,)
        As :func:`evaluate`'s.
    """
    w_goal, w_term, w_eff, w_comf = weights
    d2g = ((pos - goal) ** 2).sum(-1)
    cost = w_goal * d2g[:, :-1].sum(1) + w_term * d2g[:, -1]
    prev = np.concatenate([np.broadcast_to(last, cmds[:, :1].shape), cmds[:, :-1]], 1)
    cost = cost + w_eff * (cmds**2).sum((1, 2)) + w_comf * ((cmds - prev) ** 2).sum((1, 2))
    n = pos.shape[0]
    if pred.shape[0] == 0:
        return cost, np.full(n, np.inf), np.zeros(n)
    b = pos[:, :, None, :] - pred.transpose(1, 0, 2)[None]  # (N, H, M, 2): ends
    d2 = (b**2).sum(-1)
    if continuous:
        start_p = np.concatenate([np.broadcast_to(p0, (n, 1, 2)), pos[:, :-1]], 1)
        start_y = np.concatenate([y0[:, None], pred[:, :-1]], 1)  # (M, H, 2)
        a = start_p[:, :, None, :] - start_y.transpose(1, 0, 2)[None]
        d = b - a
        dd = (d**2).sum(-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.clip(-(a * d).sum(-1) / dd, 0.0, 1.0)
        s = np.where(dd > 0, s, 1.0)
        q = a + s[..., None] * d
        d2 = (q**2).sum(-1)
    r = np.broadcast_to(np.asarray(radius, dtype=float), pos.shape[:2])
    per_step = np.sqrt(d2.min(axis=2)) - r
    return cost, per_step.min(axis=1), np.maximum(-per_step, 0.0).sum(axis=1)
