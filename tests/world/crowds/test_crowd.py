"""Seeding from the recording, waypoints on schedule, entries and exits, mixed mode."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.world.crowds import Crowd

NAN = np.full(2, np.nan)


@pytest.mark.parametrize("crowd", ["social_force", "orca"])
def test_unhindered_pedestrians_walk_as_recorded(
    crowd: str, line_scene, straight, run_stopped_robot
) -> None:
    # far from the robot and from each other: one walks, one stands, one turns a corner
    walk = straight((20.0, 10.0), (1.2, 0.0))
    stand = straight((40.0, -20.0), (0.0, 0.0))
    corner = straight((-30.0, 20.0), (0.0, -1.0))
    corner[100:] = corner[100] + straight((0.0, 0.0), (1.0, 0.0))[:100]
    scene = line_scene([walk, stand, corner])
    env = run_stopped_robot(scene, crowd, frames=150)
    sim = env.simulated_scene().positions
    frames = np.arange(scene.start_index, scene.start_index + len(env.log.frame))
    err = np.hypot(*(sim[frames] - scene.positions[frames]).transpose(2, 0, 1))
    assert err[:, 0].max() < 0.05  # the model follows the schedule of the waypoints
    assert err[:, 1].max() < 1e-9  # standing still stays put
    assert err[:, 2].max() < 1.0  # cuts the corner (heads 1-2 s ahead)
    assert env.crowd.summary()["n_simulated"] == 3


def test_entry_at_the_recorded_place_and_exit_where_the_track_ends(
    line_scene, straight, run_stopped_robot
) -> None:
    late = straight((5.0, 8.0), (1.0, 0.0))
    late[:40] = np.nan  # enters at frame 40 (after the start frame 20)
    late[90:] = np.nan  # leaves at frame 89
    scene = line_scene([late])
    env = run_stopped_robot(scene, "social_force", frames=120)
    sim = env.simulated_scene().positions
    assert np.isnan(sim[20:40, 0]).all()
    assert np.array_equal(sim[40, 0], late[40])
    assert np.isfinite(sim[41:89, 0]).all()
    assert np.isnan(sim[95:140, 0]).all()  # left at its last recorded position
    assert env.crowd.summary()["n_left"] == 1


def test_mixed_mode_replays_far_pedestrians_bit_for_bit(
    line_scene, straight, run_stopped_robot
) -> None:
    rng = np.random.default_rng(3)
    near = straight((8.0, 0.05), (-1.3, 0.0))  # walks straight at the robot
    far = [straight((rng.uniform(-30, 30), 15.0 + 3 * i), (0.8, -0.1)) for i in range(4)]
    for tr in far:  # recorded jitter the model could never reproduce
        tr += rng.normal(0.0, 0.02, tr.shape)
    scene = line_scene([near, *far])
    env = run_stopped_robot(scene, "mixed", {"radius": 3.0}, frames=150)
    sim = env.simulated_scene().positions
    last = scene.start_index + len(env.log.frame)
    assert np.array_equal(sim[:last, 1:], scene.positions[:last, 1:])
    assert env.crowd.switched_at_[0] >= scene.start_index
    assert (env.crowd.switched_at_[1:] == -1).all()
    # switched with the robot 3 m away: replayed exactly until then
    k = env.crowd.switched_at_[0]
    assert np.array_equal(sim[:k, 0], near[:k])
    assert np.hypot(*(sim[k + 30, 0] - near[k + 30])) > 0.3


def test_two_runs_are_identical_and_the_seed_drives_the_noise(
    line_scene, straight, run_stopped_robot
) -> None:
    scene = line_scene([straight((8.0, 0.1), (-1.3, 0.0)), straight((-6.0, 2.0), (1.0, -0.2))])

    def run(seed: int) -> np.ndarray:
        env = run_stopped_robot(scene, "social_force", {"noise": 0.3, "seed": seed}, frames=60)
        return env.simulated_scene().positions[: scene.start_index + 60].copy()

    a, b, c = run(5), run(5), run(6)
    assert np.array_equal(a, b, equal_nan=True)
    assert not np.array_equal(a, c, equal_nan=True)


@pytest.mark.parametrize(
    "kw, word",
    [
        ({"mixed_radius": -1.0}, "mixed_radius"),
        ({"waypoint_interval": 0.0}, "waypoint_interval"),
        ({"body_radius": float("inf")}, "body_radius"),
        ({"max_delay": "10"}, "max_delay"),
        ({"seed": 1.5}, "seed"),
        ({"model": "boids"}, "unknown crowd .boids.; registered crowd plugins"),
        ({"model_params": {"A": 1.0, "B": 2.0}}, "no parameter"),
    ],
)
def test_bad_crowd_parameters_are_refused(kw: dict, word: str) -> None:
    crowd = Crowd(**kw)
    with pytest.raises(ValueError, match=word):
        crowd.reset(np.zeros((5, 1, 2)), 10.0, 0, 4, 0.5)
