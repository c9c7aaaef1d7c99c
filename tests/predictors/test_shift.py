"""Predictor shifts (``delayed``, ``noisy``, ``scaled``, ``dropout``): their numbers, their
neutral settings, their seeds, their errors, and closed-loop runs on the batch engine.

(The contract kit runs on every registered predictor in ``tests/testing``.)"""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.core import registry
from conformal_control.predictors import ConstantVelocityPredictor, PredictionQuery
from conformal_control.predictors.shift import (
    DelayedPredictor,
    DropoutPredictor,
    NoisyPredictor,
    ScaledPredictor,
    hash_normal,
    hash_uniform,
)
from conformal_control.testing.predictor import make_query


def _walkers(n: int = 3, T: int = 40, dt: float = 0.1) -> PredictionQuery:
    """Agents walking straight at known velocities, exact positions."""
    v = np.array([[1.0, 0.0], [0.0, -0.5], [0.6, 0.8]])[:n]
    p0 = np.array([[0.0, 0.0], [5.0, 5.0], [-3.0, 2.0]])[:n]
    t = np.arange(T) * dt
    hist = p0[:, None, :] + v[:, None, :] * t[None, :, None]
    return PredictionQuery(
        ids=np.arange(n) + 10, history=hist, dt=dt, horizon=4, t=3.9, frame=39, scene="walk"
    )


@pytest.mark.parametrize("name", ["delayed", "noisy", "scaled", "dropout"])
def test_shifts_are_registered_and_wrap_any_predictor(name):
    cls = registry.get("predictor", name)
    by_name = cls(predictor="var")
    by_name.reset()
    assert type(by_name.base_).__name__ == "VARPredictor"
    inner = ConstantVelocityPredictor(window=2)
    by_instance = cls(predictor=inner)
    by_instance.reset()
    assert by_instance.base_ is inner
    with_params = cls(predictor="constant_velocity", predictor_params={"window": 3})
    with_params.reset()
    assert with_params.base_.window == 3


def test_neutral_settings_return_the_wrapped_forecast_bit_for_bit():
    q = make_query(n_agents=5, history=12, horizon=7)
    q.history[2, :5] = np.nan
    base = ConstantVelocityPredictor().predict(q).positions
    for p in (
        DelayedPredictor(delay_s=0.0),
        NoisyPredictor(sigma_m=0.0, random_state=3),
        ScaledPredictor(scale=1.0),
        DropoutPredictor(p=0.0),
    ):
        assert np.array_equal(p.predict(q).positions, base, equal_nan=True), p


def test_delayed_forecasts_from_old_data_without_compensation():
    q = _walkers()
    dt = q.dt
    out = DelayedPredictor(delay_s=0.5).predict(q).positions
    # constant velocity from the history 5 samples old: the positions 0.5 s behind
    expect = q.history[:, -6][:, None, :] + (
        np.array([[1.0, 0.0], [0.0, -0.5], [0.6, 0.8]])[:, None, :]
        * (dt * np.arange(1, 5))[None, :, None]
    )
    np.testing.assert_allclose(out, expect, atol=1e-12)
    # the delay is rounded to whole samples
    assert np.array_equal(DelayedPredictor(delay_s=0.52).predict(q).positions, out)


def test_delayed_agent_unseen_or_gapped_at_the_cut_is_counted():
    q = _walkers()
    q.history[0, :-3] = np.nan  # appeared 0.2 s ago: not in the data 0.5 s old
    q.history[1, -8:-4] = np.nan  # a gap around the cut: its last earlier sample is used
    fc = DelayedPredictor(delay_s=0.5).predict(q)
    assert fc.info["n_unseen"] == 1 and fc.info["n_stale"] == 1
    # unseen: stands at its first observation
    np.testing.assert_allclose(fc.positions[0], np.repeat(q.history[0, -3][None], 4, axis=0))
    assert np.isfinite(fc.positions).all()


def test_delayed_oracle_sees_the_past_truth():
    q = _walkers()
    future = q.history[:, -1][:, None, :] + (
        np.array([[1.0, 0.0], [0.0, -0.5], [0.6, 0.8]])[:, None, :]
        * (q.dt * np.arange(1, 5))[None, :, None]
    )
    q.ground_truth = future
    out = DelayedPredictor("oracle", delay_s=0.2).predict(q).positions
    np.testing.assert_allclose(out[:, 0], q.history[:, -2])
    np.testing.assert_allclose(out[:, 1], q.history[:, -1])
    np.testing.assert_allclose(out[:, 2:], future[:, :2])


def test_delay_longer_than_the_history_is_a_one_line_error():
    q = _walkers(T=10)
    with pytest.raises(ValueError, match=r"delay_s=2 s is 20 samples.*history holds 10"):
        DelayedPredictor(delay_s=2.0).predict(q)


@pytest.mark.parametrize(
    ("plugin", "message"),
    [
        (DelayedPredictor(delay_s=-0.1), "delay_s must be a finite number >= 0"),
        (DelayedPredictor(delay_s=float("nan")), "delay_s must be a finite number >= 0"),
        (NoisyPredictor(sigma_m=-1.0), "sigma_m must be a finite number >= 0"),
        (ScaledPredictor(scale="fast"), "scale must be a number"),
        (DropoutPredictor(p=1.5), r"p must be a finite number in \[0, 1\]"),
        (DropoutPredictor(duration_s=0.0), "duration_s must be > 0"),
        (DelayedPredictor(predictor="no_such"), "no_such"),
    ],
)
def test_bad_parameters_are_one_line_errors(plugin, message):
    with pytest.raises(ValueError, match=message) as exc:
        plugin.reset()
    assert "\n" not in str(exc.value)


def test_noisy_is_reproducible_with_a_seed_and_independent_of_the_batch():
    q = make_query(n_agents=6)
    a = NoisyPredictor(sigma_m=0.3, random_state=7).predict(q).positions
    b = NoisyPredictor(sigma_m=0.3, random_state=7).predict(q).positions
    c = NoisyPredictor(sigma_m=0.3, random_state=8).predict(q).positions
    assert np.array_equal(a, b) and not np.allclose(a, c)
    base = ConstantVelocityPredictor().predict(q).positions
    offset = a - base
    # one offset per agent and sampling time, the same over the horizon
    np.testing.assert_allclose(offset, offset[:, :1].repeat(q.horizon, axis=1), atol=1e-12)
    # agent 3 alone gets the same draw as in the batch
    sub = PredictionQuery(q.ids[3:4], q.history[3:4], q.dt, q.horizon, q.t, q.frame, q.scene)
    np.testing.assert_array_equal(
        NoisyPredictor(sigma_m=0.3, random_state=7).predict(sub).positions[0], a[3]
    )
    # another frame, another draw
    q2 = make_query(n_agents=6)
    q2.frame += 1
    assert not np.allclose(NoisyPredictor(sigma_m=0.3, random_state=7).predict(q2).positions, a)


def test_hashed_draws_are_standard_normal_and_uniform():
    z = hash_normal(5, np.arange(200_000))
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1.0) < 0.01
    u = hash_uniform(5, np.arange(200_000))
    assert u.min() >= 0.0 and u.max() < 1.0 and abs(u.mean() - 0.5) < 0.005
    # deterministic, and different keys give different numbers
    assert np.array_equal(hash_normal(1, 2, 3), hash_normal(1, 2, 3))
    assert hash_normal(1, 2, 3)[0] != hash_normal(1, 2, 4)[0]


def test_scaled_zero_is_frozen_and_two_doubles_the_displacement():
    q = _walkers()
    frozen = ScaledPredictor(scale=0.0).predict(q).positions
    np.testing.assert_array_equal(frozen, np.repeat(q.history[:, -1][:, None], 4, axis=1))
    base = ConstantVelocityPredictor().predict(q).positions
    double = ScaledPredictor(scale=2.0).predict(q).positions
    cur = q.history[:, -1][:, None]
    np.testing.assert_allclose(double - cur, 2.0 * (base - cur), atol=1e-12)


def test_dropout_hides_detections_in_blocks_with_the_given_probability():
    p = DropoutPredictor(p=0.3, duration_s=1.0, random_state=0)
    n, T, dt = 400, 50, 0.1
    q = PredictionQuery(
        ids=np.arange(n),
        history=np.zeros((n, T, 2)),
        dt=dt,
        horizon=2,
        frame=1000,
        scene="s",
    )
    miss = p.missing(q)
    assert abs(miss.mean() - 0.3) < 0.03
    # constant within a block of 1 s (10 samples aligned on frame * dt), varies across blocks
    frames = q.frame - (T - 1) + np.arange(T)
    blocks = np.floor(frames * dt + 1e-9)
    for b in np.unique(blocks):
        cols = miss[:, blocks == b]
        assert (cols == cols[:, :1]).all()
    assert (miss[:, 0] != miss[:, -1]).any()


def test_dropout_predicts_a_dropped_agent_from_its_last_detection():
    q = _walkers(n=3, T=40)
    p = DropoutPredictor(p=0.5, duration_s=1.0, random_state=0)
    miss = p.missing(q)
    fc = p.predict(q)
    for i in range(3):
        if miss[i, -1]:
            seen = np.flatnonzero(~miss[i])
            last = q.history[i, seen[-1]]
            assert np.allclose(fc.positions[i, 0], last + (q.history[i, 1] - q.history[i, 0]))
    assert fc.info["n_dropped"] == int(miss[:, -1].sum())


def test_shifted_runs_on_the_batch_engine_equal_the_loop(data_root):
    from conformal_control.experiments.bench import load_scenario, load_suite
    from conformal_control.runs.engines.batch import run_batch
    from conformal_control.runs.episode import run_episode

    suite = load_suite("crossings-v1")
    scs = suite.scenarios_for("test")[:3]
    scenes = [load_scenario(sc, data_root) for sc in scs]
    frames = [sc.max_frames for sc in scs]
    for name, params in [
        ("delayed", {"delay_s": 0.5}),
        ("noisy", {"sigma_m": 0.25}),
        ("scaled", {"scale": 0.0}),
        ("dropout", {"p": 0.3, "duration_s": 1.0}),
    ]:
        batched = run_batch(scenes, name, predictor_params=params, max_frames=frames)
        for scene, mf, b in zip(scenes, frames, batched, strict=True):
            loop = run_episode(
                scene,
                name,
                predictor_params=params,
                max_frames=mf,
                engine="loop",
                record_animation=False,
            ).metrics
            da = {k: v for k, v in b.as_dict().items() if k != "wall_s"}
            db = {k: v for k, v in loop.as_dict().items() if k != "wall_s"}
            assert da == db, name


def test_neutral_shift_equals_its_base_in_closed_loop(data_root):
    from conformal_control.experiments.bench import load_scenario, load_suite
    from conformal_control.runs.engines.batch import run_batch

    suite = load_suite("crossings-v1")
    scs = suite.scenarios_for("test")[:12]
    scenes = [load_scenario(sc, data_root) for sc in scs]
    frames = [sc.max_frames for sc in scs]
    base = run_batch(scenes, "constant_velocity", max_frames=frames)
    for name, params in [
        ("delayed", {"delay_s": 0.0}),
        ("noisy", {"sigma_m": 0.0}),
        ("scaled", {"scale": 1.0}),
        ("dropout", {"p": 0.0}),
    ]:
        shifted = run_batch(scenes, name, predictor_params=params, max_frames=frames)
        for a, b in zip(shifted, base, strict=True):
            da = {k: v for k, v in a.as_dict().items() if k != "wall_s"}
            db = {k: v for k, v in b.as_dict().items() if k != "wall_s"}
            assert da == db, name
    # and the shifts do change the runs
    delayed = run_batch(scenes, "delayed", predictor_params={"delay_s": 1.0}, max_frames=frames)
    assert sum(m["n_collide"] for m in delayed) > sum(m["n_collide"] for m in base)


@pytest.mark.parametrize(
    ("params", "message"),
    [
        (["--predictor", "delayed", "--predictor-param", "delay_s=-0.5"],
         "delay_s must be a finite number >= 0, got -0.5"),
        (["--predictor", "noisy", "--predictor-param", "sigma_m=-1"],
         "sigma_m must be a finite number >= 0"),
        (["--predictor", "recorded", "--predictor-param", "path={missing}"],
         "missing column(s) step: its first line must be a header"),
        (["--predictor", "recorded", "--predictor-param", "path={nan}"],
         "nan.csv:2: non-finite value"),
    ],
)  # fmt: skip
def test_bad_shift_or_recorded_input_is_one_line_from_the_cli(
    params, message, tmp_path, data_root, capsys
):
    """Through ``conformal-control run``: exit status 2 and one line, before any output."""
    from conformal_control.cli import main

    (tmp_path / "missing.csv").write_text("frame,track_id,x,y\n1,2,3.0,4.0\n")
    (tmp_path / "nan.csv").write_text("frame,track_id,step,x,y\n1,2,1,nan,4.0\n")
    argv = [p.format(missing=tmp_path / "missing.csv", nan=tmp_path / "nan.csv") for p in params]
    rc = main([
        "run", "--scene", "scenario:crossings-v2/ethucy-biwi_hotel-w006", "--frames", "10",
        "--data-root", str(data_root), "--out", str(tmp_path / "run"), *argv,
    ])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and message in err, err
    assert "internal error" not in err
