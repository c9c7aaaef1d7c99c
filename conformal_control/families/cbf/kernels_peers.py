"""The fused APF control step with robot rows: per-agent shares and slack, compiled.

:func:`~conformal_control.families.cbf.kernels2d.apf_control` builds one conformal row per predicted
agent, every row with the whole ``a h`` and ``+ lambda``. In a multi-robot world a robot's
rows about the other robots are reciprocal (:mod:`~conformal_control.families.cbf.reciprocal`): the
robot's share ``s_ij`` of ``a h``, a reference velocity ``v~_j`` computed at every control
instant from what the robot knows now, and ``+ lambda`` only where the conformal scope
puts it. :func:`apf_control_peers` is that step, one compiled call: it writes the peers'
positions and ``v~_j`` into the interval's arrays, builds the rows (the arithmetic of
:func:`~conformal_control.families.cbf.kernels2d.apf_rows` with the two weights) and solves with
:func:`~conformal_control.families.cbf.kernels2d.filter_step`, recorded as ``apf_control`` records.
A row without slack is handed to the filter as ``b - lambda`` (so ``A v + b >= 0`` at the
requested lambda).

When the rows are infeasible at lambda and the filter's fallback is ``lambda_search``,
:func:`lexicographic_search` raises a slack level ``lambda' >= lambda`` on the rows with
slack (the smallest feasible one, by bisection on the exact projection's feasibility,
which is monotone in it; rows with a zero gradient -- an agent already overlapped, which
no velocity helps -- are left out). The rows without slack, by the ``keep`` flag, either join the
level once it passes 0 (they get ``max(0, lambda')``) or keep no slack at all unless they
cannot be met on their own (then every row is relaxed together, as ``lambda_search``
does). A step that relaxed the rows without slack returns :data:`SEARCH_ALL` (counted).
"""

from __future__ import annotations

import math

import numpy as np

from .kernels2d import (
    ESCAPE_POLYGON,
    HEADER,
    INFEASIBLE,
    NONFINITE,
    OPTIMAL,
    OUT_OF_RANGE,
    RECORD_FIELDS,
    SEARCHED,
    TOO_MANY,
    UNCONSTRAINED,
    edge_prepare,
    edge_step,
    edge_views,
    filter_step,
    jit,
    lambda_margin,
    meets_sides,
    smallest_lambda,
    solve_rows,
)
from .pyhypot import c_hypot

__all__ = [
    "PYTHON_STEP",
    "SEARCH_ALL",
    "apf_control_peers",
    "apf_rows_weighted",
    "floor_rows_into",
    "lexicographic_search",
]

#: Result code of :func:`apf_control_peers`: the search had to give the rows without
#: slack some too (the common level ended above 0).
SEARCH_ALL = 7

#: Result code of :func:`apf_control_peers` with the robot rows giving way first
#: (``turn[6]``): the step needs what only the generic Python path does -- an agent or a
#: peer within the edge rule's distance, a coinciding peer, or no command meeting every
#: row (the priority stages of
#: :func:`~conformal_control.families.cbf.reciprocal.priority_relax`). Nothing was
#: recorded or counted; the caller decides the step in Python.
PYTHON_STEP = 9

#: Below this distance (m) two robots coincide
#: (:data:`~conformal_control.families.cbf.reciprocal.TIE_DISTANCE`: the generic path
#: decides, with the pair's tie-break direction).
TIE_DISTANCE = 1e-9

#: Bisection steps of :func:`lexicographic_search` at most.
MAX_BISECTIONS = 60


@jit
def _feasible_at(
    n0: float,
    n1: float,
    A: np.ndarray,
    b: np.ndarray,
    hard: np.ndarray,
    lam: float,
    lam_soft: float,
    keep: bool,
    S: np.ndarray,
    s: np.ndarray,
    radius: float,
    G: np.ndarray,
    h: np.ndarray,
    rhs: np.ndarray,
) -> tuple[bool, float, float]:
    """The projection at the level ``lam_soft``: the rows without slack (whose ``b`` holds
    ``- lam``) at 0 (``keep``) or ``max(0, lam_soft)``, the others at ``lam_soft``."""
    up = lam if keep else lam + max(0.0, lam_soft)
    for j in range(A.shape[0]):
        if A[j, 0] == 0.0 and A[j, 1] == 0.0:  # no velocity changes it: left out
            rhs[j] = math.inf
        else:
            rhs[j] = b[j] + (up if hard[j] != 0.0 else lam_soft)
    return solve_rows(n0, n1, A, rhs, S, s, radius, G, h)


@jit
def lexicographic_search(
    n0: float,
    n1: float,
    A: np.ndarray,
    b: np.ndarray,
    hard: np.ndarray,
    lam: float,
    keep: bool,
    S: np.ndarray,
    s: np.ndarray,
    verts: np.ndarray,
    radius: float,
    margin_rel: float,
    G: np.ndarray,
    h: np.ndarray,
    rhs: np.ndarray,
    Ak: np.ndarray,
    bk: np.ndarray,
) -> tuple[int, float, float, float, int]:
    """The fallback of an infeasible step with rows without slack (``hard`` != 0; their
    ``b`` already holds ``- lam``): ``(code, v_x, v_y, lambda_applied, n_solves)``.

    Rows with a zero gradient (an agent the robot already overlaps: no velocity changes
    them) are left out of the search -- they would set the level for every other row
    and cannot be helped. The smallest level ``lambda' >= lam`` at which the rows with
    slack at ``lambda'`` and
    the others at 0 (``keep``) or ``max(0, lambda')`` are feasible (see the module
    docstring), bracketed below by the smallest lambda of the rows with slack alone and
    above by the level that meets them anywhere in the speed disc, then bisected to the
    filter's margin; the projection there. :data:`SEARCHED` when the rows without slack
    kept none, :data:`SEARCH_ALL` otherwise (with ``keep``: every row relaxed together
    because the rows without slack could not be met on their own).
    """
    m = A.shape[0]
    # the rows with slack alone: their smallest lambda (lower bound), compacted into G, h
    ms = 0
    hi = lam
    for j in range(m):
        nrm = c_hypot(A[j, 0], A[j, 1])
        if nrm == 0.0:
            continue
        top = -b[j] + nrm * radius
        if hard[j] == 0.0:
            G[ms, 0] = A[j, 0]
            G[ms, 1] = A[j, 1]
            h[ms] = b[j]
            ms += 1
        elif keep:
            continue
        else:
            top -= lam
        if top > hi:
            hi = top
    lo = lam
    if ms:
        star, _, _ = smallest_lambda(G[:ms], h[:ms].copy(), S, s, verts, radius, Ak, bk)
        if star > lo:
            lo = star
    solves = 1
    margin = lambda_margin(max(abs(lo), abs(hi)), A, b, radius, margin_rel)
    ok, v0, v1 = _feasible_at(n0, n1, A, b, hard, lam, hi + margin, keep, S, s, radius, G, h, rhs)
    solves += 1
    if not ok:  # the rows without slack cannot be met (keep), or round-off: all together
        # (the rows with a zero gradient left out here too, as the generic path does)
        ml = 0
        for j in range(m):
            if A[j, 0] != 0.0 or A[j, 1] != 0.0:
                G[ml, 0] = A[j, 0]
                G[ml, 1] = A[j, 1]
                h[ml] = b[j]
                ml += 1
        star, w0, w1 = smallest_lambda(G[:ml], h[:ml].copy(), S, s, verts, radius, Ak, bk)
        floor = max(lam, star)
        used = floor + lambda_margin(floor, G[:ml], h[:ml], radius, margin_rel)
        for j in range(m):
            if A[j, 0] == 0.0 and A[j, 1] == 0.0:
                rhs[j] = math.inf
            else:
                rhs[j] = b[j] + used
        ok, v0, v1 = solve_rows(n0, n1, A, rhs, S, s, radius, G, h)
        if ok:
            return SEARCH_ALL, v0, v1, used, solves + 2
        return SEARCH_ALL, w0, w1, floor, solves + 2
    hi = hi + margin
    ok, w0, w1 = _feasible_at(n0, n1, A, b, hard, lam, lo + margin, keep, S, s, radius, G, h, rhs)
    solves += 1
    if ok:
        code = SEARCHED if keep or lo + margin <= 0.0 else SEARCH_ALL
        return code, w0, w1, lo + margin, solves
    for _ in range(MAX_BISECTIONS):
        if hi - lo <= margin:
            break
        mid = 0.5 * (lo + hi)
        ok, w0, w1 = _feasible_at(n0, n1, A, b, hard, lam, mid, keep, S, s, radius, G, h, rhs)
        solves += 1
        if ok:
            hi, v0, v1 = mid, w0, w1
        else:
            lo = mid
    return (SEARCHED if keep or hi <= 0.0 else SEARCH_ALL), v0, v1, hi, solves


@jit
def apf_rows_weighted(
    x0: float,
    x1: float,
    xp: np.ndarray,
    vp: np.ndarray,
    col: np.ndarray,
    lam: float,
    prm: np.ndarray,
    A: np.ndarray,
    b: np.ndarray,
) -> None:
    """Rows ``A_j v + b_j`` with ``b_j = dh/dx_j . v_j + share_j a h_j - hard_j lambda``
    (the APF barrier and slope in ``prm``, :data:`~conformal_control.families.cbf.kernels2d.PARAMS`;
    ``col`` (3, N): share, hard (0 or 1) and the collision distance added for the agent,
    which the "surface" convention allows)."""
    K = prm[0]
    rho0 = prm[1]
    d_c = prm[2]
    delta = prm[3]
    surface = prm[4] != 0.0
    a = prm[5]
    for j in range(xp.shape[0]):
        dx0 = x0 - xp[j, 0]
        dx1 = x1 - xp[j, 1]
        d = c_hypot(dx0, dx1)
        extra = col[2, j]
        rho = (d - d_c if extra == 0.0 else d - (d_c + extra)) if surface else d
        r = min(max(rho, 0.0), rho0)
        q = 1.0 - r / rho0
        r2 = r * r
        inv_d = 1.0 / (2.0 * r2 + K * q * q)
        hval = 2.0 * r2 * inv_d - delta
        scale = 4.0 * K * q * r * inv_d * inv_d / max(d, 1e-300)
        a0 = scale * dx0
        a1 = scale * dx1
        A[j, 0] = a0
        A[j, 1] = a1
        s = col[0, j]
        ah = a * hval if s == 1.0 else s * (a * hval)
        bj = (-a0) * vp[j, 0] + (-a1) * vp[j, 1] + ah
        if col[1, j] != 0.0:
            bj -= lam
        b[j] = bj


@jit
def apf_control_peers(
    x0: float,
    x1: float,
    n0: float,
    n1: float,
    lam: float,
    s: int,
    i: int,
    pv: np.ndarray,
    buf: np.ndarray,
    rec: np.ndarray,
    col: np.ndarray,
    npred: int,
    peer_pos: np.ndarray,
    peer_ref: np.ndarray,
    own0: float,
    own1: float,
    turn: np.ndarray,
    vx: float,
    vy: float,
    floor: np.ndarray,
) -> int:
    """:func:`~conformal_control.families.cbf.kernels2d.apf_control` with robot columns.

    ``pv`` (2, steps, N, 2): columns ``:npred`` hold the predicted agents (as for
    ``apf_control``), columns ``npred:`` the peers, whose step ``s`` this call writes:
    positions ``peer_pos`` (K, 2) and reference velocities ``v~_j = share_j r_j + (1 -
    share_j) r_i`` from the peers' references ``peer_ref`` (K, 2) and the robot's own
    ``(own0, own1)`` (zeros for position-only information). ``col`` (3, N) gives per
    column the share weighing ``a h`` (1 for predicted agents), 1 for a row without
    ``+ lambda`` (else 0) and the collision distance added (m; "surface" convention).
    ``turn`` holds the side-step rule's cosine, sine, horizon (s), cone cosine and slow
    fraction, then the lexicographic search's ``keep`` flag
    (:meth:`~conformal_control.families.cbf.reciprocal.Reciprocity.turn`): with the robot's velocity
    ``(vx, vy)`` below that fraction of the nominal speed, the nominal velocity is first
    turned away from the nearest peer ahead. Same codes, record and buffers as
    ``apf_control``.

    With ``turn[6]`` (priority ``"pedestrians"``: the robot rows give way first) the
    rows are those of the generic path's ``_with_robots``: the predicted agents', the
    peers' barrier rows and their floor rows (:func:`floor_rows_into`, ``floor`` = the
    robots' collision distance and the floor margin, m), and the step is decided here
    only when it is the plain projection (or the nominal velocity): with an agent or a
    peer within the edge rule's distance, a coinciding peer or an infeasible step it
    returns :data:`PYTHON_STEP` before recording or counting anything (the generic path
    decides it: the edge rule's polygon with the robots, the priority stages).
    """
    cap = int(buf[11])
    m = pv.shape[2]
    first = turn[6] != 0.0 and m > npred
    rows = m + (m - npred) if first else m
    if rows > cap:
        return TOO_MANY
    if s < 0 or s >= pv.shape[1]:
        return OUT_OF_RANGE
    for k in range(m - npred):
        j = npred + k
        sj = col[0, j]
        pv[0, s, j, 0] = peer_pos[k, 0]
        pv[0, s, j, 1] = peer_pos[k, 1]
        pv[1, s, j, 0] = sj * peer_ref[k, 0] + (1.0 - sj) * own0
        pv[1, s, j, 1] = sj * peer_ref[k, 1] + (1.0 - sj) * own1
    prm = buf[: HEADER - 3]
    if turn[1] != 0.0 and m > npred:
        sp = c_hypot(n0, n1)
        if sp > 0.0 and c_hypot(vx, vy) < turn[4] * sp:  # side-step (held back)
            near = math.inf
            side = 0.0
            for k in range(m - npred):
                rx = peer_pos[k, 0] - x0
                ry = peer_pos[k, 1] - x1
                d = c_hypot(rx, ry)
                if (
                    d < prm[2] + col[2, npred + k] + sp * turn[2]
                    and rx * n0 + ry * n1 > turn[3] * sp * d
                    and d < near
                ):
                    near = d
                    side = n0 * ry - n1 * rx
            if near < math.inf:
                sn = -turn[1] if side < 0.0 else turn[1]
                t0 = turn[0] * n0 + sn * n1
                n1 = -sn * n0 + turn[0] * n1
                n0 = t0
    if first:
        edge = prm[12]
        for k in range(m - npred):  # a coinciding peer, or one inside (robot_escape)
            d = c_hypot(peer_pos[k, 0] - x0, peer_pos[k, 1] - x1)
            if d < TIE_DISTANCE or (edge >= 0.0 and d < floor[0]):
                return PYTHON_STEP
        if edge >= 0.0:  # an agent within the edge rule's distance (constraint.escape)
            for j in range(npred):
                if c_hypot(x0 - pv[0, s, j, 0], x1 - pv[0, s, j, 1]) < edge:
                    return PYTHON_STEP
    ns = int(buf[HEADER - 3])
    o = HEADER + 5 * ns
    poly = buf[HEADER:o]
    work = buf[o:]
    if first:
        return _first_step(
            x0, x1, n0, n1, lam, s, i, pv, buf, rec, col, npred, peer_pos, floor, cap, ns,
            poly, work,
        )  # fmt: skip
    A = work[0 : 2 * m].reshape((m, 2))
    b = work[2 * cap : 2 * cap + m]
    rhs = work[3 * cap : 3 * cap + m]
    Ak = work[4 * cap : 4 * cap + 2 * m].reshape((m, 2))
    bk = work[6 * cap : 6 * cap + m]
    G = work[7 * cap : 9 * cap + 2 * ns].reshape((cap + ns, 2))
    h = work[9 * cap + 2 * ns : 10 * cap + 3 * ns]
    S = poly[0 : 2 * ns].reshape((ns, 2))
    sv = poly[2 * ns : 3 * ns]
    verts = poly[3 * ns : 5 * ns].reshape((ns, 2))
    apf_rows_weighted(x0, x1, pv[0, s], pv[1, s], col, lam, prm, A, b)
    search = prm[9] != 0.0
    hard = col[1, :m]
    lexicographic = search and hard.any()
    # the edge rule on the predicted agents (kernels2d.edge_prepare): within the escape
    # polygon, or decided by it alone
    region = work[10 * cap + 3 * ns :]
    region[2] = -1.0
    v_max = prm[8]
    mode = -1
    if prm[12] >= 0.0 and npred:
        mode, nsq, nvq, e0, e1 = edge_prepare(
            x0, x1, pv[0, s, :npred], pv[1, s, :npred], max(prm[12], prm[2]), prm[13], prm[14],
            lam, A, b, S, sv, verts, prm[6], region, cap,
        )  # fmt: skip
        if mode >= 0:
            if mode != ESCAPE_POLYGON:
                code, v0, v1, lam_used, _ = edge_step(
                    n0, n1, A, b, lam, prm, mode, ns, nsq, nvq, e0, e1, region, cap, rhs, Ak, bk
                )
                return _record_peers(code, x0, x1, v0, v1, lam_used, i, buf, rec)
            ES, es, ev, _, G, h = edge_views(region, cap, ns)[5:11]
            if not meets_sides(n0, n1, ES, es, ns, nsq):
                v_max = math.nan  # never unconstrained
            S, sv, verts = ES[:nsq], es[:nsq], ev[:nvq]
    code, v0, v1, lam_used, _ = filter_step(
        n0, n1, A, b, lam, S, sv, verts, prm[6], prm[7] != 0.0, v_max,
        search and not lexicographic, prm[10], G, h, rhs, Ak, bk,
    )  # fmt: skip
    if lexicographic and code == INFEASIBLE:
        code, v0, v1, lam_used, _ = lexicographic_search(
            n0, n1, A, b, hard, lam, turn[5] != 0.0, S, sv, verts, prm[6], prm[10], G, h, rhs,
            Ak, bk,
        )  # fmt: skip
    return _record_peers(code, x0, x1, v0, v1, lam_used, i, buf, rec)


@jit
def floor_rows_into(
    x0: float,
    x1: float,
    peer_pos: np.ndarray,
    shares: np.ndarray,
    d_c: float,
    a: float,
    margin: float,
    lam: float,
    A: np.ndarray,
    b: np.ndarray,
) -> None:
    """The robots' floor rows (:func:`~conformal_control.families.cbf.reciprocal.floor_rows`,
    the same operations) written to ``A`` and ``b``, minus ``lam`` (rows without slack):
    ``-u . v + s_ij a (d - d_c - margin) - lam`` with ``u`` the unit vector toward the
    peer; no peer may coincide with the robot (the caller checks)."""
    target = d_c + margin
    for k in range(peer_pos.shape[0]):
        r0 = peer_pos[k, 0] - x0
        r1 = peer_pos[k, 1] - x1
        d = c_hypot(r0, r1)
        A[k, 0] = -(r0 / d)
        A[k, 1] = -(r1 / d)
        b[k] = shares[k] * a * (d - target) - lam


@jit
def _first_step(
    x0: float,
    x1: float,
    n0: float,
    n1: float,
    lam: float,
    s: int,
    i: int,
    pv: np.ndarray,
    buf: np.ndarray,
    rec: np.ndarray,
    col: np.ndarray,
    npred: int,
    peer_pos: np.ndarray,
    floor: np.ndarray,
    cap: int,
    ns: int,
    poly: np.ndarray,
    work: np.ndarray,
) -> int:
    """The plain step of :func:`apf_control_peers` with the floor rows (``turn[6]``): the
    predicted agents' and the peers' rows, the floor rows after them, projected; an
    infeasible step is :data:`PYTHON_STEP` (nothing recorded)."""
    m = pv.shape[2]
    k = m - npred
    rows = m + k
    prm = buf[: HEADER - 3]
    A = work[0 : 2 * rows].reshape((rows, 2))
    b = work[2 * cap : 2 * cap + rows]
    rhs = work[3 * cap : 3 * cap + rows]
    Ak = work[4 * cap : 4 * cap + 2 * rows].reshape((rows, 2))
    bk = work[6 * cap : 6 * cap + rows]
    G = work[7 * cap : 9 * cap + 2 * ns].reshape((cap + ns, 2))
    h = work[9 * cap + 2 * ns : 10 * cap + 3 * ns]
    S = poly[0 : 2 * ns].reshape((ns, 2))
    sv = poly[2 * ns : 3 * ns]
    verts = poly[3 * ns : 5 * ns].reshape((ns, 2))
    apf_rows_weighted(x0, x1, pv[0, s], pv[1, s], col, lam, prm, A[:m], b[:m])
    floor_rows_into(
        x0, x1, peer_pos, col[0, npred:m], floor[0], prm[5], floor[1], lam, A[m:], b[m:]
    )
    code, v0, v1, lam_used, _ = filter_step(
        n0, n1, A, b, lam, S, sv, verts, prm[6], prm[7] != 0.0, prm[8], False, prm[10], G, h,
        rhs, Ak, bk,
    )  # fmt: skip
    if code != UNCONSTRAINED and code != OPTIMAL:
        return PYTHON_STEP
    return _record_peers(code, x0, x1, v0, v1, lam_used, i, buf, rec)


@jit
def _record_peers(
    code: int,
    x0: float,
    x1: float,
    v0: float,
    v1: float,
    lam_used: float,
    i: int,
    buf: np.ndarray,
    rec: np.ndarray,
) -> int:
    """Record a step of :func:`apf_control_peers` (``apf_control``'s record); its code."""
    if code == NONFINITE:
        return code
    rows = rec.shape[0] // RECORD_FIELDS
    rec[2 * i] = x0
    rec[2 * i + 1] = x1
    rec[5 * rows + i] = code
    if code != INFEASIBLE:
        rec[2 * rows + 2 * i] = v0
        rec[2 * rows + 2 * i + 1] = v1
        rec[4 * rows + i] = lam_used
        buf[HEADER - 2] = v0
        buf[HEADER - 1] = v1
    return code
