"""Bootstrap CIs against known distributions; paired comparisons."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.bench.stats import bootstrap_mean, paired_comparison


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
