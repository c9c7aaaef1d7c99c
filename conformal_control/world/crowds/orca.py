"""Optimal reciprocal collision avoidance (ORCA), van den Berg, Guy, Lin & Manocha (2011).

"Reciprocal n-body collision avoidance", Robotics Research (ISRR 2009), Springer STAR
70, pp. 3-19; reference implementation: the RVO2 library. At every step each simulated
pedestrian ``i`` takes its ``max_neighbors`` nearest agents within ``neighbor_dist``; for
each neighbour ``j`` the velocity obstacle of ``j`` over the time horizon (a truncated
cone in relative-velocity space) gives the smallest change ``u`` of the relative
velocity that leaves it, and the half-plane

    ORCA_ij = { v : (v - (v_i + r_ij u)) . n >= 0 },   n = outward normal of the cone at u,

where ``r_ij`` is the share of the avoidance ``i`` takes. The new velocity is the point
of the intersection of these half-planes and of the disc ``|v| <= v_max`` closest to the
preferred velocity; if the intersection is empty, the point of the disc that minimises
the largest violation (the paper's "safest" velocity, section 5.2). Overlapping agents
use the cut-off circle of one time step, as RVO2 does. Positions then move by
``v dt``.

Reciprocity. Two pedestrians both running ORCA each take half (``r_ij = 1/2``, the
paper's reciprocity). The robot is driven by our controller and the replayed pedestrians
of mixed mode by the recording: neither runs ORCA, so a pedestrian takes the whole
avoidance towards them (``other_responsibility = 1``, the velocity obstacle of a
non-reciprocating agent). ``other_responsibility = 0.5`` gives RVO2's behaviour, which
treats every agent as reciprocating.

Parameters (ORCA has no universal values; the defaults are the ones used for simulated
pedestrians in the CrowdNav benchmark, Chen et al. 2019, with RVO2):

========================= ======== ====================================================
``time_horizon``          5 s      horizon of the velocity obstacles (RVO2 ``timeHorizon``)
``neighbor_dist``         10 m     neighbours considered (RVO2 ``neighborDist``)
``max_neighbors``         10       at most that many, the nearest (``maxNeighbors``)
``other_responsibility``  1.0      share of the avoidance towards non-ORCA agents
========================= ======== ====================================================

Body radii and speed bounds come per agent from the caller
(:class:`~conformal_control.world.crowds.crowd.Crowd`).

Why not ``pyrvo`` (PyPI 0.4.3, pybind11 bindings to RVO2, Apache-2.0, the package this
module was evaluated against and is tested against): (i) RVO2 hard-codes the reciprocal
share 1/2 for every agent, so a pedestrian assumes the robot will do half the avoiding,
which it does not (the robot neither sees nor obeys the model): there is no way to add
an externally driven agent, and the pedestrians under-react to the robot (a test shows
the share 1/2 leaves a pedestrian on a collision course with a standing robot); (ii) it
cannot remove an agent (pedestrians enter and leave the scene) and computes in single
precision; (iii) it pulls in a robot simulator (``ir-sim``, with shapely and loguru).
Speed is not a reason: synchronising 101 agents one call at a time plus ``do_step``
costs about 1.5 ms of CPU per step for 100 pedestrians on this machine, and this module
about 0.1 ms (``do_step`` alone: 0.34 ms); ``benchmarks/bench_crowds.py`` prints the
figures and the ratios.
This module solves the same linear programs exactly, vectorised over the pedestrians (and,
in :meth:`ORCAModel.step`, compiled per pedestrian with the same arithmetic:
:mod:`~conformal_control.world.crowds.orca_compiled`): a 2-D program's optimum is one of a few
candidate points (the preferred velocity clipped
to the disc, its projection on each line clipped to the disc, the intersection of each
pair of lines), so all candidates are formed at once and the closest feasible one is
kept; the same enumeration (lines, pairs on the circle, triples of equal violation)
solves the "safest velocity" program. ``tests/world/crowds/test_orca.py`` checks a step
against RVO2 on reciprocal agents.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .base import CrowdModel
from .neighbors import neighbor_pairs
from .orca_compiled import orca_lines_compiled, solve_orca_lp_compiled

__all__ = ["ORCAModel", "solve_orca_lp"]

_TOL = 1e-9  # m/s: a candidate within this of a line counts as on its feasible side
_EPS = 1e-9  # determinants below this: (almost) parallel lines


class ORCAModel(CrowdModel):
    """ORCA (van den Berg et al. 2011) for pedestrians among non-reciprocating agents, in numpy.

    Parameters
    ----------
    time_horizon : float
        Horizon (s) of the velocity obstacles.
    neighbor_dist : float
        Only agents closer than this (m, centre distance) are considered.
    max_neighbors : int
        At most this many (the nearest) are considered.
    other_responsibility : float
        Share of the avoidance a pedestrian takes towards agents that do not run ORCA (the
        robot, replayed pedestrians), in (0, 1]; 0.5 treats them as reciprocating (RVO2).
    """

    def __init__(
        self,
        time_horizon: float = 5.0,
        neighbor_dist: float = 10.0,
        max_neighbors: int = 10,
        other_responsibility: float = 1.0,
    ) -> None:
        self.time_horizon = time_horizon
        self.neighbor_dist = neighbor_dist
        self.max_neighbors = max_neighbors
        self.other_responsibility = other_responsibility

    def _validate(self) -> None:
        self._check_positive(
            time_horizon=self.time_horizon,
            neighbor_dist=self.neighbor_dist,
            other_responsibility=self.other_responsibility,
        )
        if self.other_responsibility > 1:
            raise ValueError(
                f"other_responsibility must be in (0, 1], got {self.other_responsibility!r}"
            )
        k = self.max_neighbors
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 0:
            raise ValueError(f"max_neighbors must be an integer >= 0, got {k!r}")

    def orca_lines(
        self,
        pos: np.ndarray,
        vel: np.ndarray,
        radius: np.ndarray,
        other_pos: np.ndarray,
        other_vel: np.ndarray,
        other_radius: np.ndarray,
        dt: float,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The ORCA half-planes of each simulated pedestrian.

        Returns ``point`` and ``direction`` of shape (N, K, 2) and ``valid`` (N, K) (rows
        with fewer neighbours are padded with invalid lines). The permitted side of line
        ``k`` is to the left of ``direction`` (RVO2's convention:
        ``det(direction, point - v) <= 0``).

        Parameters
        ----------
        pos, vel : ndarray of shape (N, 2)
            The simulated pedestrians' positions (m) and velocities (m/s).
        radius : ndarray of shape (N,)
            Their radii (m).
        other_pos, other_vel : ndarray of shape (O, 2)
            The other agents' positions (m) and velocities (m/s): replayed pedestrians,
            the robot; each takes ``other_responsibility`` of avoiding a pair, simulated
            pedestrians half.
        other_radius : ndarray of shape (O,)
            Their radii (m).
        dt : float
            The simulation step (s): the cut-off time of a pair that already overlaps.
        """
        n = pos.shape[0]
        all_pos = np.concatenate([pos, other_pos])
        all_vel = np.concatenate([vel, other_vel])
        all_rad = np.concatenate([radius, other_radius])
        kmax = int(self.max_neighbors)
        rows, cols, px, py = neighbor_pairs(pos, all_pos, self.neighbor_dist, kmax)
        # slot of each pair within its row; ties at the cut beyond max_neighbors dropped
        start = np.searchsorted(rows, np.arange(n))
        slot = np.arange(rows.size) - start[rows]
        keep = slot < kmax
        if not keep.all():
            rows, cols, px, py, slot = rows[keep], cols[keep], px[keep], py[keep], slot[keep]
        k = int(slot.max()) + 1 if slot.size else 0
        point = np.zeros((n, k, 2))
        direction = np.zeros((n, k, 2))
        direction[..., 0] = 1.0
        valid = np.zeros((n, k), dtype=bool)
        if not rows.size:
            return point, direction, valid
        vix, viy = vel[rows, 0], vel[rows, 1]
        rvx = vix - all_vel[cols, 0]  # relative velocity v_i - v_j
        rvy = viy - all_vel[cols, 1]
        r = radius[rows] + all_rad[cols]
        share = np.where(cols < n, 0.5, float(self.other_responsibility))
        dist_sq = px * px + py * py
        r_sq = r * r
        collide = dist_sq <= r_sq
        # cut-off circle: of the time horizon, or of one time step when overlapping
        inv_t = np.where(collide, 1.0 / dt, 1.0 / self.time_horizon)
        wx, wy = rvx - inv_t * px, rvy - inv_t * py
        w_sq = wx * wx + wy * wy
        dot = wx * px + wy * py
        on_circle = collide | ((dot < 0) & (dot * dot > r_sq * w_sq))
        w_len = np.sqrt(w_sq)
        ok = ~on_circle | (w_len > 0)
        inv_w = np.divide(1.0, w_len, out=np.zeros_like(w_len), where=w_len > 0)
        uwx, uwy = wx * inv_w, wy * inv_w
        # legs (where not on the circle)
        leg = np.sqrt(np.maximum(dist_sq - r_sq, 0.0))
        inv_d = np.divide(1.0, dist_sq, out=np.zeros_like(dist_sq), where=dist_sq > 0)
        side = np.where((px * wy - py * wx) > 0, 1.0, -1.0)  # left leg: +1, right leg: -1
        ldx = (px * leg - side * py * r) * inv_d * side
        ldy = (side * px * r + py * leg) * inv_d * side
        proj = rvx * ldx + rvy * ldy
        c_mag = r * inv_t - w_len
        dx_ = np.where(on_circle, uwy, ldx)
        dy_ = np.where(on_circle, -uwx, ldy)
        ux = np.where(on_circle, c_mag * uwx, proj * ldx - rvx)
        uy = np.where(on_circle, c_mag * uwy, proj * ldy - rvy)
        rows, slot = rows[ok], slot[ok]
        point[rows, slot, 0] = (vix + share * ux)[ok]
        point[rows, slot, 1] = (viy + share * uy)[ok]
        direction[rows, slot, 0] = dx_[ok]
        direction[rows, slot, 1] = dy_[ok]
        valid[rows, slot] = True
        return point, direction, valid

    def step(
        self,
        pos: np.ndarray,
        vel: np.ndarray,
        radius: np.ndarray,
        v_pref: np.ndarray,
        v_max: np.ndarray,
        other_pos: np.ndarray,
        other_vel: np.ndarray,
        other_radius: np.ndarray,
        dt: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        if pos.shape[0] == 0:
            return pos.copy(), vel.copy()
        # orca_lines and solve_orca_lp, compiled per pedestrian (the same numbers, bit for
        # bit; most of a step of a hundred pedestrians was numpy's per-call overhead)
        n = pos.shape[0]
        f64 = np.float64
        vel = np.ascontiguousarray(vel, dtype=f64)
        all_pos = np.concatenate([pos, other_pos]).astype(f64, copy=False)
        all_vel = np.ascontiguousarray(np.concatenate([vel, other_vel]), dtype=f64)
        radius = np.ascontiguousarray(radius, dtype=f64)
        all_rad = np.ascontiguousarray(np.concatenate([radius, other_radius]), dtype=f64)
        kmax = int(self.max_neighbors)
        rows, cols, px, py = neighbor_pairs(pos, all_pos, self.neighbor_dist, kmax)
        point, direction, valid = orca_lines_compiled(
            n, kmax, rows, cols, px, py, vel, all_vel, radius, all_rad,
            float(self.other_responsibility), 1.0 / dt, 1.0 / self.time_horizon,
        )  # fmt: skip
        v, _ = solve_orca_lp_compiled(
            point,
            direction,
            valid,
            np.ascontiguousarray(v_pref, dtype=f64),
            np.ascontiguousarray(v_max, dtype=f64),
        )
        return pos + dt * v, v


# ------------------------------------------------------------------------------ programs
@lru_cache(maxsize=64)
def _pairs(k: int) -> tuple[np.ndarray, np.ndarray]:
    return np.triu_indices(k, 1)


@lru_cache(maxsize=64)
def _triples(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    i, j, m = (x.ravel() for x in np.meshgrid(*(np.arange(k),) * 3, indexing="ij"))
    keep = (i < j) & (j < m)
    return i[keep], j[keep], m[keep]


def _violation(alpha: np.ndarray, beta: np.ndarray, cand: np.ndarray) -> np.ndarray:
    """det(d_k, p_k - c) = alpha_k + beta_k . c for candidates (N, C, 2): (N, C, K)."""
    det: np.ndarray = (
        alpha[:, None, :]
        + cand[..., 0:1] * beta[:, None, :, 0]
        + cand[..., 1:2] * beta[:, None, :, 1]
    )
    return det


def solve_orca_lp(
    point: np.ndarray,
    direction: np.ndarray,
    valid: np.ndarray,
    v_pref: np.ndarray,
    v_max: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Solve each agent's ORCA program exactly, vectorised over agents.

    Minimise ``|v - v_pref|`` subject to ``det(direction_k, point_k - v) <= 0`` for the
    valid lines and ``|v| <= v_max``; where no velocity satisfies every line, minimise the
    largest violation ``max_k det(direction_k, point_k - v)`` over the disc instead.

    Parameters
    ----------
    point, direction : ndarray of shape (N, K, 2)
        Lines (``direction`` of unit length).
    valid : ndarray of shape (N, K)
    v_pref : ndarray of shape (N, 2)
    v_max : ndarray of shape (N,)

    Returns
    -------
    v : ndarray of shape (N, 2)
    feasible : ndarray of shape (N,)
        False where the program was infeasible (the safest velocity was taken).
    """
    n, k = valid.shape
    vmax = np.asarray(v_max, dtype=float)
    sp = np.hypot(v_pref[:, 0], v_pref[:, 1])
    scale = np.where(sp > vmax, vmax / np.where(sp > 0, sp, 1.0), 1.0)
    v = v_pref * scale[:, None]  # the preferred velocity clipped to the disc
    feasible = np.ones(n, dtype=bool)
    if k == 0 or n == 0:
        return v, feasible
    alpha = direction[..., 0] * point[..., 1] - direction[..., 1] * point[..., 0]
    alpha = np.where(valid, alpha, 0.0)
    beta = np.stack([direction[..., 1], -direction[..., 0]], axis=-1)
    beta[~valid] = 0.0
    violated = (alpha + v[:, 0:1] * beta[..., 0] + v[:, 1:2] * beta[..., 1] > _TOL) & valid
    need = np.flatnonzero(violated.any(axis=1))
    if need.size == 0:
        return v, feasible
    v_sub, ok_sub = _closest(
        point[need], direction[need], valid[need], alpha[need], beta[need],
        v_pref[need], vmax[need], violated[need],
    )  # fmt: skip
    v[need] = v_sub
    feasible[need] = ok_sub
    if not ok_sub.all():
        bad = need[~ok_sub]
        v[bad] = _safest(alpha[bad], beta[bad], valid[bad], vmax[bad])
    return v, feasible


def _closest(
    point: np.ndarray,
    direction: np.ndarray,
    valid: np.ndarray,
    alpha: np.ndarray,
    beta: np.ndarray,
    v_pref: np.ndarray,
    vmax: np.ndarray,
    violated: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Closest point to v_pref of the lines' half-planes and the disc, by enumeration.

    Called where the clipped preferred velocity violates the lines ``violated``. The
    optimum then lies on a line, and (from the optimality conditions) at least one of
    the lines it lies on is violated: it is the projection of v_pref on a violated line
    (clipped to the disc along it) or the intersection of a violated line with another.
    """
    n, k = valid.shape
    # projections on the violated lines
    r1, k1 = np.nonzero(violated)
    p1, d1 = point[r1, k1], direction[r1, k1]
    pd = np.einsum("ij,ij->i", p1, d1)
    disc = pd * pd + vmax[r1] ** 2 - np.einsum("ij,ij->i", p1, p1)
    root = np.sqrt(np.maximum(disc, 0.0))
    t = np.clip(np.einsum("ij,ij->i", v_pref[r1] - p1, d1), -pd - root, -pd + root)
    c1 = p1 + t[:, None] * d1
    ok1 = disc >= 0
    # intersections of a violated line with another valid line
    a, b = _pairs(k)
    mask = valid[:, a] & valid[:, b] & (violated[:, a] | violated[:, b])
    r2, q = np.nonzero(mask)
    a, b = a[q], b[q]
    pa, da, db = point[r2, a], direction[r2, a], direction[r2, b]
    den = da[:, 0] * db[:, 1] - da[:, 1] * db[:, 0]
    diff = pa - point[r2, b]
    num = db[:, 0] * diff[:, 1] - db[:, 1] * diff[:, 0]
    ok2 = np.abs(den) > _EPS
    c2 = pa + np.divide(num, den, out=np.zeros_like(num), where=ok2)[:, None] * da
    rows = np.concatenate([r1, r2])
    cand = np.concatenate([c1, c2])
    ok = np.concatenate([ok1, ok2])
    viol = alpha[rows] + cand[:, 0:1] * beta[rows, :, 0] + cand[:, 1:2] * beta[rows, :, 1]
    ok &= ((viol <= _TOL) | ~valid[rows]).all(axis=1)
    ok &= np.einsum("ij,ij->i", cand, cand) <= (vmax[rows] + _TOL) ** 2
    cost = np.where(ok, np.sum((cand - v_pref[rows]) ** 2, axis=1), np.inf)
    order = np.lexsort((cost, rows))
    ro = rows[order]
    first = np.concatenate([[True], ro[1:] != ro[:-1]])
    pick = order[first]
    v = np.zeros((n, 2))
    found = np.zeros(n, dtype=bool)
    v[rows[pick]] = cand[pick]
    found[rows[pick]] = np.isfinite(cost[pick])
    return v, found


def _safest(alpha: np.ndarray, beta: np.ndarray, valid: np.ndarray, vmax: np.ndarray) -> np.ndarray:
    """argmin over |v| <= v_max of max_k (alpha_k + beta_k . v), by enumeration.

    ``alpha`` must be finite (0 on invalid lines, which are left out).

    The objective is convex and piecewise linear with unit-norm slopes, so its minimum
    over the disc is attained where one piece meets the circle (``-v_max beta_k``), where
    two equal pieces meet the circle, or where three pieces are equal inside the disc.
    """
    n, k = valid.shape
    r = vmax[:, None]
    cands = [-r[..., None] * beta]
    oks = [valid.copy()]
    if k > 1:
        a, b = _pairs(k)
        mx = beta[:, a, 0] - beta[:, b, 0]
        my = beta[:, a, 1] - beta[:, b, 1]
        rhs = alpha[:, b] - alpha[:, a]
        m_sq = mx * mx + my * my
        ok = valid[:, a] & valid[:, b] & (m_sq > _EPS)
        inv = np.divide(1.0, m_sq, out=np.zeros_like(m_sq), where=ok)
        h_sq = rhs * rhs * inv
        ok &= h_sq <= r * r
        s = np.sqrt(np.maximum(r * r - h_sq, 0.0) * inv)  # offset / |m|
        cx, cy = rhs * mx * inv, rhs * my * inv
        for sign in (1.0, -1.0):
            cands.append(np.stack([cx - sign * s * my, cy + sign * s * mx], axis=-1))
            oks.append(ok)
    if k > 2:
        i, j, m = _triples(k)
        a1x, a1y = beta[:, i, 0] - beta[:, j, 0], beta[:, i, 1] - beta[:, j, 1]
        a2x, a2y = beta[:, i, 0] - beta[:, m, 0], beta[:, i, 1] - beta[:, m, 1]
        b1, b2 = alpha[:, j] - alpha[:, i], alpha[:, m] - alpha[:, i]
        det = a1x * a2y - a1y * a2x
        ok = valid[:, i] & valid[:, j] & valid[:, m] & (np.abs(det) > _EPS)
        inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
        c = np.stack([(b1 * a2y - b2 * a1y) * inv, (a1x * b2 - a2x * b1) * inv], axis=-1)
        ok &= np.einsum("ncx,ncx->nc", c, c) <= (r + _TOL) ** 2
        cands.append(c)
        oks.append(ok)
    cand = np.concatenate(cands, axis=1)
    ok = np.concatenate(oks, axis=1)
    cand[~ok] = 0.0
    viol = _violation(alpha, beta, cand)
    worst = np.where(valid[:, None, :], viol, -np.inf).max(axis=2)
    worst = np.where(ok, worst, np.inf)
    best = np.argmin(worst, axis=1)
    v: np.ndarray = cand[np.arange(n), best]
    none = ~np.isfinite(worst[np.arange(n), best])
    v[none] = 0.0  # no valid line at all cannot be infeasible; kept for safety
    return v
