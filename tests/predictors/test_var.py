"""The core VAR predictor: Yule–Walker estimates, stability, fallbacks, batching."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.core import registry
from conformal_control.predictors.base import PredictionQuery
from conformal_control.predictors.var import (
    VARPredictor,
    companion,
    fit_var_yule_walker,
    forecast_var,
    radius_bound,
    stabilise,
)
from conformal_control.testing import check_predictor


def _simulate_var(coefs, mean, n, seed=0, noise=1.0):
    """A VAR(p) path y_t = mean + sum_k A_k (y_{t-k} - mean) + e_t of n samples."""
    rng = np.random.default_rng(seed)
    p, k = coefs.shape[0], coefs.shape[1]
    y = np.zeros((n + 200, k))
    for t in range(p, n + 200):
        y[t] = sum(coefs[j] @ y[t - 1 - j] for j in range(p)) + rng.normal(0, noise, k)
    return y[200:] + mean


def _walk_query(lengths, t=60, horizon=8, seed=1, dt=1 / 30):
    """Pedestrians with a wobbling velocity (an AR process on the steps)."""
    rng = np.random.default_rng(seed)
    hist = np.full((len(lengths), t, 2), np.nan)
    for i, length in enumerate(lengths):
        v = np.array([1.2, 0.4]) * (1 + 0.3 * i)
        wobble = np.cumsum(rng.normal(0, 0.02, (length, 2)), axis=0) * 0.3
        steps = v * dt + wobble * dt
        hist[i, t - length :] = np.array([5.0, 3.0]) + np.cumsum(steps, axis=0)
    return PredictionQuery(np.arange(len(lengths)), hist, dt=dt, horizon=horizon, scene="t")


def _reference_yule_walker(y, p):
    """Textbook multivariate Yule–Walker on one series, written out with loops."""
    n, k = y.shape
    mu = y.mean(axis=0)
    c = y - mu

    def gamma(h):
        return sum(np.outer(c[t], c[t - h]) for t in range(h, n)) / n

    big = np.zeros((k * p, k * p))
    for i in range(p):
        for j in range(p):
            g = gamma(j - i) if j >= i else gamma(i - j).T
            big[i * k : (i + 1) * k, j * k : (j + 1) * k] = g
    rhs = np.hstack([gamma(h) for h in range(1, p + 1)])
    a = np.linalg.solve(big.T, rhs.T).T  # A R = G
    return np.stack([a[:, j * k : (j + 1) * k] for j in range(p)]), mu


def test_registered_in_core_and_passes_the_contract_kit():
    assert registry.get("predictor", "var") is VARPredictor
    entry = registry.entry("predictor", "var")
    assert entry.origin == "conformal-control"
    check_predictor(VARPredictor)


def test_matches_textbook_yule_walker():
    rng = np.random.default_rng(3)
    y = rng.normal(size=(45, 2)).cumsum(axis=0) * 0.1 + rng.normal(size=(45, 2))
    coefs, mean, _ = fit_var_yule_walker(y[None], np.ones((1, 45), bool), 3)
    ref, mu = _reference_yule_walker(y, 3)
    np.testing.assert_allclose(coefs[0], ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(mean[0], mu)


def test_recovers_a_known_var2_from_a_long_series():
    a = np.array([[[0.5, 0.1], [0.0, 0.3]], [[-0.2, 0.0], [0.1, 0.2]]])
    y = _simulate_var(a, np.array([0.3, -0.1]), 20000, seed=4)
    coefs, mean, _ = fit_var_yule_walker(y[None], np.ones((1, len(y)), bool), 2)
    np.testing.assert_allclose(coefs[0], a, atol=0.03)
    np.testing.assert_allclose(mean[0], [0.3, -0.1], atol=0.03)


def test_padding_does_not_change_the_fit():
    # a short series fitted alone and inside a batch padded to a longer one: same estimate
    rng = np.random.default_rng(5)
    short, long_ = rng.normal(size=(20, 2)), rng.normal(size=(40, 2))
    alone, m_alone, _ = fit_var_yule_walker(short[None], np.ones((1, 20), bool), 4)
    batch = np.zeros((2, 40, 2))
    batch[0, 20:], batch[1] = short, long_
    valid = np.ones((2, 40), bool)
    valid[0, :20] = False
    both, m_both, _ = fit_var_yule_walker(batch, valid, 4)
    np.testing.assert_allclose(both[0], alone[0], rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(m_both[0], m_alone[0])


def test_stabilise_puts_the_spectral_radius_on_the_bound():
    rng = np.random.default_rng(6)
    coefs = rng.normal(0, 0.8, size=(5, 3, 2, 2))  # mostly explosive
    before = np.abs(np.linalg.eigvals(companion(coefs))).max(axis=1)
    out, radius, shrunk = stabilise(coefs, 0.95)
    np.testing.assert_allclose(radius, before)
    np.testing.assert_array_equal(shrunk, before >= 0.95)
    after = np.abs(np.linalg.eigvals(companion(out))).max(axis=1)
    np.testing.assert_allclose(after[shrunk], 0.95, rtol=1e-9)
    np.testing.assert_array_equal(out[~shrunk], coefs[~shrunk])


def test_radius_bound_is_a_tight_upper_bound():
    rng = np.random.default_rng(7)
    c = rng.normal(0, 0.3, size=(500, 6, 6))
    exact = np.abs(np.linalg.eigvals(c)).max(axis=1)
    bound = radius_bound(c)
    assert (bound >= exact * (1 - 1e-12)).all()
    assert np.median(bound / exact) < 1.01
    nilpotent = np.zeros((1, 4, 4))
    nilpotent[0, 0, 1] = 1.0
    assert radius_bound(nilpotent)[0] == 0.0
    huge = np.eye(3)[None] * 1e200  # no overflow: still a finite bound
    np.testing.assert_allclose(radius_bound(huge), 1e200, rtol=1e-3)


def test_forecast_follows_the_recursion():
    a = np.array([[[0.5, 0.0], [0.1, 0.2]], [[0.1, 0.0], [0.0, -0.1]]])[None]
    y = np.array([[[1.0, 2.0], [0.5, -1.0]]])  # y_{t-1}, y_t
    out = forecast_var(a, y, 3)
    y1 = a[0, 0] @ y[0, 1] + a[0, 1] @ y[0, 0]
    y2 = a[0, 0] @ y1 + a[0, 1] @ y[0, 1]
    y3 = a[0, 0] @ y2 + a[0, 1] @ y1
    np.testing.assert_allclose(out[0], [y1, y2, y3])


def test_straight_noisy_walk_is_continued():
    q = _walk_query([60, 60, 60])
    fc = VARPredictor().predict(q)
    assert fc.info["n_fitted"] == 3 and fc.info["n_fit_failed"] == 0
    # over 8 frames the forecast stays within 5 cm of the constant-velocity continuation
    v = (q.history[:, -1] - q.history[:, -11]) / 10
    cv = q.history[:, -1][:, None] + np.arange(1, 9)[None, :, None] * v[:, None]
    assert np.abs(fc.positions - cv).max() < 0.05


def test_fallbacks_are_counted_like_darts():
    q = _walk_query([60, 20, 60, 60, 60])
    q.history[2] = np.array([1.0, 2.0])  # stands still: degenerate
    q.history[3] = np.array([1.0, 2.0]) + np.arange(60)[:, None] * np.array([0.03, 0.01])
    q.history[4, -1] = [np.nan, 1.0]  # no current position
    fc = VARPredictor().predict(q)
    info = fc.info
    assert info["n_fitted"] == 1 and info["n_short_history"] == 1
    assert info["n_degenerate"] == 2 and info["n_nonfinite_current"] == 1
    assert np.isnan(fc.positions[4]).all() and np.isfinite(fc.positions[:4]).all()
    # an exactly linear walk is continued exactly by the constant-velocity fallback
    np.testing.assert_allclose(fc.positions[3, -1], q.history[3, -1] + 8 * np.array([0.03, 0.01]))


def test_gap_uses_only_the_trailing_run_and_the_fit_window():
    q = _walk_query([60])
    gap = PredictionQuery(q.ids, q.history.copy(), q.dt, q.horizon)
    gap.history[0, :5] = np.nan  # outside the last 50 samples: no effect
    np.testing.assert_array_equal(
        VARPredictor().predict(gap).positions, VARPredictor().predict(q).positions
    )
    gap.history[0, 40] = np.nan  # inside: only 19 trailing samples remain -> short
    assert VARPredictor().predict(gap).info["n_short_history"] == 1
    assert VARPredictor(p=2, min_history=10).predict(gap).info["n_fitted"] == 1


def test_explosive_fit_is_shrunk_and_counted():
    q = _walk_query([60, 60])
    fc = VARPredictor(max_radius=0.05).predict(q)
    assert fc.info["n_shrunk"] == 2
    assert np.isfinite(fc.positions).all()


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"p": 0}, "p must be"),
        ({"min_history": 5}, "min_history must be"),
        ({"fit_window": 20}, "fit_window"),
        ({"max_radius": 1.0}, "max_radius"),
    ],
)
def test_bad_parameters_are_clear_errors(kw, match):
    with pytest.raises(ValueError, match=match):
        VARPredictor(**kw).predict(_walk_query([60]))
