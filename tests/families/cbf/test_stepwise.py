"""StepwiseCBF driven by hand gives exactly what the replay environment gives."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.families.cbf import StepwiseCBF, Stream
from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.runs.build import build_flagship
from conformal_control.runs.episode import run_episode


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
        stream=Stream(
            tau=fl.params.tau_frames / scene.fps,
            dt=1.0 / scene.fps,
            substeps=si["substeps"],
            sensing_radius=si["sensing_radius"],
            history=fl.params.history_frames,
        ),
        a=si["a"],
        barrier=fl.barrier,
        safety_filter=fl.safety_filter,
        reference=fl.reference,
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
    ctrl = StepwiseCBF(stream=Stream(dt=0.1, tau=0.2))
    ctrl.observe([1], [[3.0, 0.0]], t=0.0)
    ctrl.step(np.zeros(4), t=0.0, goal=np.array([10.0, 0.0]))
    for s in range(1, 8):
        ctrl.step(np.zeros(4), t=s * 0.025, goal=np.array([10.0, 0.0]))
    with pytest.raises(ValueError, match="observe\\(\\) the sample"):
        ctrl.step(np.zeros(4), t=0.2, goal=np.array([10.0, 0.0]))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"stream": Stream(tau=0.25, dt=0.1)}, "whole number of samples"),
        ({"stream": Stream(dt=-1.0)}, "dt must be"),
    ],
)
def test_stepwise_rejects_nonsense(kwargs, message) -> None:
    with pytest.raises(ValueError, match=message):
        StepwiseCBF(**kwargs)


def test_finish_without_the_closing_sample_scores_what_was_observed() -> None:
    def drive(close: bool):
        ctrl = StepwiseCBF(
            "constant_velocity", epsilon=-0.1, eta=0.5, stream=Stream(tau=0.4, dt=0.1)
        )
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


# ---------------------------------------------------------------------- input contract
def _ctrl(**kw) -> StepwiseCBF:
    return StepwiseCBF(
        "constant_velocity", epsilon=-0.1, eta=0.5, stream=Stream(tau=0.4, dt=0.1), **kw
    )


GOAL = np.array([20.0, 0.0])


def test_duplicate_ids_in_one_sample_are_refused_not_collapsed() -> None:
    """Keeping only the last row drove the robot 1e-14 m past the other pedestrian."""
    ctrl = _ctrl()
    with pytest.raises(ValueError, match="id 7 appears 2 times"):
        ctrl.observe([7, 7], [[5.0, 0.0], [3.0, 0.0]], t=0.0)


@pytest.mark.parametrize("bad", [1.5, np.nan, 1e20, True, "a"])
def test_ids_are_whole_numbers(bad) -> None:
    with pytest.raises(ValueError, match="ids"):
        _ctrl().observe([0, bad], [[5.0, 0.0], [3.0, 0.0]], t=0.0)


def test_whole_float_ids_are_the_same_agents_as_int_ids() -> None:
    a, b = _ctrl(), _ctrl()
    for k in range(3):
        a.observe([1, 2], [[5.0 - k * 0.1, 0.0], [9.0, 1.0]], t=k * 0.1)
        b.observe(np.array([1.0, 2.0]), [[5.0 - k * 0.1, 0.0], [9.0, 1.0]], t=k * 0.1)
    np.testing.assert_array_equal(
        a.step(np.zeros(4), t=0.2, goal=GOAL), b.step(np.zeros(4), t=0.2, goal=GOAL)
    )


@pytest.mark.parametrize("eps", [5.0, 0.5, -0.5, np.nan, np.inf])
def test_epsilon_outside_the_loss_range_is_refused(eps) -> None:
    """epsilon=5 drove lambda to 45.5 and the robot into a static pedestrian."""
    with pytest.raises(ValueError, match=r"epsilon must lie in \(-1/2, 1/2\)"):
        StepwiseCBF(epsilon=eps)


@pytest.mark.parametrize(("name", "value"), [("eta", -1.0), ("eta", np.nan), ("a", 0.0)])
def test_rates_and_gains_are_checked(name, value) -> None:
    with pytest.raises(ValueError, match=name):
        StepwiseCBF(**{name: value})


def test_the_same_message_as_the_command_line_for_epsilon() -> None:
    from conformal_control.data import load_scene
    from conformal_control.runs.params import resolve_params

    with pytest.raises(ValueError) as cli:
        resolve_params(load_scene("crossing"), {"epsilon": 5.0})
    with pytest.raises(ValueError) as step:
        StepwiseCBF(epsilon=5.0)
    assert str(cli.value) == str(step.value)


@pytest.mark.parametrize("per_sample", [2, 8])
def test_control_steps_per_sample_are_checked(per_sample) -> None:
    ctrl = _ctrl()
    robot = np.zeros(4)

    def run() -> None:
        for k in range(8):
            ctrl.observe([0], [[10.0, 3.0]], t=k * 0.1)
            for j in range(per_sample):
                ctrl.step(robot, t=k * 0.1 + j * 0.1 / per_sample, goal=GOAL)

    with pytest.raises(ValueError, match=r"step\(\) at t = .* expected t = "):
        run()


def test_eight_steps_at_the_documented_spacing_are_caught_at_the_next_sample() -> None:
    ctrl = _ctrl()
    ctrl.observe([0], [[10.0, 3.0]], t=0.0)
    for j in range(8):  # twice the control instants of one sample, at the right spacing
        ctrl.step(np.zeros(4), t=j * ctrl.dt_control, goal=GOAL)
    with pytest.raises(ValueError, match=r"comes after step\(\) reached t = 0.2 s"):
        ctrl.observe([0], [[10.0, 3.0]], t=0.1)  # the sample the steps already passed


@pytest.mark.parametrize("t", [-5.0, np.nan, 1e9, 0.05])
def test_step_times_off_the_control_grid_are_refused(t) -> None:
    ctrl = _ctrl()
    ctrl.observe([0], [[10.0, 3.0]], t=0.0)
    ctrl.step(np.zeros(4), t=0.0, goal=GOAL)
    with pytest.raises(ValueError, match=r"step\(\)"):
        ctrl.step(np.zeros(4), t=t, goal=GOAL)


def test_a_repeated_observe_at_the_same_time_is_refused() -> None:
    ctrl = _ctrl()
    ctrl.observe([0], [[10.0, 3.0]], t=0.0)
    with pytest.raises(ValueError, match="already observed"):
        ctrl.observe([1], [[4.0, 0.0]], t=0.0)


@pytest.mark.parametrize("t", [np.nan, np.inf, 0.05])
def test_observe_times_off_the_sample_grid_are_refused(t) -> None:
    with pytest.raises(ValueError, match=r"observe\(\)"):
        _ctrl().observe([0], [[10.0, 3.0]], t=t)


def test_a_sample_far_ahead_of_the_control_clock_is_refused() -> None:
    ctrl = _ctrl()
    ctrl.observe([0], [[10.0, 3.0]], t=0.0)
    ctrl.step(np.zeros(4), t=0.0, goal=GOAL)
    with pytest.raises(ValueError, match="more than one interval"):
        ctrl.observe([0], [[10.0, 3.0]], t=1e9)
    ctrl.observe([0], [[10.0, 3.0]], t=0.3)  # a dropout of two samples is fine


@pytest.mark.parametrize(
    ("positions", "goal", "words"),
    [
        ([[1.0, 2.0, 3.0]], GOAL, "positions must be an"),
        ([[10.0, 3.0]], np.array([1.0, 2.0, 3.0]), "goal must be 2 finite"),
        ([[10.0, 3.0]], np.array([np.nan, 0.0]), "goal must be 2 finite"),
    ],
)
def test_shapes_are_checked(positions, goal, words) -> None:
    ctrl = _ctrl()
    with pytest.raises(ValueError, match=words):
        ctrl.observe([0], positions, t=0.0)
        ctrl.step(np.zeros(4), t=0.0, goal=goal)
