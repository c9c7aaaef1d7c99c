"""acp_mpc: prediction errors scored per plan step, regions, miscoverage loss."""

from __future__ import annotations

import math

import numpy as np

from conformal_control.core.loop import ConformalLoop
from conformal_control.core.update_rules import ACIRule
from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.families.mpc import ACPMPC, Limits, PlanMiscoverageLoss, Sampling
from conformal_control.predictors.base import Forecast, PredictionQuery, Predictor

DT = 0.4


class Frozen(Predictor):
    """Every agent stays where it is (an error of speed x time)."""

    def predict(self, query: PredictionQuery) -> Forecast:
        return Forecast(np.repeat(query.current[:, None, :], query.horizon, axis=1))


def observation(k: int, speeds: np.ndarray, history: int = 30) -> PredictionQuery:
    """Agents j moving along x at speeds[j] since t = -history dt, observed at t = k dt."""
    t = k * DT
    times = t - DT * np.arange(history - 1, -1, -1)
    hist = np.stack(
        [np.stack([s * times, np.full_like(times, 3.0 + j)], -1) for j, s in enumerate(speeds)]
    )
    return PredictionQuery(
        ids=np.arange(len(speeds)), history=hist, dt=DT, horizon=1, t=t, frame=k, scene="t"
    )


def family(**kw) -> ACPMPC:
    params = {
        "predictor": Frozen(),
        "dynamics": VelocityTrackingDoubleIntegrator(10.0),
        "sampling": Sampling(n_samples=30, horizon=4, dt_plan=DT),
        "substeps": 1,
        "max_inflation": 5.0,
    }
    params.update(kw)
    fam = ACPMPC(**params)
    fam.reset()
    return fam


def test_errors_are_scored_per_plan_step_when_their_target_time_has_passed():
    speeds = np.array([0.5, 1.5])
    fam = family()
    for k in range(6):
        fam.begin_interval(observation(k, speeds))
    # a frozen prediction made at t is off by speed * h dt at step h; by t = 5 dt every
    # step of the predictions made at 0 and 1 dt (and the early steps of later ones) is in
    for h in range(1, 5):
        expected = sorted(np.repeat(speeds * h * DT, 6 - h))
        np.testing.assert_allclose(sorted(fam.scores_[h - 1]), expected, rtol=1e-12)
    assert fam.n_scored_ == sum(2 * (6 - h) for h in range(1, 5))
    assert fam.n_unscored_ == 0


def test_agents_that_left_and_targets_older_than_the_history_are_counted_not_guessed():
    fam = family()
    fam.begin_interval(observation(0, np.array([1.0, 1.0])))
    gone = observation(3, np.array([1.0]))  # agent 1 is no longer sensed
    fam.begin_interval(gone)
    assert fam.n_unscored_ == 3  # its steps 1..3
    fam2 = family()
    fam2.begin_interval(observation(0, np.array([1.0])))
    fam2.begin_interval(observation(8, np.array([1.0]), history=2))  # 0.4 s of history
    assert fam2.n_scored_ == 0 and fam2.n_unscored_ == 4


def test_the_safe_distance_grows_with_the_regions():
    fam = family(d_c=1.0, margin=0.1)
    for k in range(8):
        fam.begin_interval(observation(k, np.array([0.5, 1.0, 1.5])))
    r_low, r_high = fam.safe_radius(0.05), fam.safe_radius(0.6)
    assert (r_low >= r_high).all() and (r_low > r_high).any()
    assert (np.diff(r_low) >= 0).all()  # later steps, larger errors, larger regions
    np.testing.assert_allclose(fam.safe_radius(1.0), 1.1)  # empty regions
    np.testing.assert_allclose(fam.safe_radius(0.0), 1.1 + 5.0)  # unbounded: capped


def test_loss_is_the_miscoverage_of_out_of_sample_errors_and_monotone():
    loss = PlanMiscoverageLoss()
    for record, truth in loss._unit_test_inputs():
        values = [loss(record, truth, lam) for lam in np.linspace(-0.2, 1.2, 15)]
        if record.scored_error.size == 0:
            assert all(v is None for v in values)
            continue
        assert values[0] == 0.0 and values[-1] == 1.0
        assert values == sorted(values)


def test_aci_drives_the_miscoverage_to_alpha_in_closed_loop():
    from conformal_control.data.synthetic import crossing_scene
    from conformal_control.world.replay import ReplayEnvironment

    scene = crossing_scene(duration=40.0)
    dyn = VelocityTrackingDoubleIntegrator(K_acc=20.0)
    env = ReplayEnvironment(scene, dyn, tau_frames=4, substeps=1, history_frames=60)
    fam = ACPMPC(
        Frozen(),
        dyn,
        sampling=Sampling(n_samples=60, horizon=6),
        limits=Limits(v_max=0.3),
        substeps=1,
        max_inflation=1.0,
    )
    rule = ACIRule(alpha=0.2, gamma=0.05)
    result = ConformalLoop(env, fam, PlanMiscoverageLoss(), rule).run()
    assert result.n_updates > 50
    bound = result.guarantee["long_run_bound"]
    assert abs(result.l_avg - 0.2) <= bound
    assert math.isfinite(result.lambda_final)
