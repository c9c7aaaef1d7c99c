"""The sampling MPC with robot peers: shared lines, and two planners that pass each other."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.cbf.reciprocal import PeerView, Reciprocity
from conformal_control.cbf.reference import AttractiveField
from conformal_control.cbf.safety_losses import DistanceShortfallLoss
from conformal_control.data.scene import Scene
from conformal_control.data.synthetic import SYNTHETIC_DEFAULTS
from conformal_control.loop import ConformalStepper
from conformal_control.mpc.controller import SamplingMPC
from conformal_control.mpc.peers import peer_clearance, peer_lines, reference_paths
from conformal_control.mpc.settings import Limits, Sampling
from conformal_control.predictors.constant_velocity import ConstantVelocityPredictor
from conformal_control.sim.multi import drive
from conformal_control.update_rules.fixed_eta import FixedEtaRule
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
