"""The compiled ORCA half-planes and programs give the numpy functions' numbers bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.crowds import ORCAModel
from conformal_control.crowds.neighbors import neighbor_pairs
from conformal_control.crowds.orca import solve_orca_lp
from conformal_control.crowds.orca_compiled import orca_lines_compiled, solve_orca_lp_compiled


# the ORCA half-planes in vectorised numpy: the readable reference the compiled
# orca_lines_compiled is checked against (formerly ORCAModel.orca_lines, unused by the package)
def orca_lines(
    model: ORCAModel,
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
    kmax = int(model.max_neighbors)
    rows, cols, px, py = neighbor_pairs(pos, all_pos, model.neighbor_dist, kmax)
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
    share = np.where(cols < n, 0.5, float(model.other_responsibility))
    dist_sq = px * px + py * py
    r_sq = r * r
    collide = dist_sq <= r_sq
    # cut-off circle: of the time horizon, or of one time step when overlapping
    inv_t = np.where(collide, 1.0 / dt, 1.0 / model.time_horizon)
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


def _state(rng: np.random.Generator):
    n, e = int(rng.integers(1, 60)), int(rng.integers(0, 4))
    size = float(rng.choice([2.0, 6.0, 20.0]))  # 2 m: overlapping bodies, infeasible programs
    pos, vel = rng.uniform(0.0, size, (n, 2)), rng.normal(0.0, 1.0, (n, 2))
    other, other_vel = rng.uniform(0.0, size, (e, 2)), rng.normal(0.0, 1.0, (e, 2))
    if n > 2 and rng.random() < 0.3:
        pos[1] = pos[0]  # coincident pedestrians
    rad, other_rad = np.full(n, 0.3), np.full(e, 0.5)
    pref, vmax = rng.normal(0.0, 1.5, (n, 2)), rng.uniform(0.5, 2.0, n)
    return pos, vel, rad, pref, vmax, other, other_vel, other_rad


@pytest.mark.parametrize("seed", range(6))
def test_lines_and_programs_equal_the_numpy_functions(seed):
    rng = np.random.default_rng(seed)
    n_infeasible = 0
    for _ in range(50):
        pos, vel, rad, pref, vmax, other, other_vel, other_rad = _state(rng)
        model = ORCAModel(
            max_neighbors=int(rng.choice([1, 3, 10])),
            other_responsibility=float(rng.choice([1.0, 0.5])),
        )
        model.reset()
        dt = float(rng.choice([0.1, 1 / 120]))
        lines = orca_lines(model, pos, vel, rad, other, other_vel, other_rad, dt)
        all_pos = np.concatenate([pos, other])
        rows, cols, px, py = neighbor_pairs(pos, all_pos, model.neighbor_dist, model.max_neighbors)
        compiled = orca_lines_compiled(
            pos.shape[0], model.max_neighbors, rows, cols, px, py, vel,
            np.concatenate([vel, other_vel]), rad, np.concatenate([rad, other_rad]),
            model.other_responsibility, 1.0 / dt, 1.0 / model.time_horizon,
        )  # fmt: skip
        for a, b in zip(lines, compiled, strict=True):
            assert a.shape == b.shape
            np.testing.assert_array_equal(a, b)
        v, feasible = solve_orca_lp(*lines, pref, vmax)
        v2, feasible2 = solve_orca_lp_compiled(*lines, pref, vmax)
        np.testing.assert_array_equal(v, v2)
        np.testing.assert_array_equal(feasible, feasible2)
        n_infeasible += int((~feasible).sum())
        # the step is the numpy composition (orca_lines, then solve_orca_lp)
        p, v3 = model.step(pos, vel, rad, pref, vmax, other, other_vel, other_rad, dt)
        np.testing.assert_array_equal(v3, v)
        np.testing.assert_array_equal(p, pos + dt * v)
    assert n_infeasible > 0  # the "safest velocity" programs were compared too
