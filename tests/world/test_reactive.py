"""The reactive environment: head-on avoidance, no oracle, flagship episodes, the factory."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conformal_control.core import registry
from conformal_control.core.loop import ConformalLoop
from conformal_control.core.update_rules import FixedEtaRule
from conformal_control.families.cbf import (
    APFBarrier,
    AttractiveField,
    CBFGapLoss,
    ConformalCBFController,
    ConformalConstraint,
    QPSafetyFilter,
)
from conformal_control.families.cbf.controller import PredictorError
from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.predictors.base import TruthUnavailableError
from conformal_control.runs.params import resolve_params
from conformal_control.world.reactive import (
    ReactiveEnvironment,
    make_environment,
    make_environment_like,
)
from conformal_control.world.replay import ReplayEnvironment


@pytest.mark.parametrize(
    "crowd, params",
    [
        ("social_force", None),
        ("orca", None),
        ("mixed", {"radius": 4.0}),
        ("mixed", {"model": "orca", "radius": 4.0}),
    ],
)
def test_a_pedestrian_walking_at_a_stopped_robot_steps_aside(
    crowd: str, params: dict | None, line_scene, straight, run_stopped_robot
) -> None:
    scene = line_scene([straight((12.0, 0.1), (-1.3, 0.0))])
    replay = run_stopped_robot(scene, "replay")
    reactive = run_stopped_robot(scene, crowd, params)
    d_replay = np.nanmin(replay.log.arrays()["d_min"])
    d_reactive = np.nanmin(reactive.log.arrays()["d_min"])
    assert d_replay < 0.15  # the recording walks through the robot
    assert d_reactive > 0.7  # the reactive pedestrian keeps clear of its body (0.5 + 0.3 m)
    arr = reactive.log.arrays()
    assert np.allclose(arr["x"], 0.0) and np.allclose(arr["y"], 0.0)  # the robot stood still
    sim = reactive.simulated_scene().positions[:, 0]
    assert np.nanmax(np.abs(sim[:, 1] - 0.1)) > 0.5  # it deviated sideways ...
    assert sim[scene.start_index + 140, 0] < -5.0  # ... and walked on past the robot


def test_sensor_history_truth_and_log_come_from_the_simulated_crowd(line_scene, straight) -> None:
    scene = line_scene([straight((6.0, 0.3), (-1.0, 0.0)), straight((-5.0, 3.0), (0.5, -0.3))])
    env = make_environment(
        scene,
        crowd="social_force",
        dynamics=VelocityTrackingDoubleIntegrator(K_acc=2.0),
        tau_frames=5,
        substeps=2,
        history_frames=30,
    )
    assert isinstance(env, ReactiveEnvironment)
    env.reset()
    q0 = env.sense()
    with pytest.raises(TruthUnavailableError, match="reactive crowd"):
        q0.future()
    # history before (and at) the start frame is the recording
    assert np.array_equal(q0.history[:, -21:], scene.positions[:21].transpose(1, 0, 2))
    for _ in range(env.control_instants()):
        env.apply(np.array([0.3, 0.0]))
    truth = env.reveal()
    sim = env.simulated_scene().positions
    assert np.array_equal(truth.samples, sim[20:26].transpose(1, 0, 2))
    assert not np.allclose(sim[25], scene.positions[25])  # simulated, not replayed
    q1 = env.sense()
    assert np.array_equal(q1.history[:, -1], sim[25, np.searchsorted(scene.agent_ids, q1.ids)])
    d = np.hypot(*(sim[25] - env.log.state[-1][:2]).T).min()
    assert env.log.d_min[-1] == pytest.approx(d)


def _flagship(scene, crowd, crowd_params=None, max_frames=None, predictor="constant_velocity"):
    """The flagship wired from its parts (as the episode builder does), run by the loop."""
    resolved = resolve_params(scene, {})
    si = resolved.si
    scene = dataclasses.replace(
        scene,
        robot_radius=si["robot_radius"],
        agent_radius=si["agent_radius"],
        goal_radius=si["goal_radius"],
        v_max=si["v_max"],
    )
    barrier = APFBarrier(
        K_rep=si["K_rep"],
        rho0=si["rho0"],
        d_c=si["robot_radius"] + si["agent_radius"],
        convention=si["convention"],
        delta=si["delta"],
    )
    constraint = ConformalConstraint(barrier, a=si["a"])
    policy = ConformalCBFController(
        registry.create("predictor", predictor),
        constraint,
        QPSafetyFilter(v_max=si["v_max"], fallback="lambda_search"),
        AttractiveField(K_att=si["K_att"], v_max=si["v_max"]),
        substeps=si["substeps"],
    )
    loss = CBFGapLoss(constraint, scale=si["loss_scale"])
    rule = FixedEtaRule(epsilon=si["epsilon"], eta=si["eta"], lambda_init=si["lambda_init"])
    replay = ReplayEnvironment(
        scene,
        VelocityTrackingDoubleIntegrator(K_acc=si["K_acc"]),
        tau_frames=resolved.tau_frames,
        substeps=si["substeps"],
        sensing_radius=si["sensing_radius"],
        history_frames=resolved.history_frames,
        max_frames=max_frames,
    )
    env = make_environment_like(replay, crowd, crowd_params)
    result = ConformalLoop(env, policy, loss, rule).run()
    return env, result


def _check_episode(env, result) -> None:
    log = env.log.arrays()
    sim = env.simulated_scene().positions
    rows = log["frame"] - env.scene.first_frame
    for i in (0, len(rows) // 2, len(rows) - 1):
        p = sim[rows[i]]
        p = p[np.isfinite(p[:, 0])]
        d = np.hypot(*(p - [log["x"][i], log["y"][i]]).T).min()
        assert log["d_min"][i] == pytest.approx(d)  # d_min is measured to the simulated crowd
    assert result.n_updates > 0
    assert np.isfinite(result.losses).all()


@pytest.mark.parametrize("crowd", ["social_force", "orca", "mixed"])
def test_flagship_episode_on_crossing(crossing, crowd: str) -> None:
    env, result = _flagship(crossing, crowd)
    assert env.goal_reached
    _check_episode(env, result)
    assert env.crowd.summary()["n_simulated"] > 0


def test_flagship_episodes_on_nexus4_mixed_and_orca(nexus4) -> None:
    env, result = _flagship(nexus4, "mixed", {"radius": 6.0}, max_frames=150)
    _check_episode(env, result)
    c = env.crowd
    never = c.switched_at_ < 0
    assert never.any() and (~never).any()
    last = nexus4.start_index + len(env.log.frame)
    sim = env.simulated_scene().positions[:last]
    assert np.array_equal(sim[:, never], nexus4.positions[:last, never], equal_nan=True)
    env2, result2 = _flagship(nexus4, "orca", max_frames=60)
    _check_episode(env2, result2)
    # deterministic: the same run twice gives the same robot and crowd
    env3, _ = _flagship(nexus4, "orca", max_frames=60)
    assert np.array_equal(np.array(env2.log.state), np.array(env3.log.state))
    assert np.array_equal(
        env2.simulated_scene().positions, env3.simulated_scene().positions, equal_nan=True
    )


def test_the_oracle_cannot_run_in_a_reactive_crowd(crossing) -> None:
    with pytest.raises(PredictorError, match="reactive crowd") as info:
        _flagship(crossing, "social_force", max_frames=20, predictor="oracle")
    assert isinstance(info.value.__cause__, TruthUnavailableError)


def test_replay_crowd_is_the_replay_environment(crossing) -> None:
    scene = dataclasses.replace(crossing)
    kw = {
        "dynamics": VelocityTrackingDoubleIntegrator(K_acc=10.0),
        "tau_frames": 4,
        "max_frames": 30,
    }
    env = make_environment(scene, **kw)
    assert type(env) is ReplayEnvironment
    env.reset()
    q = env.sense()
    cols = np.searchsorted(crossing.agent_ids, q.ids)
    assert np.array_equal(crossing.agent_ids[cols], q.ids)
    assert np.array_equal(
        q.future(), crossing.positions[121:125, cols].transpose(1, 0, 2), equal_nan=True
    )


@pytest.mark.parametrize(
    "crowd, params, word",
    [
        ("boids", None, "unknown crowd"),
        ("replay", {"radius": 3.0}, "takes no crowd_params"),
        ("social_force", {"radius": 3.0}, "crowd='mixed'"),
        ("mixed", {"radius": -2.0}, "radius"),
        ("mixed", {"model": "mixed"}, "unknown model"),
        ("orca", {"A": 4.5}, "no parameter"),
        ("social_force", {"waypoint_interval": 0.0}, "waypoint_interval"),
    ],
)
def test_bad_crowd_choices_are_refused_when_built(
    crossing, crowd: str, params: dict | None, word: str
) -> None:
    with pytest.raises(ValueError, match=word):
        make_environment(
            crossing,
            crowd=crowd,
            crowd_params=params,
            dynamics=VelocityTrackingDoubleIntegrator(K_acc=10.0),
            tau_frames=4,
        )
