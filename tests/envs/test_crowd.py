"""ConformalCrowd-v0: gymnasium's checker, the observation, reward and info it documents."""

from __future__ import annotations

import dataclasses
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import conformal_control.envs as envs
from conformal_control.data.synthetic import SYNTHETIC_DEFAULTS
from conformal_control.envs import ConformalCrowdEnv


def _check(env: gym.Env) -> list[str]:
    """check_env, failing on its errors; returns its warnings (minus the infinite bounds
    of positions, which are unbounded by nature, and the action-range advice)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    benign = ("infinity", "symmetric and normalized")
    return [str(w.message) for w in caught if not any(b in str(w.message) for b in benign)]


def test_check_env_replay_with_rendering(crossing):
    env = gym.make("ConformalCrowd-v0", scene=crossing, render_mode="rgb_array", max_frames=30)
    assert _check(env.unwrapped) == []
    frame = env.unwrapped.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8


def test_check_env_reactive_crowd(crossing):
    env = gym.make("ConformalCrowd-v0", scene=crossing, crowd="social_force", max_frames=30)
    assert _check(env.unwrapped) == []


def test_registered_under_its_id_and_module_path(crossing):
    assert envs.ENV_ID in gym.registry
    env = gym.make("conformal_control.envs:ConformalCrowd-v0", scene=crossing, max_frames=5)
    assert isinstance(env.unwrapped, ConformalCrowdEnv)


def _ped_scene(line_scene, straight, tracks, **kw):
    scene = line_scene(tracks, **kw)
    return dataclasses.replace(scene, defaults=dict(SYNTHETIC_DEFAULTS), v_max=2.0)


def test_observation_agents_relative_nearest_first_with_mask(line_scene, straight):
    # at the start frame (2 s in) the first is at (3, 2), the second at (2, 2)
    tracks = [
        straight((3.0, 0.0), (0.0, 1.0)),  # walking +y
        straight((0.0, 2.0), (1.0, 0.0)),  # walking +x
        straight((40.0, 0.0), (0.0, 0.0)),  # out of range
    ]
    env = ConformalCrowdEnv(_ped_scene(line_scene, straight, tracks), max_agents=4)
    obs, _ = env.reset(seed=0)
    assert obs["mask"].tolist() == [1, 1, 0, 0]
    np.testing.assert_allclose(obs["agents"][0], [2.0, 2.0, 1.0, 0.0], atol=1e-5)
    np.testing.assert_allclose(obs["agents"][1], [3.0, 2.0, 0.0, 1.0], atol=1e-5)
    assert not obs["agents"][2:].any()
    # robot at its start (0, 0), standing, goal 500 m ahead in +y
    np.testing.assert_allclose(obs["robot"], [0, 0, 0, 0, 0, 500], atol=1e-5)
    assert env.observation_space.contains(obs)
    # relative to the robot once it moves: the rows follow it
    for _ in range(8):
        obs, *_ = env.step(np.array([0.0, 1.0]))
    x = env.core.world.state(0).x
    np.testing.assert_allclose(obs["robot"][:4], x, atol=1e-5)
    peds = env.core.world.pedestrians()[env.core.world.frame_index]
    np.testing.assert_allclose(obs["agents"][0, :2], peds[1] - x[:2], atol=1e-5)
    np.testing.assert_allclose(obs["agents"][0, 2:], [1.0, 0.0] - x[2:], atol=1e-5)


def test_reward_is_progress_minus_collisions_plus_goal(line_scene, straight):
    # a pedestrian standing 1.5 m ahead: the robot walks into it
    tracks = [straight((0.0, 1.5), (0.0, 0.0))]
    env = ConformalCrowdEnv(_ped_scene(line_scene, straight, tracks), collision_penalty=3.0)
    _, info = env.reset(seed=0)
    d = info["distance_to_goal"]
    hits = 0
    for _ in range(60):
        _obs, r, _term, _trunc, info = env.step(np.array([0.0, 1.0], dtype=np.float32))
        contact = info["collision_pedestrian"] or info["collision_robot"]
        hits += contact
        assert r == pytest.approx(d - info["distance_to_goal"] - 3.0 * contact)
        d = info["distance_to_goal"]
    assert hits > 0 and info["n_collision_steps"] == hits
    assert info["collision_pedestrian"] and not info["collision_robot"]


def test_goal_terminates_with_the_bonus(line_scene, straight):
    scene = _ped_scene(line_scene, straight, [straight((50.0, 50.0), (0.0, 0.0))])
    scene = dataclasses.replace(scene, goals=np.array([[0.0, 1.0]]))
    env = ConformalCrowdEnv(scene, goal_bonus=7.0)
    env.reset(seed=0)
    for _ in range(200):
        _, r, term, trunc, info = env.step(np.array([0.0, 2.0]))
        if term or trunc:
            break
    assert term and not trunc and info["goal_reached"]
    assert r > 7.0 - 0.1
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2))


def test_truncated_when_the_data_runs_out(crossing):
    env = ConformalCrowdEnv(crossing, max_frames=3)
    env.reset(seed=0)
    n = 0
    while True:
        _, _, term, trunc, _ = env.step(np.zeros(2))
        n += 1
        if term or trunc:
            break
    assert trunc and not term
    assert n == 3 * env.core.world.substeps


def test_info_carries_the_monitor(crossing):
    env = ConformalCrowdEnv(crossing)
    obs, _ = env.reset(seed=0)
    statuses, losses, lams = set(), [], []
    for _ in range(400):
        g = obs["robot"][4:6]
        obs, _, term, trunc, info = env.step(2.0 * g / np.hypot(*g))
        statuses.add(info["constraint_status"])
        lams.append(info["lambda"])
        if info["loss"] is not None:
            losses.append(info["loss"])
            assert info["interval_closed"]
        if info["constraint_status"] == "violated":
            assert info["n_violated"] > 0 and info["min_slack"] < 0
        if term or trunc:
            break
    assert {"satisfied", "violated"} <= statuses
    assert len(losses) > 10 and all(-0.5 < x < 0.5 for x in losses)
    assert len(set(lams)) > 5  # lambda learns from the losses


def test_actions_longer_than_v_max_are_scaled_back(crossing):
    env = ConformalCrowdEnv(crossing, max_frames=5)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([30.0, 40.0]))
    assert info["action_clipped"]
    cmd = env.core.world.robots[0].steps_cmd[-1]
    np.testing.assert_allclose(cmd, [0.6 * env.core.v_max, 0.8 * env.core.v_max])
    with pytest.raises(ValueError, match="finite velocity"):
        env.step(np.array([np.nan, 0.0]))


def test_reset_with_a_seed_is_deterministic_for_a_reactive_crowd(crossing):
    env = ConformalCrowdEnv(crossing, crowd="orca", crowd_params={"time_horizon": 2.0})
    traj = []
    for _ in range(2):
        obs, _ = env.reset(seed=4)
        run = []
        for _ in range(40):
            obs, r, *_ = env.step(np.array([1.5, 0.0]))
            run.append((obs["agents"].copy(), r))
        traj.append(run)
    for (a, ra), (b, rb) in zip(*traj, strict=True):
        np.testing.assert_array_equal(a, b)
        assert ra == rb


def test_flatten_observation_gives_one_box(crossing):
    env = gym.wrappers.FlattenObservation(ConformalCrowdEnv(crossing, max_agents=5, max_frames=5))
    obs, _ = env.reset(seed=0)
    assert obs.shape == (5 * 4 + 5 + 6,)
