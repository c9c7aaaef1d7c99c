"""StepwiseMPC: the MPC families one call at a time, as the replay environment runs them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.families.cbf import Stream
from conformal_control.families.mpc import SamplingMPC, StepwiseMPC
from conformal_control.runs.build import build_flagship
from conformal_control.runs.episode import run_episode

FAST = {"sampling__n_samples": 60, "sampling__horizon": 6, "sampling__replan_every": 2}


def drive(scene, fl, ctrl: StepwiseMPC, max_frames: int):
    """Replay the scene's pedestrians into ctrl and integrate the robot ourselves."""
    dyn = fl.dynamics
    x = np.array([*scene.start, 0.0, 0.0])
    goal = scene.goals[-1]
    dt = 1.0 / scene.fps
    commands = []
    fi = scene.start_index
    last = min(scene.n_frames - 1, scene.start_index + max_frames)

    def observe(j: int) -> None:
        pos = scene.positions[j]
        ok = np.isfinite(pos[:, 0])
        ctrl.observe(scene.agent_ids[ok], pos[ok], t=(j - scene.start_index) * dt)

    for j in range(max(fi - fl.params.history_frames + 1, 0), fi):
        observe(j)
    done = False
    while fi < last and not done:
        observe(fi)
        t0 = (fi - scene.start_index) * dt
        for s in range(ctrl.substeps):
            u = ctrl.step(x, t=t0 + s * ctrl.dt_control, goal=goal)
            commands.append(u.copy())
            x = dyn.step(x, u, ctrl.dt_control)
            if math.hypot(*(x[:2] - goal)) <= scene.goal_radius:
                done = True
                break
        fi += 1
    observe(fi + 1 if done else fi)
    return np.array(commands), ctrl.finish()


@pytest.mark.parametrize(
    ("family", "rule", "rule_params"),
    [("mpc", None, None), ("acp_mpc", "aci", {"alpha": 0.2, "gamma": 0.05})],
)
def test_stepwise_mpc_matches_the_replay_environment(crossing, family, rule, rule_params):
    frames = 100
    settings = {
        "family": family,
        "family_params": FAST,
        "rule": rule,
        "rule_params": rule_params,
        "max_frames": frames,
    }
    ref = run_episode(crossing, record_animation=False, **settings)
    fl = build_flagship(crossing, **settings)
    si = fl.params.si
    ctrl = StepwiseMPC(
        fl.predictor,
        family=fl.family,
        dynamics=fl.dynamics,
        loss=fl.loss,
        rule=fl.rule,
        stream=Stream(
            tau=fl.params.tau_frames / crossing.fps,
            dt=1.0 / crossing.fps,
            substeps=si["substeps"],
            sensing_radius=si["sensing_radius"],
            history=fl.params.history_frames,
        ),
    )
    commands, result = drive(fl.scene, fl, ctrl, frames)
    np.testing.assert_allclose(commands, ref.steps["cmd"], rtol=0, atol=1e-12)
    lam_ref = [iv.lam for iv in ref.loop.intervals]
    np.testing.assert_allclose([iv.lam for iv in result.intervals], lam_ref, rtol=0, atol=1e-12)
    assert result.n_updates == ref.loop.n_updates > 5
    assert len(set(np.round(lam_ref, 9))) > 1  # lambda moved: the loss was scored
    assert ctrl.stats()["n_infeasible"] == ref.metrics["n_infeasible"]
    assert ctrl.stats()["n_plans"] > 0


def test_built_by_name_with_the_family_defaults():
    ctrl = StepwiseMPC(family=("mpc", FAST), stream=Stream(tau=0.4, dt=0.1))
    assert isinstance(ctrl.planner, SamplingMPC) and ctrl.planner.sampling.n_samples == 60
    rule = ctrl.stepper.rule
    assert (rule.epsilon, rule.eta, rule.lambda_min) == (0.1, 0.2, -1.0)
    assert type(ctrl.stepper.loss).__name__ == "DistanceShortfallLoss"
    # an agent walking at the robot: the plan keeps d_c + margin - lambda away
    goal = np.array([10.0, 0.0])
    x = np.zeros(4)
    for k in range(20):
        ctrl.observe([7], [[6.0 - 0.1 * k, 0.0]], t=k * 0.1)
        for j in range(ctrl.substeps):
            u = ctrl.step(x, t=k * 0.1 + j * ctrl.dt_control, goal=goal)
            assert u.shape == (2,) and np.hypot(*u) <= 2.0 + 1e-9
            x = np.array([*(x[:2] + u * ctrl.dt_control), *u])
    assert ctrl.stats()["n_steps"] == 80
    assert np.hypot(*(x[:2] - np.array([6.0 - 1.9, 0.0]))) > 1.0


def test_a_unicycle_takes_its_five_numbers():
    ctrl = StepwiseMPC(
        family=("mpc", FAST),
        dynamics=("unicycle", {"v_max": 1.5, "omega_max": 1.0}),
    )
    ctrl.observe([1], [[5.0, 2.0]], t=0.0)
    u = ctrl.step(np.zeros(5), t=0.0, goal=np.array([10.0, 0.0]))
    assert 0.0 <= u[0] <= 1.5 and abs(u[1]) <= 1.0
    with pytest.raises(ValueError, match="ego_state must be 5 finite numbers"):
        ctrl.step(np.zeros(4), t=ctrl.dt_control, goal=np.array([10.0, 0.0]))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"family": "cbf"}, "StepwiseMPC runs a planning family"),
        ({"family": "mcp"}, "mcp"),
        ({"family": ("mpc", {"sampling__n_samples": 0})}, "n_samples"),
        ({"stream": Stream(tau=0.25, dt=0.1)}, "whole number of samples"),
        ({"epsilon": 1.5}, "epsilon"),
        ({"family": ("mpc", {"substeps": 2})}, "substeps"),
        ({"v_max": float("nan")}, "v_max"),
    ],
)
def test_nonsense_is_a_one_line_error(kwargs, message):
    with pytest.raises(ValueError, match=message) as info:
        ctrl = StepwiseMPC(**kwargs)
        ctrl.observe([1], [[5.0, 0.0]], t=0.0)
        ctrl.step(np.zeros(4), t=0.0, goal=np.array([10.0, 0.0]))
    assert "\n" not in str(info.value)
