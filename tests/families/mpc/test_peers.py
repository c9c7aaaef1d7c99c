"""The sampling MPC with robot peers: shared lines, and two planners that pass each other."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.core.loop import ConformalStepper
from conformal_control.core.update_rules.fixed_eta import FixedEtaRule
from conformal_control.data.scene import Scene
from conformal_control.data.synthetic import SYNTHETIC_DEFAULTS
from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.families.cbf.reciprocal import PeerView, Reciprocity
from conformal_control.families.cbf.reference import AttractiveField
from conformal_control.families.cbf.safety_losses import DistanceShortfallLoss
from conformal_control.families.mpc.controller import SamplingMPC
from conformal_control.families.mpc.peers import (
    between_steps,
    near_steps,
    peer_clearance,
    peer_lines,
    peer_terms,
    reference_paths,
)
from conformal_control.families.mpc.settings import Limits, Sampling
from conformal_control.predictors.constant_velocity import ConstantVelocityPredictor
from conformal_control.runs.fleet import drive
from conformal_control.world.multi import MultiRobotWorld


@pytest.mark.parametrize("information", ["position", "velocity"])
def test_the_two_robots_lines_coincide_and_their_sides_are_apart(information):
    rng = np.random.default_rng(0)
    for _ in range(20):
        x = rng.uniform(-3, 3, (2, 4))
        s_ij = float(rng.uniform(0.2, 0.8))
        times = np.linspace(0.2, 2.0, 6)
        views = []
        for me, other, share in ((0, 1, s_ij), (1, 0, 1.0 - s_ij)):
            ref = None if information == "position" else x[[other], 2:]
            own = None if information == "position" else x[me, 2:].copy()
            views.append(
                PeerView(
                    np.array([other]), x[[other], :2], np.array([share]), information, ref, own
                )
            )
        lines = []
        for me, v in enumerate(views):
            own, peers = reference_paths(v, x[me], times, 0.0)
            lines.append(peer_lines(v, own, peers, 0.4))
        (n0, o0), (n1, o1) = lines
        np.testing.assert_allclose(n0, -n1, atol=1e-12)
        # a point meeting robot 0's line and one meeting robot 1's are 2 buffers apart at
        # least along the normal: o0 + o1 = -2 buffer
        np.testing.assert_allclose(o0 + o1, -0.8, atol=1e-9)


def _path(rng, t0, h=7, dt=0.4):
    return t0 + dt * np.arange(1, h + 1), rng.uniform(-3, 3, (h, 2))


def test_with_broadcast_plans_both_robots_draw_the_same_lines():
    # each robot reads the other's broadcast path *and its own*: the two robots' lines are
    # one line (before, a robot extrapolated its own position at its broadcast velocity
    # while its peer read its broadcast path, so the two lines differed)
    rng = np.random.default_rng(1)
    for _ in range(20):
        x = rng.uniform(-3, 3, (2, 4))
        paths = [_path(rng, -0.1), _path(rng, -0.1)]
        v = rng.uniform(-1, 1, (2, 2))
        s_ij = float(rng.uniform(0.2, 0.8))
        times = paths[0][0][:6]  # the paths' own times
        lines = []
        for me, other, share in ((0, 1, s_ij), (1, 0, 1.0 - s_ij)):
            view = PeerView(
                np.array([other]), x[[other], :2], np.array([share]), "plan",
                v[[other]], v[me].copy(), (paths[other],), paths[me],
            )  # fmt: skip
            own, peers = reference_paths(view, x[me], times, 0.0)
            np.testing.assert_allclose(peers[0], paths[other][1][:6])
            np.testing.assert_allclose(own, paths[me][1][:6])
            lines.append(peer_lines(view, own, peers, 0.4))
        (n0, o0), (n1, o1) = lines
        np.testing.assert_allclose(n0, -n1, atol=1e-12)
        np.testing.assert_allclose(o0 + o1, -0.8, atol=1e-9)


def test_the_lines_bind_only_the_near_horizon():
    assert near_steps(0.4, 12, None) == 12
    assert near_steps(0.4, 12, 1.2) == 3
    assert near_steps(0.4, 12, 0.1) == 1  # at least the first step
    assert near_steps(0.4, 12, 100.0) == 12

    class Fam:
        d_c, margin = 0.7, 0.0
        sampling = Sampling(n_samples=10, horizon=4, dt_plan=0.5)

    class State:
        t = 0.0
        x = np.zeros(4)
        peers = PeerView(np.array([7]), np.array([[3.0, 0.0]]), np.array([0.5]), "position")

    # a plan crossing the line (x = 1.5 - 0.35) only at its last step
    plan = np.array([[[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [2.0, 0.0]]])
    fam = Fam()
    fam.reciprocity = Reciprocity("reciprocal", peer_horizon=None)  # the whole plan
    clear, viol = peer_terms(fam, State(), 0.0, plan)
    assert clear[0] < 0 and viol[0] > 0
    assert Reciprocity("reciprocal").peer_horizon == 1.2  # the default near horizon
    fam.reciprocity = Reciprocity("reciprocal", peer_horizon=1.5)
    clear, viol = peer_terms(fam, State(), 0.0, plan)
    np.testing.assert_allclose(clear, [1.15 - 1.0])
    assert viol[0] == 0.0
    with pytest.raises(ValueError, match="peer_horizon"):
        Reciprocity("reciprocal", peer_horizon=0.0).validate()


def test_the_lines_bind_between_plan_steps_too():
    # two robots swapping sides in one plan step (issue 36, gates 4 random: the pair came
    # within 0.68 m with both plans meeting every line): the robot at (0, 0) goes to
    # (1, 1) in the first step, its peer at (1, 0) to (0, 0.8) -- at every plan step the
    # robot's plan is 0.11 m clear of the line (buffer 0.4 m), but halfway through the
    # first step the two references are 0.1 m apart and the plan is 0.35 m over the line
    class Fam:
        d_c, margin = 0.8, 0.0
        sampling = Sampling(n_samples=10, horizon=4, dt_plan=0.4)
        reciprocity = Reciprocity("reciprocal", peer_horizon=1.2)

    class State:
        t = 0.0
        x = np.zeros(4)
        peers = PeerView(
            np.array([7]), np.array([[1.0, 0.0]]), np.array([0.5]), "velocity",
            np.array([[-2.5, 2.0]]), np.array([2.5, 2.5]),
        )  # fmt: skip

    plan = np.array([[[1.0, 1.0], [2.0, 2.0], [3.0, 3.0], [4.0, 4.0]]])  # its references
    clear, viol = peer_terms(Fam(), State(), 0.0, plan)
    np.testing.assert_allclose(clear, [-0.35], atol=1e-12)
    assert viol[0] > 0.0
    # at the plan steps alone it was clear (the lines there, as before)
    own, peers = reference_paths(State.peers, State.x, np.array([0.4, 0.8, 1.2]), 0.0)
    normal, offset = peer_lines(State.peers, own, peers, 0.4)
    assert peer_clearance(plan[:, :3], normal, offset)[0][0] > 0.1
    # the halfway points: from the position now, before each step
    got = between_steps(plan[:, :2], np.array([0.0, 0.0]))
    np.testing.assert_allclose(got[0], [[0.5, 0.5], [1.0, 1.0], [1.5, 1.5], [2.0, 2.0]])


def test_the_lines_give_way_before_the_pedestrians():
    # three candidate plans: A crosses the peer's line and keeps the pedestrian's safe
    # distance, B keeps the line and enters the pedestrian's, C does both a little.
    # Pedestrians first: A ("peer_yield"); with every plan intruding on the pedestrian,
    # least_violation ranks the pedestrian's intrusion first
    mpc = SamplingMPC(
        ConstantVelocityPredictor(), VelocityTrackingDoubleIntegrator(K_acc=10.0),
        AttractiveField(K_att=1.0, v_max=1.0), sampling=Sampling(n_samples=3, horizon=2),
        d_c=0.7, fallback="least_violation",
    )  # fmt: skip
    mpc.reciprocity = Reciprocity("reciprocal", priority="pedestrians")
    mpc.reset()

    class State:
        t = 0.0
        x = np.zeros(4)
        peers = PeerView(np.array([7]), np.array([[3.0, 0.0]]), np.array([0.5]), "position")

    from conformal_control.families.mpc.controller import PlanInputs

    pos = np.array([[[1.6, 0.0], [1.6, 0.0]], [[0.0, 0.0], [0.0, 0.0]], [[1.3, 0.0], [1.3, 0.0]]])
    todo = PlanInputs(State(), 0.0, np.zeros((3, 2, 2)), pos, ())
    cost = np.array([3.0, 1.0, 2.0])
    plan = mpc.plan_end(todo, cost, np.array([0.2, -0.3, -0.1]), np.array([0.0, 0.3, 0.1]))
    assert plan.status == "peer_yield" and plan.cost == 3.0
    assert mpc.stats()["n_peer_yield"] == 1 and mpc.stats()["n_infeasible"] == 0
    plan = mpc.plan_end(todo, cost, np.array([-0.2, -0.3, -0.1]), np.array([0.2, 0.3, 0.1]))
    assert plan.status == "least_violation" and plan.cost == 2.0  # C: least pedestrian
    plan = mpc.plan_end(todo, cost, np.array([-0.1, -0.3, -0.1]), np.array([0.1, 0.3, 0.1]))
    assert plan.cost == 2.0  # A and C tie on the pedestrian: C crosses the line less
    # priority "robots": one problem, no order -- the least summed intrusion (B)
    mpc.reciprocity = Reciprocity("reciprocal", priority="robots")
    plan = mpc.plan_end(todo, cost, np.array([0.2, -0.3, -0.1]), np.array([0.0, 0.3, 0.1]))
    assert plan.status == "least_violation" and plan.cost == 1.0


def test_clearance_is_the_smallest_margin_to_the_lines():
    normal = np.array([[[1.0, 0.0], [1.0, 0.0]]])
    offset = np.array([[1.0, 0.5]])
    plans = np.array([[[0.0, 0.0], [0.0, 0.0]], [[2.0, 0.0], [0.0, 0.0]]])
    clear, viol = peer_clearance(plans, normal, offset)
    np.testing.assert_allclose(clear, [0.5, -1.0])
    np.testing.assert_allclose(viol, [0.0, 1.0])


def _free_scene() -> Scene:
    pos = np.full((400, 1, 2), np.nan)
    pos[:, 0] = [500.0, 500.0]
    return Scene(
        name="free",
        fps=10.0,
        first_frame=0,
        start_index=20,
        positions=pos,
        agent_ids=np.array([1]),
        start=np.zeros(2),
        goals=np.array([[10.0, 0.0]]),
        v_max=1.0,
        robot_radius=0.4,
        agent_radius=0.3,
        defaults=dict(SYNTHETIC_DEFAULTS),
    )


def _run(mode, information, starts, goals):
    dyn = VelocityTrackingDoubleIntegrator(K_acc=10.0)
    steppers = []
    for i in range(2):
        p = SamplingMPC(
            ConstantVelocityPredictor(),
            dyn,
            AttractiveField(K_att=1.0, v_max=1.0),
            sampling=Sampling(n_samples=150, horizon=8, dt_plan=0.3),
            d_c=0.7,
            limits=Limits(v_max=1.0),
            substeps=2,
            random_state=i,
        )
        if mode is not None:
            p.reciprocity = Reciprocity(mode, "pedestrians", robot_margin=0.1)
        steppers.append(
            ConformalStepper(p, DistanceShortfallLoss(2.0, 0.8), FixedEtaRule(epsilon=0.1))
        )
    world = MultiRobotWorld(
        _free_scene(),
        np.array(starts, dtype=float),
        [np.array(g, dtype=float).reshape(-1, 2) for g in goals],
        dyn,
        tau_frames=4,
        substeps=2,
        sensing_radius=10.0,
        information=information,
        max_frames=250,
    )
    drive(world, steppers, broadcast=information == "plan")
    x = world.robot_track()[20 : world.frame_index + 1]
    return float(np.nanmin(np.hypot(*(x[:, 0] - x[:, 1]).T))), world


@pytest.mark.parametrize("information", ["position", "velocity", "plan"])
def test_two_planners_sharing_lines_pass_each_other(information):
    starts, goals = [(-6.0, 0.0), (6.0, 0.0)], [[(6.0, 0.0)], [(-6.0, 0.0)]]
    d, world = _run("reciprocal", information, starts, goals)
    assert d > 0.8  # two robot radii
    assert all(r.t_goal_ is not None for r in world.robots)


def test_without_reciprocity_two_planners_predicting_each_other_collide():
    # the contrast: each predicts the other at constant velocity and plans against it
    starts, goals = [(-6.0, 0.0), (6.0, 0.0)], [[(6.0, 0.0)], [(-6.0, 0.0)]]
    d, _ = _run(None, None, starts, goals)
    assert d < 0.8
