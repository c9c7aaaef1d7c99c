"""Bootstrap CIs against known distributions; paired comparisons."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.experiments.bench.stats import bootstrap_mean, paired_comparison


def test_bootstrap_ci_covers_the_true_mean_at_its_level() -> None:
    """Over 200 samples of a known distribution the 90 % CI covers the mean ~90 % of the
    time (binomial tolerance), and its width shrinks like 1/sqrt(n)."""
    rng = np.random.default_rng(1)
    covered = 0
    trials = 200
    for i in range(trials):
        x = rng.exponential(2.0, size=60)  # true mean 2
        est = bootstrap_mean(x, confidence=0.9, n_resamples=800, seed=i)
        covered += est.low <= 2.0 <= est.high
    # percentile bootstrap under-covers slightly for skewed data at n = 60
    assert 0.80 * trials <= covered <= 0.97 * trials
    wide = bootstrap_mean(rng.normal(0, 1, 50), seed=0)
    narrow = bootstrap_mean(rng.normal(0, 1, 800), seed=0)
    assert (narrow.high - narrow.low) < 0.4 * (wide.high - wide.low)


def test_bootstrap_rate_and_degenerate_samples() -> None:
    est = bootstrap_mean([True, False, True, True], seed=0)
    assert est.mean == pytest.approx(0.75) and est.n == 4 and est.low < 0.75 < est.high + 1e-12
    assert bootstrap_mean([3.0, 3.0]).low == 3.0 == bootstrap_mean([3.0, 3.0]).high
    empty = bootstrap_mean([math.nan])
    assert empty.n == 0 and math.isnan(empty.mean) and empty.format() == "-"
    assert bootstrap_mean([1.0, 2.0, 3.0], seed=5) == bootstrap_mean([1.0, 2.0, 3.0], seed=5)


def test_paired_comparison_counts_and_ci() -> None:
    base = np.array([5.0, 3.0, 0.0, 2.0, np.nan, 4.0])
    meth = np.array([1.0, 3.0, 1.0, 0.0, 1.0, 4.5])
    c = paired_comparison(meth, base, metric="n_collide")
    assert (c.n, c.wins, c.losses, c.ties) == (5, 2, 2, 1)
    assert c.difference.mean == pytest.approx(np.mean([-4.0, 0.0, 1.0, -2.0, 0.5]))
    # a method better on every scenario: the CI of the difference excludes 0
    rng = np.random.default_rng(0)
    b = rng.uniform(1, 5, 100)
    strong = paired_comparison(b - rng.uniform(0.5, 1.0, 100), b)
    assert strong.wins == 100 and strong.difference.high < 0
    with pytest.raises(ValueError, match="same shape"):
        paired_comparison([1.0], [1.0, 2.0])


def test_the_interval_does_not_depend_on_the_order_of_the_values() -> None:
    """The bootstrap resampled the values in the order given: shuffling a results file's
    lines moved the intervals (209 cells of leaderboard.csv)."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=37)
    first = bootstrap_mean(x, seed=0)
    for _ in range(5):
        assert bootstrap_mean(rng.permutation(x), seed=0) == first
    pc = paired_comparison(x, x[::-1] + 0.1, seed=0)
    order = rng.permutation(x.size)
    assert paired_comparison(x[order], (x[::-1] + 0.1)[order], seed=0) == pc


def _scipy_bootstrap(values, *, confidence=0.95, n_resamples=2000, seed=0):
    """The interval exactly as ``scipy.stats.bootstrap`` gives it (the reference)."""
    from scipy.stats import bootstrap

    x = np.asarray(values, dtype=float)
    x = np.sort(x[np.isfinite(x)])
    res = bootstrap(
        (x,),
        np.mean,
        confidence_level=confidence,
        n_resamples=n_resamples,
        method="percentile",
        random_state=np.random.default_rng(seed),
        vectorized=True,
    )
    return float(x.mean()), float(res.confidence_interval.low), float(res.confidence_interval.high)


def test_the_batched_bootstrap_is_scipys_to_the_bit() -> None:
    """``bootstrap_means`` draws the indices once per size and sums integer-valued samples
    through their counts: every bound must still be exactly scipy's (rates, counts, large
    counts beyond the exact-sum shortcut, floats, NaNs; samples of shared and lone sizes)."""
    from conformal_control.experiments.bench.stats import bootstrap_means

    rng = np.random.default_rng(11)
    samples: list[np.ndarray] = []
    for n in (2, 7, 40, 40, 40, 40, 131, 131, 131, 300):
        samples += [
            rng.integers(0, 2, n).astype(float),  # a rate
            rng.integers(0, 60, n).astype(float),  # frame counts
            rng.normal(3.0, 2.0, n),  # seconds, metres
            np.round(rng.normal(0.0, 10.0, n)) / 4,  # quarters: not integers
        ]
    samples.append(rng.integers(0, 2, 40) * 2.0**50)  # integer, beyond the exact-sum shortcut
    with_nan = rng.integers(0, 9, 60).astype(float)
    with_nan[::7] = np.nan
    samples.append(with_nan)
    for seed, confidence, n_resamples in ((0, 0.95, 2000), (5, 0.9, 333)):
        got = bootstrap_means(samples, seed=seed, confidence=confidence, n_resamples=n_resamples)
        for x, e in zip(samples, got, strict=True):
            ref = _scipy_bootstrap(x, seed=seed, confidence=confidence, n_resamples=n_resamples)
            assert (e.mean, e.low, e.high) == ref
            assert e == bootstrap_mean(x, seed=seed, confidence=confidence, n_resamples=n_resamples)


def test_batched_paired_comparisons_equal_one_at_a_time() -> None:
    from conformal_control.experiments.bench.stats import paired_comparisons

    rng = np.random.default_rng(4)
    pairs = []
    for i in range(6):
        a = rng.integers(0, 5, 80).astype(float)
        b = rng.normal(2.0, 1.0, 80) if i % 2 else rng.integers(0, 5, 80).astype(float)
        pairs.append((a, b, f"m{i}", bool(i % 3)))
    got = paired_comparisons(pairs, seed=3)
    for (a, b, metric, lower), pc in zip(pairs, got, strict=True):
        assert pc == paired_comparison(a, b, metric=metric, lower_is_better=lower, seed=3)
    with pytest.raises(ValueError, match="same shape"):
        paired_comparisons([([1.0], [1.0, 2.0], "x", True)])
