"""Statistics of the benchmark: bootstrap confidence intervals and paired comparisons.

Every figure of a leaderboard is an average over scenarios; its uncertainty is the
sampling uncertainty of the scenario set, estimated with the percentile bootstrap over
scenarios (``scipy.stats.bootstrap``, seeded). The values are sorted before they are
resampled, so an interval is a function of the multiset of values and the seed alone,
never of the order the rows were stored in (a process pool stores them in the order its
episodes finish). A comparison of two methods uses the
scenarios both ran (paired): wins / losses / ties per scenario and a paired bootstrap CI of
the mean difference.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Estimate", "PairedComparison", "bootstrap_mean", "paired_comparison"]


@dataclass(frozen=True)
class Estimate:
    """A mean over scenarios with its bootstrap confidence interval.

    Attributes
    ----------
    mean : float
        NaN when there is no value.
    low, high : float
        The CI bounds (equal to the mean for a single value or a constant sample).
    n : int
        Number of values (scenarios).
    """

    mean: float
    low: float
    high: float
    n: int

    def format(self, digits: int = 3, percent: bool = False) -> str:
        """``mean [low, high]``, optionally as percentages."""
        if self.n == 0 or math.isnan(self.mean):
            return "-"
        f = 100.0 if percent else 1.0
        unit = " %" if percent else ""
        return (
            f"{self.mean * f:.{digits}g}{unit} "
            f"[{self.low * f:.{digits}g}, {self.high * f:.{digits}g}]"
        )


def bootstrap_mean(
    values: Sequence[float] | np.ndarray,
    *,
    confidence: float = 0.95,
    n_resamples: int = 2000,
    seed: int = 0,
) -> Estimate:
    """Mean of ``values`` with a percentile-bootstrap CI (NaNs are left out and not counted).

    The finite values are sorted before resampling: the interval depends on the values
    and the seed, not on their order.

    Parameters
    ----------
    values : sequence of float
        One value per scenario (booleans give rates).
    confidence : float
        Confidence level of the interval.
    n_resamples : int
        Bootstrap resamples.
    seed : int
        Seed of the resampling (results are reproducible).
    """
    x = np.asarray(values, dtype=float).ravel()
    x = np.sort(x[np.isfinite(x)])  # the resamples index the sorted values: order-free
    n = int(x.size)
    if n == 0:
        return Estimate(math.nan, math.nan, math.nan, 0)
    mean = float(x.mean())
    if n == 1 or np.all(x == x[0]):
        return Estimate(mean, mean, mean, n)
    from scipy.stats import bootstrap

    res = bootstrap(
        (x,),
        np.mean,
        confidence_level=confidence,
        n_resamples=n_resamples,
        method="percentile",
        random_state=np.random.default_rng(seed),
        vectorized=True,
    )
    ci = res.confidence_interval
    return Estimate(mean, float(ci.low), float(ci.high), n)


@dataclass(frozen=True)
class PairedComparison:
    """A method against a baseline on the scenarios both ran.

    ``difference`` is the mean of (method - baseline) with its paired bootstrap CI;
    a *win* is a scenario where the method is better (``lower_is_better`` says which
    direction is better), a *tie* one with equal values.
    """

    metric: str
    n: int
    wins: int
    losses: int
    ties: int
    difference: Estimate
    lower_is_better: bool


def paired_comparison(
    method: Sequence[float] | np.ndarray,
    baseline: Sequence[float] | np.ndarray,
    *,
    metric: str = "",
    lower_is_better: bool = True,
    confidence: float = 0.95,
    n_resamples: int = 2000,
    seed: int = 0,
) -> PairedComparison:
    """Wins / losses / ties and the paired bootstrap CI of the mean difference.

    ``method[i]`` and ``baseline[i]`` are the same scenario; pairs with a NaN are left out.

    Parameters
    ----------
    method, baseline : sequence of float
        The metric per scenario, same length.
    metric : str
        Its name (recorded).
    lower_is_better : bool
        Whether a smaller value wins.
    confidence : float
        Level of the bootstrap interval.
    n_resamples : int
        Bootstrap resamples.
    seed : int
        Seed of the bootstrap.
    """
    a = np.asarray(method, dtype=float)
    b = np.asarray(baseline, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"paired values need the same shape, got {a.shape} and {b.shape}")
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    d = a - b
    better = d < 0 if lower_is_better else d > 0
    worse = d > 0 if lower_is_better else d < 0
    return PairedComparison(
        metric=metric,
        n=int(d.size),
        wins=int(better.sum()),
        losses=int(worse.sum()),
        ties=int((d == 0).sum()),
        difference=bootstrap_mean(d, confidence=confidence, n_resamples=n_resamples, seed=seed),
        lower_is_better=lower_is_better,
    )
