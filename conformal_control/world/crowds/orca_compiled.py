"""ORCA's half-planes and linear programs, compiled: one pass over the pedestrians.

:meth:`ORCAModel.orca_lines <conformal_control.world.crowds.orca.ORCAModel.orca_lines>` and
:func:`~conformal_control.world.crowds.orca.solve_orca_lp` are vectorised numpy: readable, and
fast for thousands of pedestrians, but each is a few dozen numpy calls, which is most of a
step for a hundred (0.6 of 0.75 ms on the shared 2-core machine). The functions below do
the same arithmetic per pedestrian in scalar loops compiled with numba (``cache=True``, as
the controller's kernels): the same operations in the same order (no fused multiply-add:
numba does not contract without ``fastmath``), the same candidates in the same order and
the same tie-breaks, so their results are the numpy functions' bit for bit
(``tests/world/crowds/test_orca_compiled.py`` checks it on random crowds, infeasible programs
included). :meth:`ORCAModel.step <conformal_control.world.crowds.orca.ORCAModel.step>` uses
them.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.jit import kernel

__all__ = ["orca_lines_compiled", "solve_orca_lp_compiled"]

jit = kernel(cache=True, nogil=True)

_TOL = 1e-9  # as in orca.py
_EPS = 1e-9


@jit
def orca_lines_compiled(
    n: int,
    kmax: int,
    rows: np.ndarray,
    cols: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    vel: np.ndarray,
    all_vel: np.ndarray,
    radius: np.ndarray,
    all_rad: np.ndarray,
    other_responsibility: float,
    inv_dt: float,
    inv_horizon: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``orca_lines`` from the neighbour pairs (rows sorted): point, direction, valid."""
    p = rows.size
    slot = np.empty(p, dtype=np.int64)
    k = 0
    for q in range(p):
        slot[q] = slot[q - 1] + 1 if q > 0 and rows[q] == rows[q - 1] else 0
        if slot[q] < kmax:
            k = max(k, slot[q] + 1)
    point = np.zeros((n, k, 2))
    direction = np.zeros((n, k, 2))
    direction[:, :, 0] = 1.0
    valid = np.zeros((n, k), dtype=np.bool_)
    for q in range(p):
        s = slot[q]
        if s >= kmax:
            continue
        i, j = rows[q], cols[q]
        x, y = px[q], py[q]
        vix, viy = vel[i, 0], vel[i, 1]
        rvx = vix - all_vel[j, 0]
        rvy = viy - all_vel[j, 1]
        r = radius[i] + all_rad[j]
        share = 0.5 if j < n else other_responsibility
        dist_sq = x * x + y * y
        r_sq = r * r
        collide = dist_sq <= r_sq
        inv_t = inv_dt if collide else inv_horizon
        wx = rvx - inv_t * x
        wy = rvy - inv_t * y
        w_sq = wx * wx + wy * wy
        dot = wx * x + wy * y
        on_circle = collide or (dot < 0 and dot * dot > r_sq * w_sq)
        w_len = math.sqrt(w_sq)
        if on_circle and not w_len > 0:
            continue
        if on_circle:
            inv_w = 1.0 / w_len if w_len > 0 else 0.0
            uwx, uwy = wx * inv_w, wy * inv_w
            c_mag = r * inv_t - w_len
            dx_, dy_ = uwy, -uwx
            ux, uy = c_mag * uwx, c_mag * uwy
        else:
            leg = math.sqrt(max(dist_sq - r_sq, 0.0))
            inv_d = 1.0 / dist_sq if dist_sq > 0 else 0.0
            side = 1.0 if (x * wy - y * wx) > 0 else -1.0
            ldx = (x * leg - side * y * r) * inv_d * side
            ldy = (side * x * r + y * leg) * inv_d * side
            proj = rvx * ldx + rvy * ldy
            dx_, dy_ = ldx, ldy
            ux, uy = proj * ldx - rvx, proj * ldy - rvy
        point[i, s, 0] = vix + share * ux
        point[i, s, 1] = viy + share * uy
        direction[i, s, 0] = dx_
        direction[i, s, 1] = dy_
        valid[i, s] = True
    return point, direction, valid


@jit
def _closest_one(
    pt: np.ndarray,
    dr: np.ndarray,
    ok_line: np.ndarray,
    alpha: np.ndarray,
    beta: np.ndarray,
    violated: np.ndarray,
    vpx: float,
    vpy: float,
    vmax: float,
) -> tuple[float, float, bool]:
    """``_closest`` for one pedestrian: the first cheapest feasible candidate."""
    k = ok_line.size
    best = math.inf
    bx = by = 0.0
    have = False
    lim = (vmax + _TOL) * (vmax + _TOL)
    # projections on the violated lines, then intersections of pairs (a < b)
    for stage in range(2):
        for a in range(k):
            for b in range(a + 1 if stage else a, a + 1 if not stage else k):
                if stage == 0:
                    if not violated[a]:
                        continue
                    p0, p1, d0, d1 = pt[a, 0], pt[a, 1], dr[a, 0], dr[a, 1]
                    pd = p0 * d0 + p1 * d1
                    disc = pd * pd + vmax * vmax - (p0 * p0 + p1 * p1)
                    root = math.sqrt(max(disc, 0.0))
                    t = (vpx - p0) * d0 + (vpy - p1) * d1
                    t = min(max(t, -pd - root), -pd + root)
                    cx, cy = p0 + t * d0, p1 + t * d1
                    ok = disc >= 0
                else:
                    if not (ok_line[a] and ok_line[b] and (violated[a] or violated[b])):
                        continue
                    da0, da1, db0, db1 = dr[a, 0], dr[a, 1], dr[b, 0], dr[b, 1]
                    den = da0 * db1 - da1 * db0
                    e0, e1 = pt[a, 0] - pt[b, 0], pt[a, 1] - pt[b, 1]
                    num = db0 * e1 - db1 * e0
                    ok = abs(den) > _EPS
                    f = num / den if ok else 0.0
                    cx, cy = pt[a, 0] + f * da0, pt[a, 1] + f * da1
                if not have:  # the first candidate is the pick unless a cheaper one comes
                    bx, by, have = cx, cy, True
                if ok:
                    for m in range(k):
                        viol = alpha[m] + cx * beta[m, 0] + cy * beta[m, 1]
                        if ok_line[m] and not viol <= _TOL:
                            ok = False
                            break
                if ok and cx * cx + cy * cy <= lim:
                    cost = (cx - vpx) * (cx - vpx) + (cy - vpy) * (cy - vpy)
                    if cost < best:
                        best, bx, by = cost, cx, cy
    return bx, by, best < math.inf


@jit
def _safest_one(
    alpha: np.ndarray, beta: np.ndarray, ok_line: np.ndarray, r: float
) -> tuple[float, float]:
    """``_safest`` for one pedestrian: the first candidate of smallest largest violation."""
    k = ok_line.size
    best = math.inf
    bx = by = 0.0
    found = False
    # candidates in the numpy order: one line, pairs (+), pairs (-), triples
    for stage in range(4):
        if stage == 0:
            count = k
        elif stage < 3:
            count = k * (k - 1) // 2 if k > 1 else 0
        else:
            count = k * (k - 1) * (k - 2) // 6 if k > 2 else 0
        a = 0
        b = 1
        c = 2
        for _ in range(count):
            cx = cy = 0.0
            if stage == 0:
                ok = ok_line[a]
                if ok:
                    cx, cy = -r * beta[a, 0], -r * beta[a, 1]
            elif stage < 3:
                sign = 1.0 if stage == 1 else -1.0
                mx = beta[a, 0] - beta[b, 0]
                my = beta[a, 1] - beta[b, 1]
                rhs = alpha[b] - alpha[a]
                m_sq = mx * mx + my * my
                ok = ok_line[a] and ok_line[b] and m_sq > _EPS
                inv = 1.0 / m_sq if ok else 0.0
                h_sq = rhs * rhs * inv
                ok = ok and h_sq <= r * r
                s = math.sqrt(max(r * r - h_sq, 0.0) * inv)
                if ok:
                    cx = rhs * mx * inv - sign * s * my
                    cy = rhs * my * inv + sign * s * mx
            else:
                a1x, a1y = beta[a, 0] - beta[b, 0], beta[a, 1] - beta[b, 1]
                a2x, a2y = beta[a, 0] - beta[c, 0], beta[a, 1] - beta[c, 1]
                b1, b2 = alpha[b] - alpha[a], alpha[c] - alpha[a]
                det = a1x * a2y - a1y * a2x
                ok = ok_line[a] and ok_line[b] and ok_line[c] and abs(det) > _EPS
                inv = 1.0 / det if ok else 0.0
                tx = (b1 * a2y - b2 * a1y) * inv
                ty = (a1x * b2 - a2x * b1) * inv
                ok = ok and tx * tx + ty * ty <= (r + _TOL) * (r + _TOL)
                if ok:
                    cx, cy = tx, ty
            worst = math.inf
            if ok:
                worst = -math.inf
                for m in range(k):
                    if ok_line[m]:
                        worst = max(worst, alpha[m] + cx * beta[m, 0] + cy * beta[m, 1])
            if not found or worst < best:
                best, bx, by, found = worst, cx, cy, True
            # next index tuple in the numpy order (a < b < c, lexicographic)
            if stage == 0:
                a += 1
            elif stage < 3:
                b += 1
                if b == k:
                    a += 1
                    b = a + 1
            else:
                c += 1
                if c == k:
                    b += 1
                    c = b + 1
                    if c >= k:
                        a += 1
                        b = a + 1
                        c = b + 1
    if not math.isfinite(best):
        return 0.0, 0.0
    return bx, by


@jit
def solve_orca_lp_compiled(
    point: np.ndarray,
    direction: np.ndarray,
    valid: np.ndarray,
    v_pref: np.ndarray,
    v_max: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~conformal_control.world.crowds.orca.solve_orca_lp`, one pedestrian at a time."""
    n, k = valid.shape
    v = np.empty((n, 2))
    feasible = np.ones(n, dtype=np.bool_)
    alpha = np.zeros(k)
    beta = np.zeros((k, 2))
    violated = np.zeros(k, dtype=np.bool_)
    for i in range(n):
        vmax = v_max[i]
        sp = np.hypot(v_pref[i, 0], v_pref[i, 1])
        scale = vmax / (sp if sp > 0 else 1.0) if sp > vmax else 1.0
        vx, vy = v_pref[i, 0] * scale, v_pref[i, 1] * scale
        v[i, 0], v[i, 1] = vx, vy
        anyv = False
        for m in range(k):
            if valid[i, m]:
                d0, d1 = direction[i, m, 0], direction[i, m, 1]
                alpha[m] = d0 * point[i, m, 1] - d1 * point[i, m, 0]
                beta[m, 0], beta[m, 1] = d1, -d0
            else:
                alpha[m] = 0.0
                beta[m, 0] = beta[m, 1] = 0.0
            violated[m] = valid[i, m] and alpha[m] + vx * beta[m, 0] + vy * beta[m, 1] > _TOL
            anyv = anyv or violated[m]
        if not anyv:
            continue
        cx, cy, ok = _closest_one(
            point[i], direction[i], valid[i], alpha, beta, violated,
            v_pref[i, 0], v_pref[i, 1], vmax,
        )  # fmt: skip
        if ok:
            v[i, 0], v[i, 1] = cx, cy
        else:
            feasible[i] = False
            v[i, 0], v[i, 1] = _safest_one(alpha, beta, valid[i], vmax)
    return v, feasible
