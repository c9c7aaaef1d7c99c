"""ecp_mpc: egocentric scores and quantiles, scoring of past plans, errors."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from conformal_control.core.loop import ConformalLoop
from conformal_control.core.update_rules import ACIRule
from conformal_control.families.cbf.controller import ControlState
from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.families.mpc import ECPMPC, EgocentricMiscoverageLoss, Limits, Sampling
from conformal_control.families.mpc.ecp import egocentric_quantiles
from conformal_control.predictors.base import Forecast, PredictionQuery, Predictor

DT = 0.4


class Frozen(Predictor):
    """Every agent stays where it is."""

    def predict(self, query: PredictionQuery) -> Forecast:
        return Forecast(np.repeat(query.current[:, None, :], query.horizon, axis=1))


def test_quantiles_equal_a_brute_force_evaluation():
    rng = np.random.default_rng(0)
    h_n, b_max, m = 3, 6, 4
    pos = rng.normal(0, 3, (7, h_n, 2))
    cal_pred = rng.normal(0, 3, (h_n, b_max, m, 2))
    cal_obs = rng.normal(0, 3, (h_n, b_max, m, 2))
    cal_n = rng.integers(0, m + 1, (h_n, b_max))
    cal_b = np.array([6, 4, 0])
    for lam in (-0.1, 0.0, 0.1, 0.3, 0.5, 0.99, 1.0, 1.5):
        q = egocentric_quantiles(pos, cal_pred, cal_obs, cal_n, cal_b, lam)
        for n in range(7):
            for h in range(h_n):
                scores = []
                for b in range(cal_b[h]):
                    k = cal_n[h, b]
                    if k == 0:
                        scores.append(0.0)
                        continue
                    dp = min(np.hypot(*(pos[n, h] - cal_pred[h, b, j])) for j in range(k))
                    do = min(np.hypot(*(pos[n, h] - cal_obs[h, b, j])) for j in range(k))
                    scores.append(max(dp - do, 0.0))
                if lam >= 1:
                    expected = -math.inf
                else:
                    k = math.ceil((len(scores) + 1) * (1 - lam))
                    if lam <= 0 or not scores or k > len(scores):
                        expected = math.inf
                    else:
                        expected = sorted(scores)[k - 1]
                assert math.isclose(q[n, h], expected, abs_tol=1e-12) or q[n, h] == expected


def observation(k: int, speeds: np.ndarray) -> PredictionQuery:
    t = k * DT
    times = t - DT * np.arange(9, -1, -1)
    hist = np.stack(
        [np.stack([s * times, np.full_like(times, 1.0 + j)], -1) for j, s in enumerate(speeds)]
    )
    return PredictionQuery(
        ids=np.arange(len(speeds)), history=hist, dt=DT, horizon=1, t=t, frame=k, scene="t"
    )


def family(**kw) -> ECPMPC:
    params = {
        "predictor": Frozen(),
        "dynamics": VelocityTrackingDoubleIntegrator(10.0),
        "sampling": Sampling(n_samples=20, horizon=3, dt_plan=DT),
        "substeps": 1,
        "calibration_size": 4,
        "max_inflation": 3.0,
    }
    params.update(kw)
    fam = ECPMPC(**params)
    fam.reset()
    return fam


def test_past_plans_are_scored_and_calibration_pairs_collected():
    fam = family()
    speeds = np.array([1.0, -0.5])
    for k in range(8):
        fam.begin_interval(observation(k, speeds))
        fam.decide(ControlState(np.array([0.0, 5.0, 0, 0]), k * DT, 0, np.array([9.0, 5.0])), 0.3)
        rec = fam.interval_record()
        # every step h <= k has a plan made h steps ago, scored candidate by candidate: 20
        # random ones + the stop seed (+ the warm start from the second plan on)
        assert rec.ego_missed.size == sum(21 if k - h == 0 else 22 for h in range(1, min(k, 3) + 1))
    cal_pred, cal_obs, cal_n, cal_b = fam._cal
    np.testing.assert_array_equal(cal_b, [4, 4, 4])
    assert (cal_n[:, :4] == 2).all()
    # a frozen prediction of step h is the position h steps earlier
    np.testing.assert_allclose(cal_obs[1, 0] - cal_pred[1, 0], [[2 * DT, 0.0], [-DT, 0.0]])


def test_a_smaller_lambda_gives_larger_regions():
    fam = family()
    for k in range(8):
        fam.begin_interval(observation(k, np.array([1.0, -0.5, 0.7])))
    pos = np.random.default_rng(1).normal(0, 2, (30, 3, 2))
    r = [fam.plan_radius(lam, pos) for lam in (0.0, 0.2, 0.5, 0.9, 1.0)]
    for a, b in itertools.pairwise(r):
        assert (a >= b).all()
    np.testing.assert_allclose(r[0], 1.0 + 3.0)  # unbounded: capped
    np.testing.assert_allclose(r[-1], 1.0)  # empty


def test_plan_steps_must_be_whole_sampling_periods():
    fam = family(sampling__dt_plan=0.5)
    with pytest.raises(ValueError, match="whole sampling periods") as info:
        fam.begin_interval(observation(0, np.array([1.0])))
    assert "\n" not in str(info.value)


def test_aci_drives_the_egocentric_miscoverage_to_alpha_in_closed_loop():
    from conformal_control.data.synthetic import crossing_scene
    from conformal_control.world.replay import ReplayEnvironment

    scene = crossing_scene(duration=40.0)
    dyn = VelocityTrackingDoubleIntegrator(K_acc=20.0)
    env = ReplayEnvironment(scene, dyn, tau_frames=4, substeps=1, history_frames=20)
    fam = ECPMPC(
        Frozen(),
        dyn,
        sampling=Sampling(n_samples=40, horizon=5),
        limits=Limits(v_max=0.3),
        substeps=1,
        max_inflation=1.0,
    )
    result = ConformalLoop(env, fam, EgocentricMiscoverageLoss(), ACIRule(0.2, 0.05)).run()
    assert result.n_updates > 50
    assert abs(result.l_avg - 0.2) <= result.guarantee["long_run_bound"]


def _quantiles_one_candidate_at_a_time(pos, cal_pred, cal_obs, cal_n, cal_b, lam):
    """The quantiles as first written: one candidate at a time, every score sorted (the
    reference the compiled kernel must equal bit for bit)."""
    n_plans, horizon = pos.shape[:2]
    out = np.empty((n_plans, horizon))
    for h in range(horizon):
        b_n = int(cal_b[h])
        if lam >= 1.0:
            out[:, h] = -math.inf
            continue
        k = math.ceil((b_n + 1) * (1.0 - lam))
        if lam <= 0.0 or b_n == 0 or k > b_n:
            out[:, h] = math.inf
            continue
        for n in range(n_plans):
            px, py = float(pos[n, h, 0]), float(pos[n, h, 1])
            scores = []
            for b in range(b_n):
                dp = do = math.inf
                for j in range(int(cal_n[h, b])):
                    ax, ay = px - float(cal_pred[h, b, j, 0]), py - float(cal_pred[h, b, j, 1])
                    dp = min(dp, ax * ax + ay * ay)
                    ax, ay = px - float(cal_obs[h, b, j, 0]), py - float(cal_obs[h, b, j, 1])
                    do = min(do, ax * ax + ay * ay)
                s = math.sqrt(dp) - math.sqrt(do) if cal_n[h, b] else 0.0
                scores.append(s if s > 0.0 else 0.0)
            out[n, h] = sorted(scores)[max(k, 1) - 1]
    return out


def test_quantiles_equal_the_one_candidate_at_a_time_evaluation_bit_for_bit():
    rng = np.random.default_rng(3)
    for trial in range(40):
        n, h_n, b_max, m = 9, 3, int(rng.integers(1, 17)), int(rng.integers(1, 5))
        pos = rng.normal(0, 3, (n, h_n, 2))
        cal_pred = rng.normal(0, 3, (h_n, b_max, m, 2))
        cal_obs = rng.normal(0, 3, (h_n, b_max, m, 2))
        if trial % 2:  # on a lattice: many equal scores
            pos, cal_pred, cal_obs = np.round(pos), np.round(cal_pred), np.round(cal_obs)
        cal_n = rng.integers(0, m + 1, (h_n, b_max))
        cal_b = rng.integers(0, b_max + 1, h_n)
        for lam in (0.0, 0.04, 0.1, 0.25, 0.5, 0.75, 0.95, 1.0):
            got = egocentric_quantiles(pos, cal_pred, cal_obs, cal_n, cal_b, lam)
            want = _quantiles_one_candidate_at_a_time(pos, cal_pred, cal_obs, cal_n, cal_b, lam)
            assert got.tobytes() == want.tobytes(), (trial, lam)


def test_misses_equal_the_two_distance_fields_bit_for_bit():
    from conformal_control.families.mpc.ecp import _missed
    from conformal_control.families.mpc.fieldcp import distance_field

    rng = np.random.default_rng(5)
    x = np.round(rng.normal(0, 3, (40, 2)), 1)
    for m in (1, 4):
        pred, obs = np.round(rng.normal(0, 3, (m, 2))), rng.normal(0, 3, (m, 2))
        q = np.concatenate([rng.uniform(0, 2, 38), [-math.inf, math.inf]])
        score = np.maximum(distance_field(pred, x) - distance_field(obs, x), 0.0)
        assert _missed(x, pred, obs, q).tolist() == (score > q).tolist()
