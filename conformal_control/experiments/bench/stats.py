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

__all__ = [
    "Estimate",
    "PairedComparison",
    "bootstrap_mean",
    "bootstrap_means",
    "paired_comparison",
    "paired_comparisons",
]


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


#: Integer-valued samples are summed exactly below this bound (float64's integers).
_EXACT = float(2**52)


def _resample_means(xs: list[np.ndarray], n_resamples: int, seed: int) -> list[np.ndarray]:
    """The bootstrap distributions of the means of samples ``xs`` of one size ``n``, as
    ``scipy.stats.bootstrap`` computes each (``n_resamples`` x ``n`` indices drawn from
    a fresh generator of ``seed``, ``x[..., idx]``, ``np.mean(axis=-1)``), to the bit.

    The indices depend on ``n`` and the seed only, so they are drawn once for all. When
    several samples are integer-valued (rates, frame counts: most of a report's
    columns), they are summed through the counts matrix (how often each value is drawn
    in each resample) in one product: their sums are exact integers either way, so
    ``counts @ x / n`` is the same float as the mean of the gathered resample.
    """
    n = xs[0].size
    idx = np.random.default_rng(seed).integers(0, n, size=(n_resamples, n), dtype=np.int64)
    exact = [bool(np.all(x == np.round(x)) and n * float(np.abs(x).max()) < _EXACT) for x in xs]
    out: list[np.ndarray] = [np.empty(0)] * len(xs)
    if sum(exact) >= 3:  # below that, building the counts costs more than it saves
        rows = np.arange(n_resamples, dtype=np.int64)[:, None] * n
        counts = np.bincount((idx + rows).ravel(), minlength=n_resamples * n)
        which = [i for i, e in enumerate(exact) if e]
        sums = counts.reshape(n_resamples, n).astype(np.float64) @ np.stack(
            [xs[i] for i in which], axis=1
        )
        for j, i in enumerate(which):
            out[i] = sums[:, j] / n
    else:
        exact = [False] * len(xs)
    for i, x in enumerate(xs):
        if not exact[i]:
            out[i] = np.mean(x[..., idx], axis=-1)
    return out


def bootstrap_means(
    samples: Sequence[Sequence[float] | np.ndarray],
    *,
    confidence: float = 0.95,
    n_resamples: int = 2000,
    seed: int = 0,
) -> list[Estimate]:
    """:func:`bootstrap_mean` of each sample, the same numbers to the bit, in one pass.

    The percentile bootstrap of ``scipy.stats.bootstrap`` (``method="percentile"``, the
    resamples of a fresh generator of ``seed``, ``scipy.stats.quantile`` of the
    resampled means), computed here for many samples at once because a report asks
    for thousands of intervals: the resample indices of a size are drawn once, not per
    interval, integer-valued samples are summed through their counts, and the quantiles
    of all samples are taken in one call. ``tests/experiments/bench/test_stats.py`` checks every
    bound against ``scipy.stats.bootstrap`` itself.

    Parameters
    ----------
    samples : sequence of sequences of float
        One sample per interval (NaNs are left out and not counted).
    confidence : float
        Confidence level of the intervals.
    n_resamples : int
        Bootstrap resamples.
    seed : int
        Seed of the resampling of every sample.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    if n_resamples < 1:
        raise ValueError(f"n_resamples must be at least 1, got {n_resamples}")
    out: list[Estimate] = []
    by_size: dict[int, list[tuple[int, np.ndarray]]] = {}  # n -> (slot, sorted sample)
    for values in samples:
        x = np.asarray(values, dtype=float).ravel()
        x = np.sort(x[np.isfinite(x)])  # the resamples index the sorted values: order-free
        n = int(x.size)
        if n == 0:
            out.append(Estimate(math.nan, math.nan, math.nan, 0))
            continue
        mean = float(x.mean())
        if n == 1 or np.all(x == x[0]):
            out.append(Estimate(mean, mean, mean, n))
            continue
        by_size.setdefault(n, []).append((len(out), x))
        out.append(Estimate(mean, math.nan, math.nan, n))  # the bounds below
    if by_size:
        from scipy.stats import quantile

        slots: list[int] = []
        dists: list[np.ndarray] = []
        for group in by_size.values():
            slots += [slot for slot, _ in group]
            dists += _resample_means([x for _, x in group], n_resamples, seed)
        alpha = np.asarray((1 - confidence) / 2, dtype=np.float64)
        probs = np.stack((alpha, 1 - alpha), axis=-1)
        ci = quantile(np.stack(dists), probs, axis=-1)
        for slot, (low, high) in zip(slots, ci, strict=True):
            e = out[slot]
            out[slot] = Estimate(e.mean, float(low), float(high), e.n)
    return out


def bootstrap_mean(
    values: Sequence[float] | np.ndarray,
    *,
    confidence: float = 0.95,
    n_resamples: int = 2000,
    seed: int = 0,
) -> Estimate:
    """Mean of ``values`` with a percentile-bootstrap CI (NaNs are left out and not counted).

    The finite values are sorted before resampling: the interval depends on the values
    and the seed, not on their order. The interval is ``scipy.stats.bootstrap``'s
    (``method="percentile"``, a fresh generator of ``seed``), computed as
    :func:`bootstrap_means` does.

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
    return bootstrap_means([values], confidence=confidence, n_resamples=n_resamples, seed=seed)[0]


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
    return paired_comparisons(
        [(method, baseline, metric, lower_is_better)],
        confidence=confidence,
        n_resamples=n_resamples,
        seed=seed,
    )[0]


def paired_comparisons(
    pairs: Sequence[tuple[Sequence[float] | np.ndarray, Sequence[float] | np.ndarray, str, bool]],
    *,
    confidence: float = 0.95,
    n_resamples: int = 2000,
    seed: int = 0,
) -> list[PairedComparison]:
    """:func:`paired_comparison` of each ``(method, baseline, metric, lower_is_better)``,
    the intervals computed together (:func:`bootstrap_means`): the same results.

    Parameters
    ----------
    pairs : sequence of (method, baseline, metric, lower_is_better)
        The arguments of one :func:`paired_comparison` each.
    confidence : float
        Level of the bootstrap intervals.
    n_resamples : int
        Bootstrap resamples.
    seed : int
        Seed of every bootstrap.
    """
    diffs, counts = [], []
    for method, baseline, metric, lower_is_better in pairs:
        a = np.asarray(method, dtype=float)
        b = np.asarray(baseline, dtype=float)
        if a.shape != b.shape:
            raise ValueError(f"paired values need the same shape, got {a.shape} and {b.shape}")
        ok = np.isfinite(a) & np.isfinite(b)
        d = a[ok] - b[ok]
        better = d < 0 if lower_is_better else d > 0
        worse = d > 0 if lower_is_better else d < 0
        diffs.append(d)
        counts.append((metric, int(d.size), int(better.sum()), int(worse.sum()),
                       int((d == 0).sum()), lower_is_better))  # fmt: skip
    est = bootstrap_means(diffs, confidence=confidence, n_resamples=n_resamples, seed=seed)
    return [
        PairedComparison(
            metric=metric,
            n=n,
            wins=wins,
            losses=losses,
            ties=ties,
            difference=e,
            lower_is_better=lower,
        )
        for (metric, n, wins, losses, ties, lower), e in zip(counts, est, strict=True)
    ]
