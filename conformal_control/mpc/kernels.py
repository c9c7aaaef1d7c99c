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

Written as plain loops for numba; :func:`evaluate_numpy` is the same arithmetic in numpy
(the reference the tests compare with).
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import kernel

__all__ = ["evaluate", "evaluate_numpy"]

jit = kernel(cache=True, nogil=True)


@jit
def _evaluate(
    pos: np.ndarray,
    cmds: np.ndarray,
    p0: np.ndarray,
    pred: np.ndarray,
    y0: np.ndarray,
    radius: np.ndarray,
    goal: np.ndarray,
    weights: np.ndarray,
    last: np.ndarray,
    continuous: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n_plans, horizon = pos.shape[0], pos.shape[1]
    n_agents = pred.shape[0]
    w_goal, w_term, w_eff, w_comf = weights[0], weights[1], weights[2], weights[3]
    cost = np.zeros(n_plans)
    clear = np.full(n_plans, np.inf)
    viol = np.zeros(n_plans)
    for n in range(n_plans):
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
            d2 = np.inf
            for j in range(n_agents):
                bx = px - pred[j, h, 0]
                by = py - pred[j, h, 1]
                e = bx * bx + by * by
                if continuous:
                    if h == 0:
                        rx = ax - y0[j, 0]
                        ry = ay - y0[j, 1]
                    else:
                        rx = ax - pred[j, h - 1, 0]
                        ry = ay - pred[j, h - 1, 1]
                    dx = bx - rx
                    dy = by - ry
                    dd = dx * dx + dy * dy
                    if dd > 0.0:
                        s = -(rx * dx + ry * dy) / dd
                        if 0.0 < s < 1.0:
                            qx = rx + s * dx
                            qy = ry + s * dy
                            e = qx * qx + qy * qy
                        elif s <= 0.0:
                            e = min(e, rx * rx + ry * ry)
                if e < d2:
                    d2 = e
            if n_agents:
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

    Returns
    -------
    cost, clearance, violation : ndarrays of shape (N,)
        The clearance is ``inf`` when there is no agent; the violation is the sum over
        steps of how far the step's smallest distance falls short of its safe distance
        (0 for a safe plan).
    """
    r = np.asarray(radius, dtype=np.float64)
    if r.ndim == 1:
        r = np.broadcast_to(r, pos.shape[:2])
    c = np.ascontiguousarray
    cost, clear, viol = _evaluate(
        c(pos, dtype=np.float64),
        c(cmds, dtype=np.float64),
        c(p0, dtype=np.float64),
        c(pred, dtype=np.float64),
        c(y0, dtype=np.float64),
        c(r),
        c(goal, dtype=np.float64),
        np.asarray(weights, dtype=np.float64),
        c(last, dtype=np.float64),
        bool(continuous),
    )
    return cost, clear, viol


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
