"""ORCA: the exact linear programs, agreement with RVO2, responsibility towards the robot."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.world.crowds import ORCAModel
from conformal_control.world.crowds.neighbors import neighbor_pairs
from conformal_control.world.crowds.orca import solve_orca_lp
from conformal_control.world.crowds.orca_compiled import orca_lines_compiled

NONE2 = np.zeros((0, 2))


def _scene(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pos: list[np.ndarray] = []
    while len(pos) < n:
        p = rng.uniform(0.0, 12.0, 2)
        if all(np.hypot(*(p - q)) > 0.9 for q in pos):
            pos.append(p)
    return np.array(pos), rng.normal(0.0, 0.8, (n, 2)), rng.normal(0.0, 1.0, (n, 2))


def test_one_step_matches_rvo2_on_reciprocal_agents() -> None:
    try:
        import pyrvo  # the reference implementation (RVO2), in the 'crowds' extra
    except ImportError:
        pytest.fail("pyrvo is not installed: pip install -e '.[crowds]'", pytrace=False)
    rng = np.random.default_rng(1)
    dt, horizon, dist, k, radius, vmax = 0.1, 3.0, 6.0, 8, 0.35, 1.5
    model = ORCAModel(time_horizon=horizon, neighbor_dist=dist, max_neighbors=k)
    model.reset()
    n_infeasible = 0
    for _ in range(40):
        n = int(rng.integers(2, 30))
        pos, vel, pref = _scene(rng, n)
        sim = pyrvo.RVOSimulator()
        sim.set_time_step(dt)
        for i in range(n):
            sim.add_agent(tuple(pos[i]), dist, k, horizon, horizon, radius, vmax, tuple(vel[i]))
            sim.set_agent_pref_velocity(i, tuple(pref[i]))
        sim.do_step()
        v_rvo = np.array([sim.get_agent_velocity(i).to_tuple() for i in range(n)])
        p_rvo = np.array([sim.get_agent_position(i).to_tuple() for i in range(n)])
        rad = np.full(n, radius)
        rows, cols, px, py = neighbor_pairs(pos, pos, model.neighbor_dist, model.max_neighbors)
        lines = orca_lines_compiled(
            n, model.max_neighbors, rows, cols, px, py, vel, vel, rad, rad,
            model.other_responsibility, 1.0 / dt, 1.0 / model.time_horizon,
        )  # fmt: skip
        _, feasible = solve_orca_lp(*lines, pref, np.full(n, vmax))
        n_infeasible += int((~feasible).sum())
        p, v = model.step(
            pos, vel, np.full(n, radius), pref, np.full(n, vmax), NONE2, NONE2, np.zeros(0), dt
        )
        # RVO2 computes in single precision
        np.testing.assert_allclose(v, v_rvo, atol=1e-4)
        np.testing.assert_allclose(p, p_rvo, atol=1e-4)
    assert n_infeasible > 0  # the "safest velocity" program was exercised too


def test_lp_keeps_a_feasible_preference_and_projects_on_one_line() -> None:
    # one line x <= 0.5 (direction (0, 1): permitted side to its left, x smaller)
    point = np.array([[[0.5, 0.0]]])
    direction = np.array([[[0.0, 1.0]]])
    valid = np.ones((1, 1), dtype=bool)
    v, ok = solve_orca_lp(point, direction, valid, np.array([[0.2, 0.3]]), np.array([2.0]))
    assert ok[0] and v[0] == pytest.approx([0.2, 0.3])
    v, ok = solve_orca_lp(point, direction, valid, np.array([[1.5, 0.3]]), np.array([2.0]))
    assert ok[0] and v[0] == pytest.approx([0.5, 0.3])


def test_lp_without_solution_takes_the_least_violating_velocity() -> None:
    # x <= -1 and x >= 1 cannot both hold: the safest velocity violates both by 1 (x = 0)
    point = np.array([[[-1.0, 0.0], [1.0, 0.0]]])
    direction = np.array([[[0.0, 1.0], [0.0, -1.0]]])
    valid = np.ones((1, 2), dtype=bool)
    v, ok = solve_orca_lp(point, direction, valid, np.array([[3.0, 0.0]]), np.array([2.0]))
    assert not ok[0]
    assert v[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert abs(v[0, 1]) <= 2.0


def _min_future_distance(pos: np.ndarray, v: np.ndarray, obstacle: np.ndarray) -> float:
    t = np.linspace(0.0, 5.0, 501)[:, None]
    return float(np.hypot(*(pos + t * v - obstacle).T).min())


def test_full_responsibility_avoids_a_standing_robot_half_does_not() -> None:
    pos, vel = np.array([[0.0, 0.05]]), np.array([[1.3, 0.0]])
    robot, radius = np.array([[4.0, 0.0]]), 0.3 + 0.5
    outcomes = {}
    for share in (1.0, 0.5):
        m = ORCAModel(other_responsibility=share)
        m.reset()
        _, v = m.step(
            pos, vel, np.full(1, 0.3), vel, np.full(1, 1.7), robot, np.zeros((1, 2)),
            np.array([0.5]), 0.05,
        )  # fmt: skip
        outcomes[share] = _min_future_distance(pos, v[0], robot[0])
    assert outcomes[1.0] >= radius - 1e-6  # leaves the velocity obstacle of the robot
    assert outcomes[0.5] < radius  # RVO2's share assumes the robot will do half


@pytest.mark.parametrize(
    "kw, word",
    [
        ({"time_horizon": 0.0}, "time_horizon"),
        ({"neighbor_dist": -1.0}, "neighbor_dist"),
        ({"max_neighbors": 2.5}, "max_neighbors"),
        ({"other_responsibility": 1.5}, "other_responsibility"),
    ],
)
def test_bad_parameters_are_refused_at_reset(kw: dict, word: str) -> None:
    with pytest.raises(ValueError, match=word):
        ORCAModel(**kw).reset()
