"""The acp family: adaptive conformal prediction regions inflating the CBF barrier."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conformal_control.core import registry
from conformal_control.core.loop import ConformalLoop
from conformal_control.core.update_rules import ACIRule
from conformal_control.data.scene import scene_from_tracks
from conformal_control.data.tracks import Tracks
from conformal_control.data.units import SI
from conformal_control.families.cbf import (
    APFBarrier,
    AttractiveField,
    ConformalCBFController,
    ConformalConstraint,
    QPSafetyFilter,
)
from conformal_control.families.cbf.acp import ACPController, ACPMiscoverageLoss, region_radii
from conformal_control.families.cbf.controller import ControlState
from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.predictors import ConstantVelocityPredictor
from conformal_control.runs.params import resolve_params
from conformal_control.world.replay import ReplayEnvironment


def _acp_from(controller, **params):
    """The acp family built from the parts of a conformal CBF controller."""
    parts = ("predictor", "constraint", "safety_filter", "reference", "substeps")
    return ACPController(**{k: getattr(controller, k) for k in parts}, **params)


def _acp_run(
    scene, *, alpha=0.1, gamma=0.05, learn=True, lam0=None, max_frames=None, params=None, **kw
):
    """Wire the acp family from the flagship's parts (the scene's parameters) and run it."""
    p = resolve_params(scene, dict(params or {}))
    si = p.si
    scene = dataclasses.replace(scene, v_max=si["v_max"])
    controller = ConformalCBFController(
        ConstantVelocityPredictor(),
        ConformalConstraint(
            APFBarrier(K_rep=si["K_rep"], rho0=si["rho0"], d_c=scene.collision_distance),
            a=si["a"],
        ),
        QPSafetyFilter(v_max=si["v_max"]),
        AttractiveField(K_att=si["K_att"], v_max=si["v_max"]),
        substeps=si["substeps"],
    )
    family = _acp_from(controller, **kw)
    env = ReplayEnvironment(
        scene,
        VelocityTrackingDoubleIntegrator(K_acc=si["K_acc"]),
        tau_frames=p.tau_frames,
        substeps=si["substeps"],
        sensing_radius=si["sensing_radius"],
        history_frames=p.history_frames,
        max_frames=max_frames,
    )
    rule = ACIRule(alpha=alpha, gamma=gamma, lambda_init=lam0)
    result = ConformalLoop(env, family, ACPMiscoverageLoss(), rule, learn=learn).run()
    traj = env.log.arrays()
    n_collide = int(np.sum(traj["d_min"] < scene.collision_distance))
    return result, family, env, traj, n_collide


def test_loss_is_registered_and_monotone_in_lambda() -> None:
    assert registry.get("loss", "acp_miscoverage") is ACPMiscoverageLoss
    loss = ACPMiscoverageLoss()
    record, truth = ACPMiscoverageLoss._unit_test_inputs()[0]
    lams = np.linspace(-0.5, 1.5, 41)
    values = [loss(record, truth, lam) for lam in lams]
    assert all(np.diff(values) >= 0)
    assert values[0] == 0.0  # lambda <= 0: regions are the whole plane
    assert values[-1] == 1.0  # lambda >= 1: regions are empty
    # by hand: errors of the 4 agents x 3 steps against the step quantiles at lambda
    err = np.linalg.norm(truth.samples[:, 1:] - record.pred_samples, axis=-1)
    radii = region_radii(record.sorted_scores, 0.3)
    assert loss(record, truth, 0.3) == pytest.approx(np.mean(err > radii[None, :]))


def test_region_radii_are_conformal_quantiles() -> None:
    scores = (np.arange(1.0, 20.0), np.arange(1.0, 20.0) * 2)
    # n = 19, lambda = 0.1: the ceil(20 * 0.9) = 18th smallest score
    np.testing.assert_allclose(region_radii(scores, 0.1), [18.0, 36.0])
    assert np.all(np.isinf(region_radii(scores, 0.0)) & (region_radii(scores, 0.0) > 0))
    assert np.all(region_radii(scores, 1.0) == -np.inf)
    assert np.isinf(region_radii((np.zeros(3),), 0.1)[0])  # too few scores: everything


def test_missing_truth_is_left_out() -> None:
    loss = ACPMiscoverageLoss()
    record, truth = ACPMiscoverageLoss._unit_test_inputs()[1]
    d = loss.diagnostics(record, truth, 0.2)
    assert d["n_truth_missing"] == 2 and d["n_pairs"] == 10
    empty_record, empty_truth = ACPMiscoverageLoss._unit_test_inputs()[3]
    assert loss(empty_record, empty_truth, 0.2) is None


def test_inflation_enters_the_barrier_as_collision_distance_and_slack_is_zero() -> None:
    barrier = APFBarrier(K_rep=0.5, rho0=5.0, d_c=0.7)
    fam = ACPController(
        ConstantVelocityPredictor(),
        ConformalConstraint(barrier, a=2.0),
        registry.create("safety_filter", "qp", v_max=2.0),
        registry.create("reference", "attractive_field", K_att=1.0, v_max=2.0),
        substeps=2,
        max_inflation=0.8,
    )
    fam.reset()
    fam._ids = np.array([7])
    fam._xp = np.array([[[3.0, 0.0]], [[3.0, 0.1]], [[3.0, 0.2]], [[3.0, 0.3]]])
    fam._vp = np.zeros((4, 1, 2))
    fam._sorted = (np.linspace(0.0, 0.2, 99), np.linspace(0.0, 0.4, 99))
    state = ControlState(np.zeros(4), 0.0, 2, np.array([10.0, 0.0]))  # step 2 -> horizon 2
    A, b = fam.constraint_rows(state, 0.1)
    c2 = region_radii(fam._sorted, 0.1)[1]
    expected = ConformalConstraint(APFBarrier(K_rep=0.5, rho0=5.0, d_c=0.7 + c2), a=2.0)
    A2, b2 = expected.rows(np.zeros(2), fam._xp[2], fam._vp[2])
    np.testing.assert_allclose(A, A2)
    np.testing.assert_allclose(b, b2)
    assert fam.slack(0.1) == 0.0
    # lambda <= 0: infinite region, capped at max_inflation (and counted)
    _, b0 = fam.constraint_rows(state, -0.2)
    capped = ConformalConstraint(APFBarrier(K_rep=0.5, rho0=5.0, d_c=1.5), a=2.0)
    np.testing.assert_allclose(b0, capped.rows(np.zeros(2), fam._xp[2], fam._vp[2])[1])
    assert fam.n_capped_ == 1
    assert barrier.d_c == 0.7  # the shared barrier is never modified


def test_barrier_without_collision_distance_is_a_clear_error() -> None:
    class Plain(APFBarrier):
        def __init__(self, K_rep: float = 1.0) -> None:
            self.K_rep = K_rep
            self.rho0, self.d_c, self.convention, self.delta = 10.0, 1.0, "surface", None

    fam = ACPController(
        ConstantVelocityPredictor(),
        ConformalConstraint(Plain()),
        registry.create("safety_filter", "qp"),
        registry.create("reference", "attractive_field"),
    )
    with pytest.raises(ValueError, match="no d_c parameter"):
        fam.reset()


def _wandering_scene(seed: int = 0, duration: float = 120.0, fps: float = 10.0):
    """Agents wandering around a nearly static robot with heavy-tailed (Student t) velocity
    noise that is 2.5 times larger in the second half (a shift ACI must follow)."""
    rng = np.random.default_rng(seed)
    n = round(duration * fps)
    sigma = np.where(np.arange(n) < n // 2, 0.6, 1.5)[:, None]
    tracks = {}
    for i in range(6):
        noise = rng.standard_t(3, (n, 2)) * sigma / fps * 4
        v = np.zeros(2)
        p = rng.uniform(-4.0, 4.0, 2)
        xy = np.empty((n, 2))
        for k in range(n):
            v = np.clip(0.8 * v + noise[k], -1.5, 1.5)
            p = np.clip(p + v / fps, -4.5, 4.5)
            xy[k] = p
        tracks[i] = (np.arange(n), xy + np.array([20.0, 20.0]))
    data = Tracks(fps, tracks, source="wandering")
    return scene_from_tracks(
        data,
        name="wandering",
        start=np.array([20.0, 20.0]),
        goals=np.array([[200.0, 20.0]]),
        start_frame=20,
        v_max=0.02,
        history_frames=20,
        units=SI,
        defaults={
            "a": 2.0,
            "K_acc": 10.0,
            "K_rep": 0.5,
            "K_att": 1.0,
            "rho0": 8.0,
            "tau": 0.4,
            "eta": 1.0,
            "epsilon": 0.0,
            "loss_scale": 1.0,
        },
        robot_radius=0.3,
        agent_radius=0.3,
    )


def test_long_run_miscoverage_is_within_acis_bound_of_alpha() -> None:
    scene = _wandering_scene()
    alpha, gamma = 0.1, 0.05
    res, fam, _, _, _ = _acp_run(scene, alpha=alpha, gamma=gamma, params={"substeps": 1})
    losses = res.losses
    lams = np.array([iv.lam for iv in res.intervals])
    assert losses.size > 250 and fam.n_scored_ > 4000
    bound = res.monitor.rule.long_run_bound(losses.size, [*res.lambdas, res.lambda_final])
    gap = abs(losses.mean() - alpha)
    assert gap <= bound
    # the identity behind the bound, exactly: mean loss - alpha = (lam_1 - lam_K+1) / (gamma K)
    assert losses.mean() - alpha == pytest.approx(
        (lams[0] - res.lambda_final) / (gamma * losses.size), abs=1e-12
    )
    assert np.all((lams >= -gamma - 1e-12) & (lams <= 1 + gamma + 1e-12))
    # not only within the (loose) bound: close to alpha, before and after the shift
    half = losses.size // 2
    assert abs(losses[:half].mean() - alpha) < 0.05
    assert abs(losses[half:].mean() - alpha) < 0.05
    # the regions followed the shift: larger radii in the noisier half
    infl = [
        d["mean_finite_radius"]
        for d in (iv.diagnostics for iv in res.updates)
        if "mean_finite_radius" in d
    ]
    assert np.mean(infl[-50:]) > 1.3 * np.mean(infl[20:70])


def test_without_learning_the_level_stays_and_coverage_drifts() -> None:
    scene = _wandering_scene(seed=1)
    res, *_ = _acp_run(scene, alpha=0.1, gamma=0.05, learn=False, params={"substeps": 1})
    lams = {iv.lam for iv in res.intervals}
    assert lams == {0.1}
    # a fixed level does not track the shift: the noisy half misses more than the calm one
    half = res.losses.size // 2
    assert res.losses[half:].mean() > res.losses[:half].mean()


def test_end_to_end_on_crossing_larger_regions_keep_the_robot_further(crossing) -> None:
    res, fam, env, _, _ = _acp_run(crossing, alpha=0.1, gamma=0.05)
    assert env.goal_reached and res.n_updates > 20
    assert fam.n_scored_ > 100
    assert abs(res.monitor.identity_residual) < 1e-9
    # lambda fixed at 0 (whole-plane regions: inflation = max_inflation) vs 1 (no inflation)
    _, _, _, wide, _ = _acp_run(crossing, learn=False, lam0=0.0, max_inflation=0.5)
    _, _, _, none, _ = _acp_run(crossing, learn=False, lam0=1.0)
    assert np.nanmin(wide["d_min"]) > np.nanmin(none["d_min"]) + 0.3


@pytest.mark.data
def test_end_to_end_on_an_sdd_scenario_of_the_suite(data_root) -> None:
    from conformal_control.experiments.bench import load_scenario, load_suite

    suite = load_suite("crossings-v1")
    sc = next(s for s in suite.scenarios if s.source == "sdd" and s.collided_nolearn)
    scene = load_scenario(sc, data_root)
    res, fam, _, traj, _ = _acp_run(scene, alpha=0.1, gamma=0.05, max_frames=sc.max_frames)
    assert len(traj["frame"]) <= sc.max_frames + 1
    assert traj["frame"][0] == sc.start_frame
    assert res.n_updates > 10 and fam.n_scored_ > 0
    assert abs(res.monitor.identity_residual) < 1e-9
    infl = [iv.diagnostics.get("mean_inflation", 0.0) for iv in res.updates]
    assert max(infl) > 0.0
    assert 0.0 <= res.l_avg <= 1.0
