"""Decentralized multi-robot runs: equality with one robot, no communication, collisions."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from conformal_control.core.loop import ConformalStepper
from conformal_control.data.synthetic import SYNTHETIC_DEFAULTS
from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.predictors.constant_velocity import ConstantVelocityPredictor
from conformal_control.runs.build import build_flagship
from conformal_control.runs.episode import run_episode
from conformal_control.runs.fleet import (
    MAX_ROBOTS,
    load_robots_file,
    robot_tasks,
    run_multi,
)
from conformal_control.world.multi import MultiRobotWorld

#: Metrics that are timings, not results.
TIMINGS = {"wall_s"}


def _same_metrics(a: dict, b: dict) -> dict:
    return {k: (a[k], b[k]) for k in a if k not in TIMINGS and a[k] != b[k]}


@pytest.mark.parametrize("crowd", ["replay", "orca"])
def test_one_robot_equals_the_single_robot_episode(crossing, crowd):
    kw = {"crowd": crowd, "max_frames": 200 if crowd == "orca" else None}
    single = run_episode(crossing, record_animation=False, **kw)
    multi = run_multi(crossing, robots=1, record_animation=False, **kw)
    (robot,) = multi.robots
    assert _same_metrics(single.metrics.as_dict(), robot.metrics.as_dict()) == {}
    for key in ("x", "y", "vx", "vy", "d_min", "t"):
        np.testing.assert_array_equal(single.trajectory[key], robot.trajectory[key])
    assert [iv["lambda"] for iv in single.intervals] == [iv["lambda"] for iv in robot.intervals]
    assert multi.metrics.n_collide_robot_pairs == 0
    assert robot.contacts.d_min_robot is None


def test_one_robot_replay_reaches_goal_as_the_episode(crossing):
    # the equality above is not vacuous: the run does reach the goal with learning on
    multi = run_multi(crossing, robots=1, record_animation=False)
    m = multi.robots[0].metrics
    assert m.goal_reached and m.n_updates > 10


def test_explicit_tasks_equal_the_layout(crossing):
    s, g = robot_tasks(crossing, 3)
    a = run_multi(crossing, robots=3, max_frames=60, record_animation=False)
    b = run_multi(crossing, starts=s, goals=g, max_frames=60, record_animation=False)
    for ra, rb in zip(a.robots, b.robots, strict=True):
        assert _same_metrics(ra.metrics.as_dict(), rb.metrics.as_dict()) == {}


# -------------------------------------------------------------------- no communication
def _fleet(scene, starts, goals, seed=0, **params):
    fleet = [
        build_flagship(
            dataclasses.replace(scene, start=np.asarray(s), goals=np.asarray(g).reshape(-1, 2)),
            params,
            seed=seed + i,
        )
        for i, (s, g) in enumerate(zip(starts, goals, strict=True))
    ]
    env = fleet[0].env
    world = MultiRobotWorld(
        fleet[0].scene,
        np.asarray(starts, dtype=float),
        [np.asarray(g, dtype=float).reshape(-1, 2) for g in goals],
        [f.dynamics for f in fleet],
        tau_frames=env.tau_frames,
        substeps=env.substeps,
        sensing_radius=env.sensing_radius,
        history_frames=env.history_frames,
    )
    steppers = [ConformalStepper(f.family, f.loss, f.rule) for f in fleet]
    return world, steppers, fleet


def _drive(world, steppers, *, perturb_at=None, perturb=None, replay=None, max_intervals=40):
    """The run_multi loop, recording every robot's command; optionally perturb and replay
    one robot's commands from a previous run (so its positions are unchanged)."""
    world.reset()
    for st in steppers:
        st.start()
    n = len(steppers)
    log = []
    sensed = []
    k = 0
    while not world.done and k < max_intervals:
        if perturb_at is not None and k == perturb_at:
            perturb()
        active = [int(i) for i in world.active()]
        for i in active:
            query = world.sense(i)
            sensed.append((i, set(query.ids.tolist())))
            steppers[i].begin_interval(query)
        for _ in range(world.control_instants()):
            cmds = np.zeros((n, 2))
            for i in active:
                if not world.robot_done(i):
                    cmds[i] = steppers[i].decide(world.state(i))
            log.append(cmds.copy())
            if replay is not None:
                j, recorded = replay
                cmds[j] = recorded[len(log) - 1][j]
            world.apply(cmds)
            if world.done:
                break
        for i in active:
            steppers[i].end_interval(world.reveal(i))
        k += 1
    return np.array(log), sensed


def test_no_communication_other_robots_internal_state_does_not_matter(crossing):
    starts, goals = robot_tasks(crossing, 4, "antipodal", radius=6.0, center=(15.0, 8.0))
    world, steppers, _ = _fleet(crossing, starts, goals, sensing_radius=10.0)
    base, sensed = _drive(world, steppers)
    j = 2
    world2, steppers2, fleet2 = _fleet(crossing, starts, goals, sensing_radius=10.0)

    def perturb():
        # robot j gets another lambda (in its stepper and its rule) and another predictor
        steppers2[j].lam_ -= 7.0
        fleet2[j].rule.lambda_ = steppers2[j].lam_
        fleet2[j].family.predictor = ConstantVelocityPredictor(window=1)

    perturbed, _ = _drive(world2, steppers2, perturb_at=3, perturb=perturb, replay=(j, base))
    assert perturbed.shape == base.shape
    others = [i for i in range(4) if i != j]
    # robot j itself decides differently (the perturbation is real) ...
    assert not np.allclose(perturbed[:, j], base[:, j])
    # ... but with its positions unchanged, no other robot's decision moves by a bit
    np.testing.assert_array_equal(perturbed[:, others], base[:, others])
    # and the other robots do sense robot j after the perturbation
    rid = int(world2.robot_ids[j])
    assert sum(rid in ids for i, ids in sensed[4 * 4 :] if i != j) >= 10


def test_without_reciprocity_another_robot_is_an_agent_replaying_its_track(crossing):
    # reciprocity "none" (lambda on every row): robot 1's track, appended to the recording
    # as one more pedestrian, drives robot 0 alone (run_episode) exactly as robot 1 itself
    # did: robot 0 reads nothing else of it
    res = run_multi(
        crossing,
        robots=2,
        max_frames=150,
        record_animation=False,
        reciprocity="none",
        lambda_scope="both",
    )
    track = res.track["robots"][:, 1]
    k0 = crossing.start_index
    col = np.full((crossing.n_frames, 1, 2), np.nan)
    col[: k0 + 1, 0] = res.robots[1].start
    col[k0 : k0 + track.shape[0], 0] = track
    scene = dataclasses.replace(
        crossing,
        positions=np.concatenate([crossing.positions, col], axis=1),
        agent_ids=np.append(crossing.agent_ids, res.robots[1].id),
    )
    alone = run_episode(scene, max_frames=150, record_animation=False)
    r0 = res.robots[0]
    assert r0.contacts.d_min_robot < 4.0  # they did meet
    for key in ("x", "y", "vx", "vy"):
        np.testing.assert_array_equal(alone.trajectory[key], r0.trajectory[key])
    assert [iv["lambda"] for iv in alone.intervals] == [iv["lambda"] for iv in r0.intervals]


def test_robots_see_each_other_only_within_the_sensing_radius(line_scene, straight):
    scene = line_scene([straight((100.0, 100.0), (0.0, 0.0))])
    scene = dataclasses.replace(scene, defaults=dict(SYNTHETIC_DEFAULTS))
    starts = [(0.0, 0.0), (3.0, 0.0), (30.0, 0.0)]
    goals = [[(0.0, 40.0)], [(3.0, 40.0)], [(30.0, 40.0)]]
    world, _, _ = _fleet(scene, starts, goals, sensing_radius=5.0)
    world.reset()
    q0, q2 = world.sense(0), world.sense(2)
    assert q0.ids.tolist() == [int(world.robot_ids[1])]
    assert q2.ids.size == 0
    # the sensor types it as a robot; its history is its position where it stood (no
    # intent, no plan), and its future is unknown at the sampling time (NaN)
    assert q0.robot.tolist() == [True]
    np.testing.assert_array_equal(q0.history[0, -1], [3.0, 0.0])
    assert np.isnan(q0.future()).all()


def test_observed_history_masks_what_the_robot_did_not_see(line_scene, straight):
    # a pedestrian that walked in from far away: tracked history is complete, observed
    # history only covers the frames it was within the radius
    ped = straight((-20.0, 0.0), (3.0, 0.0), n=200)
    scene = line_scene([ped], start_index=20)
    kw = dict(tau_frames=4, substeps=2, sensing_radius=6.0, history_frames=20)
    dyn = VelocityTrackingDoubleIntegrator(K_acc=2.0)
    tracked = MultiRobotWorld(scene, [(0.0, 0.0)], [[(0.0, 50.0)]], dyn, **kw)
    observed = MultiRobotWorld(
        scene, [(0.0, 0.0)], [[(0.0, 50.0)]], dyn, sensor_history="observed", **kw
    )
    tracked.reset()
    observed.reset()
    # the pedestrian is at x = -20 + 0.3 f: at frame 60, at -2 (in range) after 20 frames
    # of which the first few were out of range
    for w in (tracked, observed):
        while w.frame_index < 60:
            w.apply(np.zeros((1, 2)))
    ht = tracked.sense(0).history[0]
    ho = observed.sense(0).history[0]
    assert np.isfinite(ht).all()
    dist = np.hypot(*(ht - [0.0, 0.0]).T)  # the robot has not moved
    np.testing.assert_array_equal(np.isfinite(ho[:, 0]), dist <= 6.0)
    assert 0 < np.isfinite(ho[:, 0]).sum() < ho.shape[0]


# -------------------------------------------------------------------- collisions
def test_robot_robot_and_robot_pedestrian_collisions_are_counted_apart(line_scene, straight):
    # robot 0 walks into a pedestrian coming the other way along the same line;
    # robots 1 and 2 are driven head-on into each other far from every pedestrian; a
    # sensing radius of 1 cm keeps every robot blind, so nothing is avoided
    ped = straight((0.0, 30.0), (0.0, -1.3), n=400)
    scene = line_scene([ped], start_index=5)
    starts = [(0.0, 0.0), (50.0, 0.0), (62.0, 0.0)]
    goals = [[(0.0, 60.0)], [(80.0, 0.0)], [(30.0, 0.0)]]
    res = run_multi(
        scene,
        starts=starts,
        goals=goals,
        params={
            "sensing_radius": 0.01,
            "rho0": 0.01,
            "tau": 4,
            "a": 1.0,
            "eta": 0.0,
            "epsilon": 0.0,
            "K_rep": 1.0,
            "K_att": 0.05,
            "K_acc": 2.0,
            "loss_scale": 1.0,
        },
        max_frames=300,
        record_animation=False,
    )
    r0, r1, r2 = res.robots
    assert r0.metrics.n_collide > 0 and r0.contacts.n_collide_robot == 0
    for r in (r1, r2):
        assert r.contacts.n_collide_robot > 0 and r.metrics.n_collide == 0
        assert not r.metrics.success
    assert r1.contacts.n_collide_robot == r2.contacts.n_collide_robot
    fleet = res.metrics
    assert fleet.n_collide_pedestrian == r0.metrics.n_collide
    # each pair-frame once: robots 1 and 2 touch in the same frames
    assert fleet.n_collide_robot_pairs == r1.contacts.n_collide_robot
    assert fleet.n_robots_hit_robot == 2 and fleet.n_robots_hit_pedestrian == 1
    assert fleet.d_min_robot < 2 * res.scene.robot_radius
    assert fleet.d_min_pedestrian < res.scene.collision_distance


def test_seeing_each_other_robots_avoid_a_head_on_collision(crossing):
    # the same head-on swap as above but with the flagship's sensor: no contact
    res = run_multi(crossing, robots=2, record_animation=False, crowd="orca", max_frames=400)
    assert res.metrics.n_collide_robot_pairs == 0
    assert res.metrics.d_min_robot > 2 * res.scene.robot_radius


# -------------------------------------------------------------------- determinism, outputs
def test_runs_are_deterministic_with_a_seed(crossing):
    kw = dict(robots=4, crowd="social_force", max_frames=120, seed=3, record_animation=False)
    a, b = run_multi(crossing, **kw), run_multi(crossing, **kw)
    for ra, rb in zip(a.robots, b.robots, strict=True):
        assert _same_metrics(ra.metrics.as_dict(), rb.metrics.as_dict()) == {}
        np.testing.assert_array_equal(ra.steps["x"], rb.steps["x"])
    np.testing.assert_array_equal(a.track["robots"], b.track["robots"])


def test_layouts(crossing):
    s, g = robot_tasks(crossing, 1)
    np.testing.assert_array_equal(s[0], crossing.start)
    np.testing.assert_array_equal(g[0], crossing.goals)
    s, g = robot_tasks(crossing, 4, "antipodal", radius=5.0, center=(15.0, 8.0))
    np.testing.assert_allclose(np.hypot(*(s - [15.0, 8.0]).T), 5.0)
    np.testing.assert_allclose([gi[0] for gi in g], 2 * np.array([15.0, 8.0]) - s)
    with pytest.raises(ValueError, match="from 1 to"):
        robot_tasks(crossing, MAX_ROBOTS + 1)
    with pytest.raises(ValueError, match="unknown layout"):
        robot_tasks(crossing, 2, "grid")


def test_robots_file(tmp_path, crossing):
    f = tmp_path / "robots.json"
    f.write_text(
        json.dumps(
            {
                "units": "fraction",
                "robots": [
                    {"start": [0.1, 0.5], "goals": [[0.9, 0.5], [0.9, 0.9]]},
                    {"start": [0.9, 0.5], "goal": [0.1, 0.5]},
                ],
            }
        )
    )
    s, g = load_robots_file(f, crossing)
    np.testing.assert_allclose(s, [[3.0, 8.0], [27.0, 8.0]])
    np.testing.assert_allclose(g[0], [[27.0, 8.0], [27.0, 14.4]])
    f.write_text(json.dumps({"robots": [{"start": [1, 2]}]}))
    with pytest.raises(ValueError, match='needs "start" and "goals"'):
        load_robots_file(f, crossing)
    f.write_text("{oops")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_robots_file(f, crossing)


def test_run_directory(tmp_path, crossing):
    res = run_multi(crossing, robots=3, max_frames=40, seed=5)
    out = res.save(tmp_path / "run")
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["kind"] == "multi" and cfg["n_robots"] == 3
    assert [r["seed"] for r in cfg["robots"]] == [5, 6, 7]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["fleet"]["n_robots"] == 3 and len(metrics["robots"]) == 3
    for i in range(3):
        m = json.loads((out / "robots" / f"robot_{i:02d}" / "metrics.json").read_text())
        assert m["n_steps"] == res.robots[i].metrics.n_steps
    rows = (out / "trajectories.csv").read_text().splitlines()
    assert len(rows) == 1 + 3 * res.track["frame"].size
    rec = np.load(out / "animation.npz")
    assert str(rec["kind"]) == "multi" and rec["robots"].shape[1] == 3


def test_bad_input(crossing):
    with pytest.raises(ValueError, match="starts need"):
        run_multi(crossing, starts=[(0, 0), (1, 1)], goals=[(2, 2)])
    with pytest.raises(ValueError, match="either explicit starts"):
        run_multi(crossing, starts=[(0, 0)], goals=[(2, 2)], layout="antipodal")
    with pytest.raises(ValueError, match="sensor_history"):
        run_multi(crossing, robots=2, sensor_history="psychic", max_frames=5)


def test_prepare_fleet_gives_the_scene_and_the_robots_section(tmp_path):
    # the fleet's preparation `run --robots` did in the command line: the scene loaded with
    # the run's seed, the tasks from a robots file or the layout's centre in metres
    from conformal_control.core.spec import RunSpec
    from conformal_control.data import load_scene
    from conformal_control.runs.fleet import prepare_fleet

    base = RunSpec(seed=3, max_frames=20)
    scene, spec = prepare_fleet("crossing", base, robots=2, layout="antipodal", center="0.5,0.5")
    expected = load_scene("crossing", seed=3)
    np.testing.assert_array_equal(scene.positions, expected.positions)
    assert spec.robots is not None and spec.robots.robots == 2
    assert spec.robots.layout == "antipodal" and spec.robots.center == (15.0, 8.0)
    assert spec.max_frames == 20 and spec.seed == 3
    f = tmp_path / "robots.json"
    f.write_text(json.dumps({"robots": [{"start": [1, 2], "goal": [20, 2]}]}))
    _, spec = prepare_fleet(scene, base, robots_file=f, layout="scene", radius=None)
    np.testing.assert_array_equal(spec.robots.starts, [[1.0, 2.0]])
    assert spec.robots.layout == "scene"
    with pytest.raises(ValueError, match="--robots-file gives the tasks"):
        prepare_fleet(scene, base, robots_file=f, layout="antipodal")
    with pytest.raises(ValueError, match="--robots-file gives the tasks"):
        prepare_fleet(scene, base, robots_file=f, center="0.5,0.5")
