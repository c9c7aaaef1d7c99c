"""Exact solvers for the flagship's 2-D problems, written once for Python and numba.

The safety filter's decision is a velocity in the plane, so its QP (the projection of the
nominal velocity onto an intersection of half-planes and the speed polygon) and its
feasibility LP (2-D velocity + lambda) are low-dimensional problems. General solvers
(piqp is an interior-point method) stop a tolerance inside the constraints; the
incremental algorithms below (Seidel's for LP and its QP analogue, the one RVO2 uses for
ORCA) are exact up to floating point and take microseconds. No maintained library ships
them for this shape (qpsolvers' backends are general n-D solvers), hence this module.

Every function is plain Python on float64 arrays with scalar loops, compiled with numba
(``cache=True``: the first use on a machine compiles for a few seconds and writes the
machine code next to this file; later processes load it in milliseconds). The interpreted
original of each is its ``.py_func``. Constraints are ``G v <= h`` with unit-norm rows
``G`` (conformal rows are normalised by :func:`presolve`; the speed polygon's sides are
unit normals).

Tolerances: a constraint counts as met when violated by at most ``tol`` (in its own
units), a 1-D interval counts as empty when its bounds cross by more than ``tol``; both are
``1e-13`` times the problem's scale, i.e. floating-point round-off.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.jit import kernel
from .pyhypot import c_hypot

__all__ = [
    "PARALLEL",
    "apf_control",
    "apf_rows",
    "apf_step",
    "filter_step",
    "min_lambda",
    "presolve",
    "project",
]

#: Two unit normals whose cross product is below this are parallel.
PARALLEL = 1e-13
#: Relative tolerance (times the problem's scale) of every feasibility comparison.
REL_TOL = 1e-13

#: Result codes of :func:`filter_step`.
NONFINITE, UNCONSTRAINED, OPTIMAL, INFEASIBLE, SEARCHED, SEARCH_VERTEX = -1, 0, 1, 2, 3, 4
#: More result codes of :func:`apf_control`: the work vector is too small for the agents;
#: the step is outside the predictions.
TOO_MANY, OUT_OF_RANGE = 5, 6
#: Result code of :func:`apf_step` (7 is ``kernels_peers.SEARCH_ALL``): the edge rule
#: decided alone (no command that does not close in on an overlapping agent exists, or
#: the commands that do form a degenerate set; see :func:`escape_polygon`).
ESCAPED = 8

#: :func:`escape_polygon`'s modes: the escape polygon is the admissible set; the decision
#: is the command minimising the largest closing speed; the polygon is degenerate (a
#: segment or a point): the decision is the nominal projected onto it.
ESCAPE_POLYGON, ESCAPE_MINIMAX, ESCAPE_DEGENERATE = 0, 1, 2
#: Width (times the speed set's radius) by which the push rows are loosened below their
#: smallest feasible relaxation, so that the escape polygon is never a sliver.
ESCAPE_WIDTH = 0.1
#: Area (times the radius squared) below which an escape polygon counts as degenerate.
ESCAPE_AREA = 1e-9

jit = kernel(cache=True, nogil=True)


@jit
def presolve(A: np.ndarray, rhs: np.ndarray, radius: float, G: np.ndarray, h: np.ndarray) -> int:
    """Write the rows ``A v + rhs >= 0`` as unit-norm ``G v <= h`` into ``G``, ``h``.

    Rows met by every v with ``||v|| <= radius`` (a disc containing the speed set) are
    dropped; returns the number of rows written, or ``-1`` when a row is met by no such v
    (infeasible whatever the other rows). Kept rows have ``|h| < radius``, so the
    projection is well scaled whatever the magnitude of ``A`` and ``rhs``.
    """
    k = 0
    for j in range(A.shape[0]):
        a0 = A[j, 0]
        a1 = A[j, 1]
        r = rhs[j]
        nrm = c_hypot(a0, a1)
        reach = nrm * radius
        if r >= reach:
            continue
        if r + reach < 0.0:
            return -1
        G[k, 0] = -a0 / nrm
        G[k, 1] = -a1 / nrm
        h[k] = r / nrm
        k += 1
    return k


@jit
def project(
    n0: float, n1: float, G: np.ndarray, h: np.ndarray, k: int, tol: float
) -> tuple[bool, float, float]:
    """argmin ||v - n||^2 s.t. ``G[:k] v <= h[:k]`` (unit rows, bounded feasible set).

    Incremental: the optimum of the first i constraints either meets constraint i, or the
    optimum of the first i + 1 lies on its line, where it is the projection of n clipped
    to the interval the previous constraints leave (a 1-D problem). Returns
    ``(feasible, v_x, v_y)``.
    """
    v0 = n0
    v1 = n1
    for i in range(k):
        g0 = G[i, 0]
        g1 = G[i, 1]
        if g0 * v0 + g1 * v1 - h[i] <= tol:
            continue
        e = g0 * n0 + g1 * n1 - h[i]
        p0 = n0 - e * g0
        p1 = n1 - e * g1
        d0 = -g1
        d1 = g0
        lo = -math.inf
        hi = math.inf
        for j in range(i):
            den = G[j, 0] * d0 + G[j, 1] * d1
            num = h[j] - (G[j, 0] * p0 + G[j, 1] * p1)
            if abs(den) <= PARALLEL:
                if num < -tol:
                    return False, v0, v1
                continue
            t = num / den
            if den > 0.0:
                if t < hi:
                    hi = t
            elif t > lo:
                lo = t
        if lo > hi:
            if lo - hi > tol:
                return False, v0, v1
            t = 0.5 * (lo + hi)
        else:
            t = min(max(0.0, lo), hi)
        v0 = p0 + t * d0
        v1 = p1 + t * d1
    return True, v0, v1


@jit
def _lp_con(
    q: int, i: int, A: np.ndarray, b: np.ndarray, bound: float
) -> tuple[float, float, float]:
    """Constraint q of the 2-D LP solved when row i becomes tight (see :func:`min_lambda`)."""
    if q == 0:  # lambda = -A_i v - b_i >= L
        return A[i, 0], A[i, 1], -b[i] - bound
    j = q - 1  # row j stays below row i: (A_i - A_j) v <= b_j - b_i
    return A[i, 0] - A[j, 0], A[i, 1] - A[j, 1], b[j] - b[i]


@jit
def min_lambda(
    A: np.ndarray,
    b: np.ndarray,
    m: int,
    S: np.ndarray,
    s: np.ndarray,
    verts: np.ndarray,
    radius: float,
    tol: float,
) -> tuple[float, float, float]:
    """min lambda s.t. ``A[:m] v + b[:m] + lambda >= 0`` and ``S v <= s`` (rows with
    ``||A_j|| > 0``; ``m >= 1``), by Seidel's incremental LP in (v, lambda).

    The current optimum (v, lambda) is kept for the rows seen so far (with the valid lower
    bound ``lambda >= L = max_j(-b_j - ||A_j|| radius)``, which never binds at the end).
    When row i is violated, the new optimum has row i tight, lambda = -A_i v - b_i: a 2-D LP
    maximising A_i v over the polygon, the bound, and ``(A_i - A_j) v <= b_j - b_i`` for
    the earlier rows j, itself solved incrementally with 1-D problems on lines. The start
    (no row yet) is v = 0, or the polygon's first vertex when 0 is outside the polygon (an
    escape polygon): each 2-D LP is feasible because the previous optimum is in it. Returns
    ``(lambda, v_x, v_y)`` with lambda recomputed at v, so v meets every row there.
    """
    ns = S.shape[0]
    L = -math.inf
    for j in range(m):
        lb = -b[j] - c_hypot(A[j, 0], A[j, 1]) * radius
        if lb > L:
            L = lb
    v0 = 0.0
    v1 = 0.0
    for k in range(ns):  # the start must be in the polygon (an escape polygon may omit 0)
        if -s[k] > tol:
            v0 = verts[0, 0]
            v1 = verts[0, 1]
            break
    lam = L
    for i in range(m):
        if -A[i, 0] * v0 - A[i, 1] * v1 - b[i] <= lam + tol:
            continue
        c0 = A[i, 0]
        c1 = A[i, 1]
        # start: the polygon's vertex maximising c
        best = -math.inf
        for k in range(verts.shape[0]):
            val = c0 * verts[k, 0] + c1 * verts[k, 1]
            if val > best:
                best = val
                v0 = verts[k, 0]
                v1 = verts[k, 1]
        for q in range(i + 1):
            g0, g1, hq = _lp_con(q, i, A, b, L)
            if g0 * v0 + g1 * v1 - hq <= tol:
                continue
            nrm = c_hypot(g0, g1)
            if nrm * radius <= tol:  # (nearly) identical gradients: flat over the speed set,
                continue  # and met where row i is violated (up to round-off)
            u0 = g0 / nrm
            u1 = g1 / nrm
            off = hq / nrm
            p0 = off * u0
            p1 = off * u1
            d0 = -u1
            d1 = u0
            lo = -math.inf
            hi = math.inf
            for k in range(ns + q):
                if k < ns:
                    w0 = S[k, 0]
                    w1 = S[k, 1]
                    wh = s[k]
                    wn = 1.0
                else:
                    w0, w1, wh = _lp_con(k - ns, i, A, b, L)
                    wn = c_hypot(w0, w1)
                    if wn * radius <= tol:  # flat over the speed set (see above)
                        continue
                # a parallel constraint cannot empty the interval: the LP is feasible
                den = (w0 * d0 + w1 * d1) / wn
                num = wh - (w0 * p0 + w1 * p1)
                if abs(den) <= PARALLEL:
                    continue
                t = num / (den * wn)
                if den > 0.0:
                    if t < hi:
                        hi = t
                elif t > lo:
                    lo = t
            if lo > hi:  # empty only by round-off: the LP is feasible
                t = 0.5 * (lo + hi)
            else:
                cd = c0 * d0 + c1 * d1
                if cd > 0.0:
                    t = hi
                elif cd < 0.0:
                    t = lo
                else:  # objective flat along the line: stay closest to the current point
                    t = min(max(d0 * v0 + d1 * v1, lo), hi)
            v0 = p0 + t * d0
            v1 = p1 + t * d1
        lam = -A[i, 0] * v0 - A[i, 1] * v1 - b[i]
        if lam < L:
            lam = L
    worst = -math.inf
    for j in range(m):
        r = -A[j, 0] * v0 - A[j, 1] * v1 - b[j]
        if r > worst:
            worst = r
    return worst, v0, v1


@jit
def apf_rows(
    x0: float,
    x1: float,
    xp: np.ndarray,
    vp: np.ndarray,
    K: float,
    rho0: float,
    d_c: float,
    delta: float,
    surface: bool,
    a: float,
    A: np.ndarray,
    b: np.ndarray,
) -> None:
    """The APF barrier's conformal rows for the agents at ``xp`` moving with ``vp``, written
    into ``A``, ``b`` (the arithmetic of
    :class:`~conformal_control.families.cbf.barriers.APFBarrier`
    and :meth:`~conformal_control.families.cbf.constraint.ConformalConstraint.rows`)."""
    for j in range(xp.shape[0]):
        dx0 = x0 - xp[j, 0]
        dx1 = x1 - xp[j, 1]
        d = c_hypot(dx0, dx1)
        rho = d - d_c if surface else d
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
        b[j] = (-a0) * vp[j, 0] + (-a1) * vp[j, 1] + a * hval


@jit
def problem_scale(A: np.ndarray, b: np.ndarray, m: int, radius: float) -> float:
    """``max(1, |b_j|, ||A_j|| radius)``: the size of the rows, in lambda units."""
    scale = 1.0
    for j in range(m):
        x = max(abs(b[j]), c_hypot(A[j, 0], A[j, 1]) * radius)
        if x > scale:
            scale = x
    return scale


@jit
def floor_rows(A: np.ndarray, b: np.ndarray, Ak: np.ndarray, bk: np.ndarray) -> tuple[int, float]:
    """Split the rows for the lambda LP: rows with a zero gradient only bound lambda from
    below (``lambda >= -b_j``, returned); the others are copied into ``Ak``, ``bk``."""
    m = 0
    L0 = -math.inf
    for j in range(A.shape[0]):
        if A[j, 0] == 0.0 and A[j, 1] == 0.0:
            if -b[j] > L0:
                L0 = -b[j]
            continue
        Ak[m, 0] = A[j, 0]
        Ak[m, 1] = A[j, 1]
        bk[m] = b[j]
        m += 1
    return m, L0


@jit
def smallest_lambda(
    A: np.ndarray,
    b: np.ndarray,
    S: np.ndarray,
    s: np.ndarray,
    verts: np.ndarray,
    radius: float,
    Ak: np.ndarray,
    bk: np.ndarray,
) -> tuple[float, float, float]:
    """min lambda over the speed set for every row (``-inf`` and v = 0 without rows)."""
    m, L0 = floor_rows(A, b, Ak, bk)
    if m == 0:
        return L0, 0.0, 0.0
    scale = problem_scale(Ak, bk, m, radius)
    lam, v0, v1 = min_lambda(Ak, bk, m, S, s, verts, radius, REL_TOL * scale)
    return max(lam, L0), v0, v1


@jit
def solve_rows(
    n0: float,
    n1: float,
    A: np.ndarray,
    rhs: np.ndarray,
    S: np.ndarray,
    s: np.ndarray,
    radius: float,
    G: np.ndarray,
    h: np.ndarray,
) -> tuple[bool, float, float]:
    """The projection of n onto ``A v + rhs >= 0`` and the speed set (presolve + project)."""
    k = presolve(A, rhs, radius, G, h)
    if k < 0:
        return False, n0, n1
    ns = S.shape[0]
    for i in range(ns):
        G[k + i, 0] = S[i, 0]
        G[k + i, 1] = S[i, 1]
        h[k + i] = s[i]
    return project(n0, n1, G, h, k + ns, REL_TOL * radius)


@jit
def lambda_margin(
    lam_star: float, A: np.ndarray, b: np.ndarray, radius: float, rel: float
) -> float:
    """Margin above lambda* at which the exact projection finds the rows feasible:
    ``rel`` times the rows' scale (1e3 times the feasibility tolerance for ``rel=1e-10``)."""
    return rel * max(problem_scale(A, b, A.shape[0], radius), abs(lam_star))


@jit
def filter_step(
    n0: float,
    n1: float,
    A: np.ndarray,
    b: np.ndarray,
    lam: float,
    S: np.ndarray,
    s: np.ndarray,
    verts: np.ndarray,
    radius: float,
    box: bool,
    v_max: float,
    search: bool,
    margin_rel: float,
    G: np.ndarray,
    h: np.ndarray,
    rhs: np.ndarray,
    Ak: np.ndarray,
    bk: np.ndarray,
) -> tuple[int, float, float, float, int]:
    """One decision of the exact filter: ``(code, v_x, v_y, lambda_applied, n_solves)``.

    The same steps, in the same order, as the generic path of
    :class:`~conformal_control.families.cbf.filters.exact2d.Exact2DSafetyFilter` with the
    ``lambda_search`` fallback (``search=True``); with ``search=False`` an infeasible step
    returns :data:`INFEASIBLE` for the caller's fallback.
    """
    m = A.shape[0]
    ok = True
    total = n0 + n1 + lam
    for j in range(m):
        rhs[j] = b[j] + lam
        r = A[j, 0] * n0 + A[j, 1] * n1 + rhs[j]
        total += r
        if r < 0.0:
            ok = False
    if not math.isfinite(total):
        return NONFINITE, n0, n1, lam, 0
    if ok:
        if box:
            ok = abs(n0) <= v_max and abs(n1) <= v_max
        else:
            ok = n0 * n0 + n1 * n1 <= v_max * v_max * (1.0 + 1e-12)
        if ok:
            return UNCONSTRAINED, n0, n1, lam, 0
    feasible, v0, v1 = solve_rows(n0, n1, A, rhs, S, s, radius, G, h)
    if feasible:
        return OPTIMAL, v0, v1, lam, 1
    if not search:
        return INFEASIBLE, n0, n1, lam, 1
    lam_star, w0, w1 = smallest_lambda(A, b, S, s, verts, radius, Ak, bk)
    floor = max(lam, lam_star)
    used = floor + lambda_margin(floor, A, b, radius, margin_rel)
    for j in range(m):
        rhs[j] = b[j] + used
    feasible, v0, v1 = solve_rows(n0, n1, A, rhs, S, s, radius, G, h)
    if feasible:
        return SEARCHED, v0, v1, used, 3
    return SEARCH_VERTEX, w0, w1, floor, 3


@jit
def clip(
    verts: np.ndarray, n: int, g0: float, g1: float, hh: float, out: np.ndarray, tol: float
) -> int:
    """The convex polygon ``verts[:n]`` cut by the half-plane ``g v <= hh`` (Sutherland-Hodgman),
    written to ``out``; returns its number of vertices (0: empty). A vertex within ``tol``
    of the line counts as inside; ``out`` has room for ``n + 1`` vertices."""
    k = 0
    for i in range(n):
        p0 = verts[i, 0]
        p1 = verts[i, 1]
        j = i + 1 if i + 1 < n else 0
        q0 = verts[j, 0]
        q1 = verts[j, 1]
        fp = g0 * p0 + g1 * p1 - hh
        fq = g0 * q0 + g1 * q1 - hh
        if fp <= tol:
            out[k, 0] = p0
            out[k, 1] = p1
            k += 1
        if (fp < -tol and fq > tol) or (fp > tol and fq < -tol):
            t = fp / (fp - fq)
            out[k, 0] = p0 + t * (q0 - p0)
            out[k, 1] = p1 + t * (q1 - p1)
            k += 1
    return k


@jit
def polygon_area(verts: np.ndarray, n: int) -> float:
    """Area of the polygon ``verts[:n]`` (shoelace; vertices in order)."""
    area = 0.0
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        area += verts[i, 0] * verts[j, 1] - verts[j, 0] * verts[i, 1]
    return 0.5 * abs(area)


@jit
def escape_polygon(
    U: np.ndarray,
    c: np.ndarray,
    push: np.ndarray,
    k: int,
    S: np.ndarray,
    s: np.ndarray,
    verts: np.ndarray,
    radius: float,
    ES: np.ndarray,
    es: np.ndarray,
    ev: np.ndarray,
    ev2: np.ndarray,
    cb: np.ndarray,
) -> tuple[int, int, int, float, float]:
    """The admissible set of the edge rule for ``k`` agents within the collision distance.

    Agent ``j`` is seen from the robot along the unit vector ``U[j]`` (from the agent to
    the robot); ``c[j] = -U[j] . v_j`` with ``v_j`` its (predicted) velocity, so the
    distance to it grows at ``U[j] . v + c[j]`` for the command ``v``. The escape polygon
    is the speed set ``S v <= s`` (vertices ``verts``) cut by

    * the non-closing rows ``U[j] v + c[j] >= 0`` (no command closes in on an overlapping
      agent), and
    * the push rows ``U[j] v + c[j] - push[j] + sigma >= 0`` (move out at ``push[j]``,
      e.g. ``a (d_c - d_j)``), with ``sigma`` the smallest relaxation (>= 0, shared by the
      push rows only) at which they can be met, loosened by :data:`ESCAPE_WIDTH` times the
      radius when it binds (so the polygon is no sliver).

    Returns ``(mode, sides, vertices, v_x, v_y)``: :data:`ESCAPE_POLYGON` with the polygon's
    sides in ``ES[:sides]``, ``es[:sides]`` (unit normals, ``ES v <= es``: the speed set's
    first, then the rows) and its vertices in ``ev[:vertices]``; :data:`ESCAPE_MINIMAX`
    when no command of the speed set is non-closing for every such agent, with ``(v_x,
    v_y)`` the one minimising the largest closing speed (the min-lambda LP on the
    non-closing rows); :data:`ESCAPE_DEGENERATE` when the polygon has (nearly) no area
    (agents on opposite sides): the caller projects its nominal onto ``ES[:sides]``.
    ``ev`` has room for ``len(verts) + 2 k`` vertices, ``ev2`` (scratch) for twice as
    many, ``ES`` and ``es`` for ``len(S) + 2 k`` sides, ``cb`` for ``k`` numbers.
    """
    ns = S.shape[0]
    nv = verts.shape[0]
    half = ev2.shape[0] // 2
    P = ev2[:half]
    Q = ev2[half:]
    tol = REL_TOL * radius
    for i in range(ns):
        ES[i, 0] = S[i, 0]
        ES[i, 1] = S[i, 1]
        es[i] = s[i]
    for i in range(nv):
        ev[i, 0] = verts[i, 0]
        ev[i, 1] = verts[i, 1]
    nsq = ns
    for j in range(k):
        nv = clip(ev, nv, -U[j, 0], -U[j, 1], c[j], P, tol)
        for i in range(nv):
            ev[i, 0] = P[i, 0]
            ev[i, 1] = P[i, 1]
        ES[nsq, 0] = -U[j, 0]
        ES[nsq, 1] = -U[j, 1]
        es[nsq] = c[j]
        nsq += 1
        if nv == 0:
            break
    if nv == 0:
        _, v0, v1 = min_lambda(U, c, k, S, s, verts, radius, tol)
        return ESCAPE_MINIMAX, nsq, 0, v0, v1
    pushing = False
    for j in range(k):
        cb[j] = c[j] - push[j]
        if push[j] > 0.0:
            pushing = True
    if pushing:
        sig = min_lambda(U, cb, k, ES[:nsq], es[:nsq], ev[:nv], radius, tol)[0]
        sig = max(sig + ESCAPE_WIDTH * radius, 0.0)
        mv = nv
        for i in range(nv):
            P[i, 0] = ev[i, 0]
            P[i, 1] = ev[i, 1]
        for j in range(k):
            mv = clip(P, mv, -U[j, 0], -U[j, 1], cb[j] + sig, Q, tol)
            for i in range(mv):
                P[i, 0] = Q[i, 0]
                P[i, 1] = Q[i, 1]
            if mv == 0:
                break
        if mv > 0:  # (empty only by round-off: then the non-closing polygon stands)
            nv = mv
            for i in range(nv):
                ev[i, 0] = P[i, 0]
                ev[i, 1] = P[i, 1]
            for j in range(k):
                ES[nsq, 0] = -U[j, 0]
                ES[nsq, 1] = -U[j, 1]
                es[nsq] = cb[j] + sig
                nsq += 1
    if nv < 3 or polygon_area(ev, nv) <= ESCAPE_AREA * radius * radius:
        return ESCAPE_DEGENERATE, nsq, nv, 0.0, 0.0
    return ESCAPE_POLYGON, nsq, nv, 0.0, 0.0


@jit
def escape_rows(
    x0: float,
    x1: float,
    xp: np.ndarray,
    vp: np.ndarray,
    d_edge: float,
    gain: float,
    margin: float,
    idx: np.ndarray,
    U: np.ndarray,
    c: np.ndarray,
    push: np.ndarray,
) -> tuple[int, int]:
    """The agents at ``xp`` (velocities ``vp``) closer than ``d_edge`` (centre distance) to
    the robot at ``(x0, x1)``: returns ``(n, k)``, their number ``n`` (indices in
    ``idx[:n]``) and the number ``k`` of rows of :func:`escape_polygon` written to ``U``,
    ``c``, ``push``: the unit vector from the agent to the robot, ``c = -U . v`` and
    ``push = gain (d_edge + margin - d)``, for each of them but an agent at the robot's very
    position (there is no direction to keep away from: every motion leaves it)."""
    n = 0
    k = 0
    for j in range(xp.shape[0]):
        dx0 = x0 - xp[j, 0]
        dx1 = x1 - xp[j, 1]
        d = c_hypot(dx0, dx1)
        if not d < d_edge:
            continue
        idx[n] = j
        n += 1
        if d > 0.0:
            u0 = dx0 / d
            u1 = dx1 / d
            U[k, 0] = u0
            U[k, 1] = u1
            c[k] = -(u0 * vp[j, 0] + u1 * vp[j, 1])
            push[k] = gain * (d_edge + margin - d)
            k += 1
    return n, k


#: Layout of the parameter vector of :func:`apf_step`.
#: ``edge``: the collision distance of the edge rule (m, centre to centre; negative: the
#: rule is off, the paper's rows; the rule applies within the larger of it and ``d_c``),
#: ``edge_gain`` its push gain (1/s) and ``edge_margin`` the distance beyond it the push
#: aims at (m), see :func:`edge_prepare`.
PARAMS = ("K_rep", "rho0", "d_c", "delta", "surface", "a", "radius", "box", "v_max", "search",
          "margin", "capacity", "edge", "edge_gain", "edge_margin")  # fmt: skip

#: Header of the edge rule's region of the work vector: agents within the collision
#: distance, escape rows, mode of :func:`escape_polygon` (-1: no agent within it), its
#: sides and vertices.
EDGE_HEAD = 8


def edge_size(capacity: int, sides: int) -> int:
    """Length of the edge rule's region of the work vector (:func:`edge_views`)."""
    return EDGE_HEAD + 33 * capacity + 12 * sides


def work_size(capacity: int, sides: int) -> int:
    """Length of the work vector of :func:`apf_step` for up to ``capacity`` agents."""
    return 10 * capacity + 3 * sides + edge_size(capacity, sides)


@jit
def edge_views(
    region: np.ndarray, cap: int, ns: int
) -> tuple[
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
    np.ndarray,
]:
    """The edge rule's arrays in its region of the work vector (:func:`edge_size` long):
    the agents' indices, ``U``, ``c``, ``push``, ``cb``, the escape polygon's sides ``ES``,
    ``es``, vertices ``ev``, the scratch ``ev2``, the projection's ``G``, ``h``, and the
    header (:data:`EDGE_HEAD`)."""
    r = ns + 2 * cap
    o = EDGE_HEAD
    idx = region[o : o + cap]
    o += cap
    U = region[o : o + 2 * cap].reshape((cap, 2))
    o += 2 * cap
    c = region[o : o + cap]
    o += cap
    push = region[o : o + cap]
    o += cap
    cb = region[o : o + cap]
    o += cap
    ES = region[o : o + 2 * r].reshape((r, 2))
    o += 2 * r
    es = region[o : o + r]
    o += r
    ev = region[o : o + 2 * r].reshape((r, 2))
    o += 2 * r
    ev2 = region[o : o + 4 * r].reshape((2 * r, 2))
    o += 4 * r
    g = 3 * cap + ns
    G = region[o : o + 2 * g].reshape((g, 2))
    o += 2 * g
    h = region[o : o + g]
    return idx, U, c, push, cb, ES, es, ev, ev2, G, h, region[:EDGE_HEAD]


@jit
def edge_prepare(
    x0: float,
    x1: float,
    xp: np.ndarray,
    vp: np.ndarray,
    d_edge: float,
    gain: float,
    margin: float,
    lam: float,
    A: np.ndarray,
    b: np.ndarray,
    S: np.ndarray,
    s: np.ndarray,
    verts: np.ndarray,
    radius: float,
    region: np.ndarray,
    cap: int,
) -> tuple[int, int, int, float, float]:
    """The edge rule on the rows ``A v + b + lambda >= 0`` of the agents at ``xp``.

    The rows of the agents closer than ``d_edge`` are neutralised (``A_j = 0``, ``b_j =
    -lam``: met at every lambda >= ``lam``, so they never raise the lambda the other rows
    share) and their escape rows (:func:`escape_rows`, push gain ``gain``, aimed
    ``margin`` beyond ``d_edge``) give the escape
    polygon (:func:`escape_polygon`) in ``region`` (:func:`edge_views`); returns its
    ``(mode, sides, vertices, v_x, v_y)``, mode -1 when no agent is that close (the header
    records it, so a later :func:`escape_guard` knows).
    """
    ns = S.shape[0]
    idx, U, c, push, cb, ES, es, ev, ev2 = edge_views(region, cap, ns)[:9]
    head = region[:EDGE_HEAD]
    head[2] = -1.0
    n = 0
    k = 0
    if d_edge >= 0.0:
        n, k = escape_rows(x0, x1, xp, vp, d_edge, gain, margin, idx, U, c, push)
    head[0] = n
    head[1] = k
    if n == 0:
        return -1, ns, 0, 0.0, 0.0
    for q in range(n):
        j = int(idx[q])
        A[j, 0] = 0.0
        A[j, 1] = 0.0
        b[j] = -lam
    if k == 0:  # only agents at the robot's very position: no direction to keep away from
        head[2] = -1.0
        return -1, ns, 0, 0.0, 0.0
    mode, nsq, nvq, v0, v1 = escape_polygon(U, c, push, k, S, s, verts, radius, ES, es, ev, ev2, cb)
    head[2] = mode
    head[3] = nsq
    head[4] = nvq
    head[5] = ns
    return mode, nsq, nvq, v0, v1


@jit
def meets_sides(v0: float, v1: float, G: np.ndarray, h: np.ndarray, lo: int, hi: int) -> bool:
    """Whether ``G[lo:hi] v <= h[lo:hi]`` holds (to the exact solvers' tolerance)."""
    for i in range(lo, hi):
        if G[i, 0] * v0 + G[i, 1] * v1 - h[i] > REL_TOL * max(1.0, abs(h[i])):
            return False
    return True


@jit
def escape_guard(
    v0: float, v1: float, region: np.ndarray, cap: int, radius: float
) -> tuple[bool, float, float]:
    """A decision taken without the edge rule (``brake``, ``hold``, a fallback's) made to
    respect the escape polygon :func:`edge_prepare` left in ``region``: ``(changed, v_x,
    v_y)``, the decision projected onto the polygon when it violates one of its rows."""
    head = region[:EDGE_HEAD]
    if head[2] != ESCAPE_POLYGON and head[2] != ESCAPE_DEGENERATE:
        return False, v0, v1
    ns = int(head[5])
    nsq = int(head[3])
    ES, es, _, _, G, h = edge_views(region, cap, ns)[5:11]
    if meets_sides(v0, v1, ES, es, ns, nsq):
        return False, v0, v1
    for i in range(nsq):
        G[i, 0] = ES[i, 0]
        G[i, 1] = ES[i, 1]
        h[i] = es[i]
    _, w0, w1 = project(v0, v1, G, h, nsq, REL_TOL * radius)
    return True, w0, w1


@jit
def apf_step(
    x0: float,
    x1: float,
    xp: np.ndarray,
    vp: np.ndarray,
    n0: float,
    n1: float,
    lam: float,
    prm: np.ndarray,
    poly: np.ndarray,
    work: np.ndarray,
    off: np.ndarray,
) -> tuple[int, float, float, float, int]:
    """The fused control step for the APF barrier: rows, then :func:`filter_step`.

    Few arguments (the call overhead grows with them) and contiguous views (so the callees
    are the very functions the generic path compiled): ``prm`` holds the scalars named in
    :data:`PARAMS`; ``poly`` the speed polygon, flat: ``S`` (sides x 2), ``s``, vertices
    (sides x 2); ``work`` the buffers, flat (:func:`work_size`): A (capacity x 2), b, rhs,
    Ak (capacity x 2), bk, G (capacity + sides, 2), h, then the edge rule's region
    (:func:`edge_views`). The rows are left in A and b (those of the agents within the
    edge rule's distance ``prm`` ``edge`` neutralised, :func:`edge_prepare`); the step is
    taken within the escape polygon when one applies (:func:`edge_step`).

    ``off`` is empty (one lambda for every row), or holds one offset per agent added to
    its row's ``b`` (lambda run per agent: row j's slack is ``lam + off[j]``, ``lam`` the
    smallest entry, so the lambda search raises every row alike). The offsets are added
    before the edge rule neutralises its rows (``b_j = -lam``: met at every lambda >=
    ``lam``, whatever the agent's own lambda).
    """
    m = xp.shape[0]
    cap = int(prm[11])
    ns = poly.shape[0] // 5
    A = work[0 : 2 * m].reshape((m, 2))
    b = work[2 * cap : 2 * cap + m]
    rhs = work[3 * cap : 3 * cap + m]
    Ak = work[4 * cap : 4 * cap + 2 * m].reshape((m, 2))
    bk = work[6 * cap : 6 * cap + m]
    G = work[7 * cap : 9 * cap + 2 * ns].reshape((cap + ns, 2))
    h = work[9 * cap + 2 * ns : 10 * cap + 3 * ns]
    S = poly[0 : 2 * ns].reshape((ns, 2))
    s = poly[2 * ns : 3 * ns]
    verts = poly[3 * ns : 5 * ns].reshape((ns, 2))
    apf_rows(x0, x1, xp, vp, prm[0], prm[1], prm[2], prm[3], prm[4] != 0.0, prm[5], A, b)
    if off.shape[0]:
        for j in range(m):
            b[j] += off[j]
    region = work[10 * cap + 3 * ns :]
    region[2] = -1.0  # no escape polygon (read by escape_guard)
    mode = -1
    nsq = ns
    nvq = 0
    e0 = 0.0
    e1 = 0.0
    if prm[12] >= 0.0:  # (the barrier's own d_c when larger: it is flat within it)
        mode, nsq, nvq, e0, e1 = edge_prepare(
            x0, x1, xp, vp, max(prm[12], prm[2]), prm[13], prm[14], lam, A, b, S, s, verts,
            prm[6],
            region, cap,
        )  # fmt: skip
    if mode < 0:
        return filter_step(
            n0, n1, A, b, lam, S, s, verts, prm[6], prm[7] != 0.0, prm[8], prm[9] != 0.0,
            prm[10], G, h, rhs, Ak, bk,
        )  # fmt: skip
    return edge_step(n0, n1, A, b, lam, prm, mode, ns, nsq, nvq, e0, e1, region, cap, rhs, Ak, bk)


@jit
def edge_step(
    n0: float,
    n1: float,
    A: np.ndarray,
    b: np.ndarray,
    lam: float,
    prm: np.ndarray,
    mode: int,
    ns: int,
    nsq: int,
    nvq: int,
    e0: float,
    e1: float,
    region: np.ndarray,
    cap: int,
    rhs: np.ndarray,
    Ak: np.ndarray,
    bk: np.ndarray,
) -> tuple[int, float, float, float, int]:
    """:func:`filter_step` within the escape polygon :func:`edge_prepare` returned (``mode``,
    its sides and vertices, the minimax command ``(e0, e1)``): :data:`ESCAPED` with that
    command, or with the nominal projected onto a degenerate polygon (lambda applied NaN:
    the other rows may not hold), else the filter's step with the polygon as speed set (the
    nominal passes unchanged only if it meets the polygon's rows too)."""
    if mode == ESCAPE_MINIMAX:
        return ESCAPED, e0, e1, math.nan, 1
    ES, es, ev, _, G, h = edge_views(region, cap, ns)[5:11]
    radius = prm[6]
    if mode == ESCAPE_DEGENERATE:
        for i in range(nsq):
            G[i, 0] = ES[i, 0]
            G[i, 1] = ES[i, 1]
            h[i] = es[i]
        _, v0, v1 = project(n0, n1, G, h, nsq, REL_TOL * radius)
        return ESCAPED, v0, v1, math.nan, 1
    # NaN: the nominal never passes unchanged (it leaves the escape polygon)
    v_max = prm[8] if meets_sides(n0, n1, ES, es, ns, nsq) else math.nan
    return filter_step(
        n0, n1, A, b, lam, ES[:nsq], es[:nsq], ev[:nvq], radius, prm[7] != 0.0, v_max,
        prm[9] != 0.0, prm[10], G, h, rhs, Ak, bk,
    )  # fmt: skip


#: Length of the header of :func:`apf_control`'s buffer: the parameters (:data:`PARAMS`),
#: the number of sides of the speed polygon and the last decision applied (x, y).
HEADER = len(PARAMS) + 3
#: Fields of the record :func:`apf_control` writes per control instant: ego position (2),
#: decision (2), lambda applied, result code.
RECORD_FIELDS = 6


@jit
def apf_control(
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
    off: np.ndarray,
) -> int:
    """:func:`apf_step` on step ``s`` of an interval's predictions, recorded: returns its code.

    ``pv`` (2, steps, agents, 2) holds the predicted positions ``pv[0]`` and velocities
    ``pv[1]``; ``buf`` the parameters, the speed polygon and the work vector, flat:
    :data:`HEADER` entries (:data:`PARAMS`, the number of sides, the last decision), then
    ``poly`` and ``work`` as :func:`apf_step` lays them out. ``rec`` is the interval's
    record, flat, in blocks of ``rows = rec.size // RECORD_FIELDS``: ego positions (rows x
    2), decisions (rows x 2), lambda applied, code. Row ``i`` gets the ego position and
    code, and, unless the step is infeasible for a Python fallback (:data:`INFEASIBLE`),
    the decision (copied to the last decision too) and the lambda applied. Nothing is
    written for :data:`NONFINITE`, :data:`TOO_MANY` (more agents than ``buf`` was laid out
    for) or :data:`OUT_OF_RANGE` (``s`` is not a step of ``pv``); the caller makes sure
    that ``i < rows``. ``off``: the per-agent offsets of :func:`apf_step` (empty: none).
    """
    cap = int(buf[11])
    if pv.shape[2] > cap:
        return TOO_MANY
    if s < 0 or s >= pv.shape[1]:
        return OUT_OF_RANGE
    ns = int(buf[HEADER - 3])
    o = HEADER + 5 * ns
    code, v0, v1, lam_used, _ = apf_step(
        x0, x1, pv[0, s], pv[1, s], n0, n1, lam, buf[: HEADER - 3], buf[HEADER:o], buf[o:],
        off,
    )  # fmt: skip
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
