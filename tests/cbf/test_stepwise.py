"""StepwiseCBF driven by hand gives exactly what the replay environment gives."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.cbf import StepwiseCBF
from conformal_control.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.sim import build_flagship, run_episode


def drive(scene, fl, ctrl: StepwiseCBF, max_frames: int):
    """Replay the scene's pedestrians into ctrl and integrate the robot ourselves."""
    dyn = VelocityTrackingDoubleIntegrator(K_acc=fl.params.si["K_acc"])
    x = np.array([*scene.start, 0.0, 0.0])
    goal = scene.goals[-1]
    dt = 1.0 / scene.fps
    velocities = []
    fi = scene.start_index
    last = min(scene.n_frames - 1, scene.start_index + max_frames)
    # the history before the start frame, as the environment hands it to the predictor
    for j in range(max(fi - fl.params.history_frames + 1, 0), fi):
        pos = scene.positions[j]
        ok = np.isfinite(pos[:, 0])
        ctrl.observe(scene.agent_ids[ok], pos[ok], t=(j - fi) * dt)
    done = False
    while fi < last and not done:
        pos = scene.positions[fi]
        ok = np.isfinite(pos[:, 0])
        t0 = (fi - scene.start_index) * dt
        ctrl.observe(scene.agent_ids[ok], pos[ok], t=t0)
        for s in range(ctrl.substeps):
            v = ctrl.step(x, t=t0 + s * ctrl.dt_control, goal=goal)
            velocities.append(v.copy())
            x = dyn.step(x, v, ctrl.dt_control)
            if math.hypot(*(x[:2] - goal)) <= scene.goal_radius:
                done = True
                break
        fi += 1
    if not done:  # the replay ends its last interval when the data runs out
        pos = scene.positions[fi]
        ok = np.isfinite(pos[:, 0])
        ctrl.observe(scene.agent_ids[ok], pos[ok], t=(fi - scene.start_index) * dt)
    else:
        pos = scene.positions[fi + 1]
        ok = np.isfinite(pos[:, 0])
        ctrl.observe(scene.agent_ids[ok], pos[ok], t=(fi + 1 - scene.start_index) * dt)
    return np.array(velocities), ctrl.finish()


@pytest.mark.parametrize("scene_name", ["crossing", "nexus_4"])
def test_stepwise_matches_the_replay_environment(scene_name, crossing, nexus4) -> None:
    scene = crossing if scene_name == "crossing" else nexus4
    params = (
        {"epsilon": -0.1, "eta": 0.5}
        if scene_name == "crossing"
        else {
            "epsilon": -0.25,
            "eta": 1,
            "tau": 4,
            "a": 10,
            "K_rep": 40,
        }
    )
    frames = 120
    ref = run_episode(scene, "constant_velocity", params, max_frames=frames, record_animation=False)
    fl = build_flagship(scene, params, max_frames=frames)
    si = fl.params.si
    ctrl = StepwiseCBF(
        "constant_velocity",
        epsilon=si["epsilon"],
        eta=si["eta"],
        tau=fl.params.tau_frames / scene.fps,
        dt=1.0 / scene.fps,
        substeps=si["substeps"],
        a=si["a"],
        barrier=fl.barrier,
        safety_filter=fl.safety_filter,
        reference=fl.reference,
        sensing_radius=si["sensing_radius"],
        history=fl.params.history_frames,
        loss_scale=si["loss_scale"],
    )
    velocities, result = drive(fl.scene, fl, ctrl, frames)
    np.testing.assert_allclose(velocities, ref.steps["cmd"], rtol=0, atol=1e-12)
    lam_ref = [iv.lam for iv in ref.loop.intervals]
    lam = [iv.lam for iv in result.intervals]
    np.testing.assert_allclose(lam, lam_ref, rtol=0, atol=1e-12)
    loss_ref = [np.nan if iv.loss is None else iv.loss for iv in ref.loop.intervals]
    loss = [np.nan if iv.loss is None else iv.loss for iv in result.intervals]
    np.testing.assert_allclose(loss, loss_ref, rtol=0, atol=1e-12)
    assert result.n_updates == ref.loop.n_updates > 5


def test_stepwise_refuses_a_step_before_the_sample() -> None:
    ctrl = StepwiseCBF(dt=0.1, tau=0.2)
    ctrl.observe([1], [[3.0, 0.0]], t=0.0)
    ctrl.step(np.zeros(4), t=0.0, goal=np.array([10.0, 0.0]))
    for s in range(1, 8):
        ctrl.step(np.zeros(4), t=s * 0.025, goal=np.array([10.0, 0.0]))
    with pytest.raises(ValueError, match="observe\\(\\) the sample"):
        ctrl.step(np.zeros(4), t=0.2, goal=np.array([10.0, 0.0]))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"tau": 0.25, "dt": 0.1}, "whole number of samples"), ({"dt": -1.0}, "dt must be")],
)
def test_stepwise_rejects_nonsense(kwargs, message) -> None:
    with pytest.raises(ValueError, match=message):
        StepwiseCBF(**kwargs)


def test_finish_without_the_closing_sample_scores_what_was_observed() -> None:
    def drive(close: bool):
        ctrl = StepwiseCBF("constant_velocity", epsilon=-0.1, eta=0.5, tau=0.4, dt=0.1)
        robot, goal, k = np.zeros(4), np.array([20.0, 0.0]), 0
        peds, ped_v = np.array([[10.0, -5.0], [14.0, 6.0]]), np.array([[0.0, 1.0], [0.0, -1.0]])
        while np.hypot(*(robot[:2] - goal)) > 0.5:
            ctrl.observe([0, 1], peds, t=k * ctrl.dt)
            for j in range(ctrl.substeps):
                v = ctrl.step(robot, t=k * ctrl.dt + j * ctrl.dt_control, goal=goal)
                robot = np.r_[robot[:2] + v * ctrl.dt_control, v]
            peds, k = peds + ped_v * ctrl.dt, k + 1
        if close:
            ctrl.observe([0, 1], peds, t=k * ctrl.dt)
        return ctrl.finish()

    closed, open_ = drive(True), drive(False)
    assert len(open_.intervals) == len(closed.intervals)
    last = open_.intervals[-1]
    # the unobserved closing sample is missing truth, counted; the interval is still scored
    assert (
        last.diagnostics["n_truth_missing"]
        > 0
        == closed.intervals[-1].diagnostics["n_truth_missing"]
    )
    assert last.loss is not None and np.isfinite(last.loss)
