"""The compiled ORCA half-planes and programs give the numpy functions' numbers bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.world.crowds import ORCAModel
from conformal_control.world.crowds.neighbors import neighbor_pairs
from conformal_control.world.crowds.orca import solve_orca_lp
from conformal_control.world.crowds.orca_compiled import orca_lines_compiled, solve_orca_lp_compiled


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
        lines = model.orca_lines(pos, vel, rad, other, other_vel, other_rad, dt)
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
