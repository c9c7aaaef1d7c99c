"""ReciprocalShield: every robot's action filtered with the robots' rows shared."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from conformal_control.envs import ConformalCrowdParallel
from conformal_control.envs.parallel import ReciprocalShield


def _env(crossing, shield, **kw):
    env = ConformalCrowdParallel(
        crossing, robots=6, layout="antipodal", radius=5.0, center=(15.0, 8.0), max_frames=150
    )
    return ReciprocalShield(env, **kw) if shield else env


def _episode(env, policy, seed=0):
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    robot = pedestrian = modified = 0
    while env.agents:
        actions = {a: policy(obs[a], rng) for a in env.agents}
        obs, _r, _term, _trunc, infos = env.step(actions)
        for info in infos.values():
            robot += info["collision_robot"]
            pedestrian += info["collision_pedestrian"]
            modified += bool(info.get("shield_modified"))
    return robot, pedestrian, modified


def straight(obs, rng):
    g = obs["robot"][4:6]
    return 1.5 * g / max(np.hypot(*g), 1e-9)


def noisy(obs, rng):
    return rng.uniform(-2.0, 2.0, 2) + 0.8 * straight(obs, rng)


def test_parallel_api_test_with_the_shield(crossing):
    env = ReciprocalShield(ConformalCrowdParallel(crossing, robots=3, max_frames=40))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_api_test(env, num_cycles=200)


@pytest.mark.parametrize("policy", [straight, noisy], ids=["scripted", "random"])
def test_shielded_policies_do_not_drive_robots_into_each_other(crossing, policy):
    robot_off, ped_off, _ = _episode(_env(crossing, False), policy)
    robot_on, ped_on, modified = _episode(_env(crossing, True), policy)
    assert robot_off > 0 and robot_on == 0
    assert ped_on < ped_off
    assert modified > 0


def test_safe_actions_pass_unchanged(crossing):
    # two robots far apart and far from the pedestrians, standing still: nothing to filter
    env = ReciprocalShield(
        ConformalCrowdParallel(
            crossing, starts=[(1.0, 1.0), (29.0, 15.0)], goals=[(1.0, 4.0), (29.0, 12.0)]
        )
    )
    env.reset(seed=0)
    _, _, _, _, infos = env.step({a: np.zeros(2) for a in env.agents})
    for info in infos.values():
        assert not info["shield_modified"] and info["shield_status"] == "unconstrained"


def test_the_shield_needs_the_parallel_environment(crossing):
    from conformal_control.envs import ConformalCrowdEnv

    with pytest.raises(TypeError, match="wraps a ConformalCrowdParallel"):
        ReciprocalShield(ConformalCrowdEnv(crossing))  # type: ignore[arg-type]


def test_the_example_script_shows_the_shield_at_work():
    import runpy
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "examples" / "parallel_shield.py"
    ns = runpy.run_path(str(path), run_name="example")
    robot_off, ped_off, goals_off, _ = ns["episode"](ns["scripted"], False)
    robot_on, ped_on, goals_on, modified = ns["episode"](ns["scripted"], True)
    assert robot_off > 0 and robot_on == 0 and modified > 0
    assert ped_on < ped_off
    # the page's table: with people first (the default) every scripted robot reaches its
    # goal (with the robot rows kept first, one misses it since the edge rule)
    assert goals_off == 6 and goals_on == 6
