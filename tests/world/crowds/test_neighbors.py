"""The cell search returns the dense search's pairs bit for bit; the models step identically."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.world.crowds import Crowd, ORCAModel, SocialForceModel
from conformal_control.world.crowds import orca as orca_module
from conformal_control.world.crowds import social_force as sf_module
from conformal_control.world.crowds.neighbors import dense_neighbor_pairs, neighbor_pairs


def _same(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...]) -> None:
    assert len(a) == len(b) == 4
    for x, y, what in zip(a, b, ("rows", "cols", "dx", "dy"), strict=True):
        assert x.shape == y.shape, what
        np.testing.assert_array_equal(x, y, err_msg=what)
        assert x.dtype.kind == y.dtype.kind, what


def _crowd(rng: np.random.Generator, n: int, e: int, size: float, r: float) -> np.ndarray:
    """``n`` pedestrians then ``e`` others in a square; some exactly at distance ``r`` of
    another, some coincident, some on a shared coordinate, a few NaN rows."""
    p = rng.uniform(0.0, size, (n + e, 2))
    m = n + e
    if m >= 2:
        for _ in range(max(1, m // 5)):  # exactly at the cut-off, along an axis or not
            i, j = rng.integers(0, m, 2)
            if i == j:
                continue
            if rng.random() < 0.5:
                p[j] = p[i] + np.array([r, 0.0]) * rng.choice([-1.0, 1.0])
            else:
                p[j] = p[i] + np.array([0.6 * r, 0.8 * r])  # (0.6, 0.8) r: |.|^2 rounds either way
        i, j = rng.integers(0, m, 2)
        p[j] = p[i]  # coincident
        p[rng.integers(0, m), 0] = p[rng.integers(0, m), 0]  # a shared x
    if m >= 4 and rng.random() < 0.3:
        p[rng.integers(0, m)] = np.nan
    return p


@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(0, 80),
    e=st.integers(0, 4),
    size=st.sampled_from([0.5, 5.0, 40.0, 1e4]),
    r=st.sampled_from([0.3, 1.0, 2.5, 10.0, 1e3]),
    k=st.sampled_from([None, 0, 1, 3, 10]),
)
def test_cell_search_equals_the_dense_search(seed, n, e, size, r, k):
    rng = np.random.default_rng(seed)
    all_pos = _crowd(rng, n, e, size, r)
    pos = all_pos[:n]
    _same(neighbor_pairs(pos, all_pos, r, k), dense_neighbor_pairs(pos, all_pos, r, k))


def test_pairs_at_the_cut_off_are_out_and_just_inside_are_in():
    r = 10.0
    inside = np.nextafter(r, 0.0)
    pos = np.array([[0.0, 0.0], [r, 0.0], [0.0, inside], [-6.0, 8.0], [3.0, 3.0]])
    rows, cols, _, _ = neighbor_pairs(pos[:1], pos, r)
    assert rows.tolist() == [0, 0]
    # (r, 0) at exactly r and (-6, 8) at exactly 10 are out; the others in
    assert cols.tolist() == [2, 4]
    _same(neighbor_pairs(pos, pos, r), dense_neighbor_pairs(pos, pos, r))


def test_large_crowd_equals_the_dense_search_with_the_nearest_cut():
    rng = np.random.default_rng(3)
    pos = rng.uniform(0.0, 120.0, (1500, 2))
    all_pos = np.vstack([pos, [[60.0, 60.0]]])
    for k in (None, 10):
        _same(neighbor_pairs(pos, all_pos, 10.0, k), dense_neighbor_pairs(pos, all_pos, 10.0, k))


def test_infinite_cut_off_and_absurd_spans_take_the_dense_search():
    pos = np.array([[0.0, 0.0], [1e300, 0.0], [5.0, 5.0]])
    _same(neighbor_pairs(pos, pos, 1.0), dense_neighbor_pairs(pos, pos, 1.0))
    _same(neighbor_pairs(pos, pos, np.inf), dense_neighbor_pairs(pos, pos, np.inf))


# ---------------------------------------------------------------- the models, step by step
@pytest.fixture
def dense(monkeypatch):
    """Switch the models to the dense search (the reference) inside a ``with`` block."""

    class Dense:
        def __enter__(self) -> None:
            monkeypatch.setattr(sf_module, "neighbor_pairs", dense_neighbor_pairs)
            monkeypatch.setattr(orca_module, "neighbor_pairs", dense_neighbor_pairs)

        def __exit__(self, *exc: object) -> None:
            monkeypatch.undo()

    return Dense()


@pytest.mark.parametrize("model", [SocialForceModel(), ORCAModel(), ORCAModel(max_neighbors=3)])
def test_models_step_exactly_as_with_the_dense_search(model, dense):
    rng = np.random.default_rng(7)
    n, size = 400, 60.0
    pos = rng.uniform(0.0, size, (n, 2))
    pos[1] = pos[0] + np.array([model.neighbor_dist, 0.0])  # a pair exactly at the cut-off
    vel = rng.normal(0.0, 0.8, (n, 2))
    goal = rng.uniform(0.0, size, (n, 2))
    rad, vmax = np.full(n, 0.3), np.full(n, 1.7)
    robot, robot_vel, robot_rad = np.array([[30.0, 30.0]]), np.array([[1.0, 0.0]]), np.full(1, 0.5)
    model.reset(np.random.default_rng(0))
    for _ in range(30):
        d = goal - pos
        pref = 1.3 * d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)[:, None]
        args = (pos, vel, rad, pref, vmax, robot, robot_vel, robot_rad, 0.05)
        fast = model.step(*args)
        with dense:
            ref = model.step(*args)
        np.testing.assert_array_equal(fast[0], ref[0])
        np.testing.assert_array_equal(fast[1], ref[1])
        pos, vel = fast
        robot = robot + 0.05 * robot_vel


@pytest.mark.parametrize("model", ["social_force", "orca"])
def test_mixed_crowd_runs_exactly_as_with_the_dense_search(
    model, dense, line_scene, straight
) -> None:
    # pedestrians walking past a robot that walks through them: replayed until it is near
    rng = np.random.default_rng(2)
    tracks = [
        straight(tuple(rng.uniform(-15.0, 15.0, 2)), tuple(rng.normal(0.0, 1.0, 2)), n=200)
        for _ in range(30)
    ]
    scene = line_scene(tracks, start_index=5)
    runs = []
    for reference in (False, True):
        crowd = Crowd(model, mixed_radius=4.0)
        crowd.reset(scene.positions, scene.fps, scene.start_index, 4, robot_radius=0.5)
        frames = []
        for f in range(scene.start_index, scene.start_index + 60):
            for sub in range(4):
                robot = np.array([-10.0 + 0.05 * (4 * f + sub), 0.0])
                if reference:
                    with dense:
                        crowd.step(f, sub, robot, np.array([2.0, 0.0]))
                else:
                    crowd.step(f, sub, robot, np.array([2.0, 0.0]))
            frames.append(crowd.frame_positions(f + 1))
        runs.append(np.array(frames))
        assert crowd.summary()["n_simulated"] > 0
    np.testing.assert_array_equal(runs[0], runs[1])
