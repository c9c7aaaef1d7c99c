"""Neighbour search of the crowd models: every pair of agents closer than a cut-off.

:func:`neighbor_pairs` bins the agents into square cells of (about) the cut-off distance,
sorted by cell, and tests only the agents of the 3 x 3 cells around each pedestrian: time
and memory proportional to the number of agents and of pairs found, where the dense
search (:func:`dense_neighbor_pairs`, every pedestrian against every agent) needs
``N x M`` of both (5,000 pedestrians: 1.25 GB and seconds per step). The result is the
dense search's, bit for bit and in the same order: the same pairs (a pair is in when its
squared distance, computed from the same coordinate differences, is below the squared
cut-off), rows sorted, columns sorted within a row, and the same cut to the nearest
``max_neighbors``. ``tests/world/crowds/test_neighbors.py`` checks this on random crowds,
including agents exactly at the cut-off.

Why by hand: ``scipy.spatial.cKDTree`` answers the same question, but its ball queries
test ``distance <= r`` with their own arithmetic (so a pair exactly at the cut-off may come
out differently from the models' ``d^2 < r^2``), return per-row Python lists (0.5-1 µs per
pedestrian to flatten) and a tree per step costs more than the sort below; the cell
search is a few dozen lines compiled with numba (``cache=True``, as the controller's
kernels: the first use on a machine compiles for about a second).

Cell size: ``r (1 + 1e-12) + 1e-14 S`` for a cut-off ``r`` and a span ``S`` of the
coordinates, so that two agents whose computed distance is below ``r`` are never two cells
apart, whatever the rounding of their cell coordinates (each is within ``2 eps S / c`` of
the exact quotient). Agents with a non-finite coordinate are in no pair (as in the dense
search, where ``NaN < r^2`` is false). An infinite cut-off (every agent is a neighbour),
or a span so large relative to the cut-off that cell keys would overflow 62 bits, takes
the dense search.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.jit import kernel

__all__ = ["cell_pairs", "dense_neighbor_pairs", "neighbor_pairs"]

jit = kernel(cache=True, nogil=True)

#: The pairs of a search: rows, cols (int64), dx, dy (float64), see :func:`neighbor_pairs`.
Pairs = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def dense_neighbor_pairs(
    pos: np.ndarray,
    all_pos: np.ndarray,
    max_dist: float,
    max_neighbors: int | None = None,
) -> Pairs:
    """:func:`neighbor_pairs` by the dense ``N x M`` distance matrix (the reference).

    Parameters
    ----------
    pos : ndarray of shape (N, 2)
        Positions (m) of the agents whose neighbours are wanted.
    all_pos : ndarray of shape (M, 2)
        Every agent, ``pos`` first (M >= N); non-finite positions are nobody's
        neighbour.
    max_dist : float
        Cut-off (m): a pair is in when its squared centre distance is below
        ``max_dist ** 2``.
    max_neighbors : int, optional
        Keep the nearest this many per row (ties at the cut may keep a few more; None:
        all).

    Returns
    -------
    rows, cols, dx, dy : ndarrays of shape (P,)
        The pairs (row-major order) and ``all_pos[cols] - pos[rows]`` (m).
    """
    n = pos.shape[0]
    dx = all_pos[None, :, 0] - pos[:, 0:1]
    dy = all_pos[None, :, 1] - pos[:, 1:2]
    with np.errstate(over="ignore", invalid="ignore"):  # inf or NaN: not a neighbour
        dsq = dx * dx + dy * dy
    diag = np.arange(n)
    dsq[diag, diag] = np.inf
    within = dsq < max_dist * max_dist
    k = max_neighbors
    if k is not None and all_pos.shape[0] - 1 > k:
        over = within.sum(axis=1) > k
        if over.any():
            if k == 0:
                within[over] = False
            else:
                sub = dsq[over]
                kth = np.partition(sub, k - 1, axis=1)[:, k - 1]
                within[over] &= sub <= kth[:, None]
    rows, cols = np.nonzero(within)
    return rows, cols, dx[rows, cols], dy[rows, cols]


def neighbor_pairs(
    pos: np.ndarray,
    all_pos: np.ndarray,
    max_dist: float,
    max_neighbors: int | None = None,
) -> Pairs:
    """Pairs (i, j) with agent ``j`` of ``all_pos`` closer than ``max_dist`` to ``pos[i]``.

    ``all_pos`` starts with ``pos`` itself (the pair (i, i) is left out). With
    ``max_neighbors``, a row keeps its nearest ``max_neighbors`` (ties at the cut may keep
    a few more; callers that need an exact bound cut by slot). Rows come out sorted, and
    the columns of a row sorted.

    Parameters
    ----------
    pos : ndarray of shape (N, 2)
        Positions (m) of the agents whose neighbours are wanted.
    all_pos : ndarray of shape (M, 2)
        Every agent, ``pos`` first (M >= N).
    max_dist : float
        Cut-off (m): a pair is in when its squared centre distance is below
        ``max_dist ** 2``; ``inf`` for every pair.
    max_neighbors : int, optional
        Keep the nearest this many per row.

    Returns
    -------
    rows, cols : ndarray of int, shape (P,)
    dx, dy : ndarray of shape (P,)
        ``all_pos[cols] - pos[rows]`` (m).
    """
    r = float(max_dist)
    if not math.isfinite(r) or pos.shape[0] == 0:
        return dense_neighbor_pairs(pos, all_pos, max_dist, max_neighbors)
    k = -1 if max_neighbors is None else int(max_neighbors)
    p = np.ascontiguousarray(pos, dtype=np.float64)
    a = np.ascontiguousarray(all_pos, dtype=np.float64)
    ok, rows, cols, dx, dy = cell_pairs(p, a, r, k)
    if not ok:  # cell keys would overflow: coordinates absurdly far apart for this cut-off
        return dense_neighbor_pairs(pos, all_pos, max_dist, max_neighbors)
    return rows, cols, dx, dy


#: Rows of at most this many pairs are sorted by insertion (no allocation).
_SMALL = 64


@jit
def _insertion_sort(key: np.ndarray, val: np.ndarray, c: int) -> None:
    """Sort ``key[:c]`` in place, carrying ``val[:c]`` along (``val`` may be ``key``)."""
    for q in range(1, c):
        kq, vq = key[q], val[q]
        u = q
        while u > 0 and key[u - 1] > kq:
            key[u] = key[u - 1]
            val[u] = val[u - 1]
            u -= 1
        key[u] = kq
        val[u] = vq


@jit
def cell_pairs(
    pos: np.ndarray, all_pos: np.ndarray, r: float, k: int
) -> tuple[bool, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`neighbor_pairs`'s cell search, compiled (for compiled callers): ``(ok, rows,
    cols, dx, dy)`` for a finite cut-off ``r`` and ``k`` nearest (-1: all); ``ok`` is
    False (and the pairs empty) where the cell keys would overflow (the caller then
    takes the dense search)."""
    n = pos.shape[0]
    m = all_pos.shape[0]
    r2 = r * r
    empty_i = np.zeros(0, dtype=np.int64)
    empty_f = np.zeros(0)
    # the finite agents and their span
    xmin = ymin = math.inf
    xmax = ymax = -math.inf
    for j in range(m):
        x, y = all_pos[j, 0], all_pos[j, 1]
        if math.isfinite(x) and math.isfinite(y):
            xmin, xmax = min(xmin, x), max(xmax, x)
            ymin, ymax = min(ymin, y), max(ymax, y)
    if xmin > xmax:  # no finite agent
        return True, empty_i, empty_i, empty_f, empty_f
    span = max(xmax - xmin, ymax - ymin)
    cell = r * (1.0 + 1e-12) + 1e-14 * span
    if not ((xmax - xmin) / cell < 2.0**30 and (ymax - ymin) / cell < 2.0**30):
        return False, empty_i, empty_i, empty_f, empty_f
    ny = np.int64((ymax - ymin) / cell) + 1
    # agents sorted by cell key cx * ny + cy (non-finite ones last, in no cell)
    key = np.full(m, np.iinfo(np.int64).max, dtype=np.int64)
    for j in range(m):
        x, y = all_pos[j, 0], all_pos[j, 1]
        if math.isfinite(x) and math.isfinite(y):
            key[j] = np.int64((x - xmin) / cell) * ny + np.int64((y - ymin) / cell)
    order = np.argsort(key, kind="mergesort")
    skey = key[order]
    sx = np.empty(m)
    sy = np.empty(m)
    for t in range(m):
        sx[t] = all_pos[order[t], 0]
        sy[t] = all_pos[order[t], 1]
    # each pedestrian's three runs of cells (cx - 1 .. cx + 1, cy - 1 .. cy + 1), sorted
    runs = np.zeros((n, 6), dtype=np.int64)
    for i in range(n):
        xi, yi = pos[i, 0], pos[i, 1]
        if not (math.isfinite(xi) and math.isfinite(yi)):
            continue
        cxi = np.int64((xi - xmin) / cell)
        cyi = np.int64((yi - ymin) / cell)
        for d in range(3):
            cx = cxi - 1 + d
            runs[i, 2 * d] = np.searchsorted(skey, cx * ny + max(cyi - 1, 0), side="left")
            runs[i, 2 * d + 1] = np.searchsorted(skey, cx * ny + min(cyi + 1, ny - 1), "right")
    # pass 1: pairs within the cut-off per pedestrian (an upper bound of the output); the
    # tests are branch-free (a third to a half of the candidates are in)
    total = 0
    for i in range(n):
        xi, yi = pos[i, 0], pos[i, 1]
        if not (math.isfinite(xi) and math.isfinite(yi)):
            continue  # in no cell: no run
        for d in range(3):
            for t in range(runs[i, 2 * d], runs[i, 2 * d + 1]):
                dx = sx[t] - xi
                dy = sy[t] - yi
                total += dx * dx + dy * dy < r2
        total -= 0.0 < r2  # the pedestrian itself, at distance 0
    rows = np.empty(total, dtype=np.int64)
    cols = np.empty(total, dtype=np.int64)
    out_dx = np.empty(total)
    out_dy = np.empty(total)
    # pass 2: each row's pairs, columns sorted, cut to the nearest k
    cand_j = np.empty(m + 1, dtype=np.int64)
    cand_d = np.empty(m + 1)
    scratch = np.empty(_SMALL)
    p = 0
    for i in range(n):
        xi, yi = pos[i, 0], pos[i, 1]
        c = 0
        for d in range(3):
            for t in range(runs[i, 2 * d], runs[i, 2 * d + 1]):
                dx = sx[t] - xi
                dy = sy[t] - yi
                dsq = dx * dx + dy * dy
                j = order[t]
                cand_j[c] = j
                cand_d[c] = dsq
                c += (dsq < r2) & (j != i)
        if c == 0 or k == 0:
            continue
        # columns in increasing order
        if c <= _SMALL:
            _insertion_sort(cand_j, cand_d, c)
        else:
            o = np.argsort(cand_j[:c], kind="mergesort")
            cand_j[:c] = cand_j[:c][o]
            cand_d[:c] = cand_d[:c][o]
        kth = math.inf
        if k > 0 and c > k:  # the k-th smallest squared distance of the row
            if c <= _SMALL:
                scratch[:c] = cand_d[:c]
                _insertion_sort(scratch, scratch, c)
                kth = scratch[k - 1]
            else:
                kth = np.partition(cand_d[:c], k - 1)[k - 1]
        for q in range(c):
            if cand_d[q] <= kth:
                j = cand_j[q]
                rows[p] = i
                cols[p] = j
                out_dx[p] = all_pos[j, 0] - xi
                out_dy[p] = all_pos[j, 1] - yi
                p += 1
    return True, rows[:p], cols[:p], out_dx[:p], out_dy[:p]
