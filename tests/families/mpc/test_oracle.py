"""The oracle predictor over an MPC's plan horizon: the true future as far as it is asked,
agents who leave the data held at their last recorded position (counted)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conformal_control.data.synthetic import crossing_scene
from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.families.cbf.reference import AttractiveField
from conformal_control.families.mpc import Sampling, SamplingMPC
from conformal_control.predictors.base import PredictionQuery, TruthUnavailableError
from conformal_control.predictors.oracle import OraclePredictor
from conformal_control.predictors.shift import DelayedPredictor
from conformal_control.runs.episode import run_episode
from conformal_control.world.replay import ReplayEnvironment


@pytest.fixture(scope="module")
def scene():
    # 10 fps, pedestrians walking in and out of a 20 m x 10 m area; 6 s of data after the start
    return crossing_scene(duration=6.0)


def _sensed(scene, tau=4):
    env = ReplayEnvironment(
        scene, VelocityTrackingDoubleIntegrator(K_acc=10.0), tau_frames=tau, substeps=2
    )
    env.reset()
    q = env.sense()
    idx = np.searchsorted(scene.agent_ids, q.ids)
    return env, q, idx


def _truth(scene, idx, lo, hi):
    """positions[lo:hi, idx] as (N, hi - lo, 2), NaN outside the data."""
    out = np.full((idx.size, hi - lo, 2), np.nan)
    b = min(hi, scene.n_frames)
    out[:, : b - lo] = scene.positions[lo:b, idx].transpose(1, 0, 2)
    return out


def test_the_oracle_returns_the_true_future_over_any_horizon(scene):
    _env, q, idx = _sensed(scene)
    fi = scene.start_index
    assert q.n_agents >= 2
    oracle = OraclePredictor()
    # the interval's horizon, and a plan's horizon running past the end of the data
    beyond = scene.n_frames - fi + 5
    for h in (q.horizon, 30, beyond):
        got = oracle.predict(dataclasses.replace(q, horizon=h)).positions
        assert got.shape == (q.n_agents, h, 2)
        np.testing.assert_array_equal(got, _truth(scene, idx, fi + 1, fi + 1 + h))
    # beyond the data nothing is known; some agent leaves the data before it ends
    got = oracle.predict(dataclasses.replace(q, horizon=beyond)).positions
    assert np.isnan(got[:, -5:]).all()
    inside = got[:, : scene.n_frames - fi - 1]
    assert (~np.isfinite(inside).all(axis=(1, 2))).any()


def test_future_takes_a_horizon_and_pads_a_short_ground_truth():
    gt = np.arange(12.0).reshape(2, 3, 2)
    q = PredictionQuery(
        ids=np.array([1, 2]), history=np.zeros((2, 1, 2)), dt=0.1, horizon=3, ground_truth=gt
    )
    np.testing.assert_array_equal(q.future(), gt)
    np.testing.assert_array_equal(q.future(2), gt[:, :2])
    five = q.future(5)
    np.testing.assert_array_equal(five[:, :3], gt)
    assert np.isnan(five[:, 3:]).all()
    with pytest.raises(ValueError, match="horizon of the true future must be >= 0"):
        q.future(-1)
    bad = dataclasses.replace(q, ground_truth=None, truth_provider=lambda h: np.zeros((2, 1, 2)))
    with pytest.raises(ValueError, match=r"truth_provider\(3\) returned shape \(2, 1, 2\)"):
        bad.future()
    with pytest.raises(TruthUnavailableError):
        dataclasses.replace(q, ground_truth=None).future()


def test_the_delayed_oracle_is_the_true_future_of_the_delayed_time(scene):
    _env, q, idx = _sensed(scene)
    fi = scene.start_index
    k = 5  # 0.5 s at 10 fps
    delayed = DelayedPredictor(predictor=OraclePredictor(), delay_s=0.5)
    for h in (3, 40):  # shorter than the delay (all observed) and longer
        got = delayed.predict(dataclasses.replace(q, horizon=h)).positions
        np.testing.assert_array_equal(got, _truth(scene, idx, fi - k + 1, fi - k + 1 + h))


def test_the_mpc_plans_with_the_true_future_and_holds_agents_who_leave(scene):
    env, q, idx = _sensed(scene)
    fam = SamplingMPC(
        OraclePredictor(),
        VelocityTrackingDoubleIntegrator(K_acc=10.0),
        AttractiveField(K_att=1.0, v_max=2.0),
        sampling=Sampling(n_samples=20, horizon=15, dt_plan=0.4),  # 6 s: past the data's end
        substeps=2,
    )
    fam.reset()
    fam.begin_interval(q)
    fi = scene.start_index
    frames = fam.forecast_frames(q)
    assert frames == q.horizon + 60
    truth = _truth(scene, idx, fi, fi + 1 + frames)  # from the sampling time
    offsets = np.arange(frames + 1) * q.dt
    planned = fam.predicted_at(offsets)
    for a in range(q.n_agents):
        known = np.isfinite(truth[a]).all(axis=1)
        last = int(np.flatnonzero(known)[-1])
        assert known[: last + 1].all()  # tracks do not have gaps in this scene
        np.testing.assert_allclose(planned[a, : last + 1], truth[a, : last + 1], atol=1e-12)
        # after its track ends the agent is held where it was last recorded
        np.testing.assert_array_equal(
            planned[a, last:], np.repeat(truth[a, last][None], frames + 1 - last, 0)
        )
    # every agent's truth ends within this horizon: all of them held and counted
    assert fam.stats()["n_nonfinite_predictions"] == q.n_agents
    env.apply(fam.decide(env.state(), 0.0))  # and it decides


@pytest.mark.filterwarnings("ignore:the goal was not reached")
def test_an_oracle_mpc_episode_runs_and_counts_the_held_agents():
    scene = crossing_scene(duration=8.0)
    res = run_episode(
        scene,
        predictor="oracle",
        family="mpc",
        family_params={
            "sampling__n_samples": 60,
            "sampling__horizon": 10,
            "sampling__replan_every": 2,
        },
        learn=False,
        record_animation=False,
    )
    m = res.metrics
    assert res.config["predictor"]["name"] == "oracle" and m["n_steps"] > 0
    # pedestrians leave the 20 m area and the data ends 8 s after the start: some agent's
    # true future ends within a 4 s plan
    assert m["n_nonfinite_predictions"] > 0
