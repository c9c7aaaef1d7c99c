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


def _score_one_agent_at_a_time(fam: ACPMPC, observation: PredictionQuery):
    """The scoring as first written: one agent at a time (the reference the vectorised
    scoring must equal bit for bit, counters included)."""
    steps, errors = [], []
    hist = observation.history
    span = (hist.shape[1] - 1) * observation.dt
    row = {int(i): r for r, i in enumerate(np.asarray(observation.ids))}
    keep = []
    for t_made, ids, pred, first in fam._pending:
        h = first
        while h <= pred.shape[1]:
            back = observation.t - (t_made + h * fam.sampling.dt_plan)
            if back < -1e-9:
                break
            if back > span + 1e-9:
                fam.n_unscored_ += len(ids)
                h += 1
                continue
            f = back / observation.dt
            k0 = math.floor(f + 1e-9)
            w = max(f - k0, 0.0)
            c0 = hist.shape[1] - 1 - k0
            c1 = max(c0 - 1, 0)
            for a, agent in enumerate(ids):
                r = row.get(int(agent))
                truth = None
                if r is not None:
                    p = hist[r, c0] if w == 0.0 else hist[r, c0] + w * (hist[r, c1] - hist[r, c0])
                    truth = p if np.isfinite(p).all() else None
                if truth is None:
                    fam.n_unscored_ += 1
                    continue
                steps.append(h)
                errors.append(float(np.hypot(*(truth - pred[a, h - 1]))))
            h += 1
        if h <= pred.shape[1]:
            keep.append((t_made, ids, pred, h))
    fam._pending = keep
    fam.n_scored_ += len(errors)
    return np.array(steps, dtype=np.int64), np.array(errors, dtype=float)


def _wandering(k: int, rng: np.random.Generator) -> PredictionQuery:
    """Agents 0..5 on random walks, some of them missing or with a gap at times, sampled
    every DT / 2 (targets between samples are interpolated)."""
    t = k * DT
    times = t - DT / 2 * np.arange(11, -1, -1)
    ids = np.array([j for j in range(6) if (k + j) % 5 != 0])
    hist = np.cumsum(rng.normal(0, 0.3, (ids.size, times.size, 2)), axis=1)
    gaps = rng.random((ids.size, times.size)) < 0.05
    gaps[:, -1] = False  # the current positions are known
    hist[gaps] = np.nan
    return PredictionQuery(ids=ids, history=hist, dt=DT / 2, horizon=2, t=t, frame=k, scene="t")


def test_vectorised_scoring_and_sorted_windows_equal_the_first_implementation():
    rng = np.random.default_rng(4)
    fam, ref = family(window=9), family(window=9)
    for k in range(30):
        obs = _wandering(k, rng)
        ref._pending = list(fam._pending)  # the same stored predictions
        want = _score_one_agent_at_a_time(ref, obs)
        fam.begin_interval(obs)
        got = fam._scored
        assert got[0].tobytes() == want[0].tobytes() and got[1].tobytes() == want[1].tobytes()
        assert (fam.n_scored_, fam.n_unscored_) == (ref.n_scored_, ref.n_unscored_)
        for h, window in enumerate(fam.scores_):  # kept sorted through the evictions
            assert fam._sorted[h].tobytes() == np.sort(np.fromiter(window, float)).tobytes()
    assert fam.n_scored_ > 9 * 4  # the windows were full: errors left them
    seeded = family(window=9)  # a window filled from outside is sorted afresh
    seeded.scores_[0].extend([5.0, 0.0, 2.0])
    for k in range(3):
        seeded.begin_interval(_wandering(k, rng))
    assert seeded._sorted[0].tobytes() == np.sort(np.fromiter(seeded.scores_[0], float)).tobytes()
