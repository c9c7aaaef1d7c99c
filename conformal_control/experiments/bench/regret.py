"""Adaptive methods against every fixed margin: the benchmark's no-regret comparison.

A method that adapts lambda should do at least as well as every fixed lambda it could have
run instead, whatever the shift: the fixed margin re-tuned on the reported split (which
knows the shift) included. Per shift, each adaptive method (a family that learns lambda)
is compared with the whole fixed-lambda grid the folder ran (the reference family,
``fixed``), on the three figures the benchmark ranks by: success rate, the rate of
reaching the goal in time, collision frames per scenario (means over the same
scenarios):

* **dominated**: a fixed lambda at least as good on all three figures and better on one;
* **regret** to the best fixed lambda in hindsight, figure by figure (the best member on
  that figure; positive: the grid did better, by that much);
* the difference to the re-tuned fixed lambda (the tuning rule's choice on this split).

:func:`issue_targets` checks the per-agent issue's targets on these figures: under
``delay-0.5s`` and ``noise-0.25m``, at most half of ``nolearn``'s collision frames, the
goal reached in time within 5 points of ``nolearn`` and no fixed lambda dominating; under
``nominal``, success within 2 points of ``nolearn``'s.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

__all__ = [
    "FIGURES",
    "GridComparison",
    "TargetCheck",
    "compare_with_grid",
    "issue_targets",
]

#: (figure, higher is better) of the comparison: the leaderboard's columns.
FIGURES: tuple[tuple[str, bool], ...] = (
    ("success", True),
    ("reached", True),
    ("collision frames", False),
)


class _Summary(Protocol):
    """What the comparison reads of a leaderboard row (``report.MethodSummary``)."""

    @property
    def method(self) -> str: ...

    @property
    def family(self) -> str: ...

    @property
    def estimates(self) -> Mapping[str, Any]: ...


@dataclass
class GridComparison:
    """One adaptive method against a fixed-lambda grid, under one shift.

    Attributes
    ----------
    shift, method, family : str
    figures : dict
        The method's mean success, reached and collision frames.
    dominated_by : list of str
        The grid members at least as good on every figure and better on one.
    regret : dict
        Per figure, the best grid member's value minus the method's, oriented so that a
        positive regret means the grid did better (collision frames: the method's minus
        the best member's).
    best : dict
        Per figure, the grid member with the best value.
    reference : str or None
        The grid member re-tuned on this split (the tuning rule's choice).
    to_reference : dict
        Per figure, the method minus the reference (oriented like ``regret``, with the
        opposite sign: positive means the method did better).
    """

    shift: str
    method: str
    family: str
    figures: dict[str, float]
    dominated_by: list[str] = field(default_factory=list)
    regret: dict[str, float] = field(default_factory=dict)
    best: dict[str, str] = field(default_factory=dict)
    reference: str | None = None
    to_reference: dict[str, float] = field(default_factory=dict)

    @property
    def dominated(self) -> bool:
        return bool(self.dominated_by)


def _mean(s: _Summary, figure: str) -> float:
    return float(s.estimates[figure].mean)


def _better(a: float, b: float, higher: bool) -> bool:
    return a > b if higher else a < b


def compare_with_grid(
    shift: str,
    summaries: Sequence[_Summary],
    grid: Sequence[str],
    adaptive: Sequence[str],
    reference: str | None = None,
) -> list[GridComparison]:
    """Each method of ``adaptive`` against the methods of ``grid`` (means of
    ``summaries``, one shift).

    Parameters
    ----------
    shift : str
        The shift the summaries are of.
    summaries : sequence
        The shift's leaderboard rows (``report.MethodSummary``).
    grid : sequence of str
        The fixed-lambda methods (the reference family's members that ran).
    adaptive : sequence of str
        The methods compared with the grid.
    reference : str, optional
        The grid member re-tuned on this split.
    """
    by = {s.method: s for s in summaries}
    members = [by[m] for m in grid if m in by]
    out = []
    for name in adaptive:
        s = by.get(name)
        if s is None or not members:
            continue
        figs = {f: _mean(s, f) for f, _ in FIGURES}
        comp = GridComparison(shift, s.method, s.family, figs, reference=reference)
        for g in members:
            vals = {f: _mean(g, f) for f, _ in FIGURES}
            no_worse = all(
                not _better(figs[f], vals[f], hi) for f, hi in FIGURES if math.isfinite(vals[f])
            )
            strictly = any(_better(vals[f], figs[f], hi) for f, hi in FIGURES)
            if no_worse and strictly:
                comp.dominated_by.append(g.method)
        for f, hi in FIGURES:
            ranked = [(_mean(g, f), g.method) for g in members if math.isfinite(_mean(g, f))]
            if not ranked:
                continue
            value, who = max(ranked) if hi else min(ranked)
            comp.regret[f] = (value - figs[f]) if hi else (figs[f] - value)
            comp.best[f] = who
            if reference is not None and reference in by:
                r = _mean(by[reference], f)
                comp.to_reference[f] = (figs[f] - r) if hi else (r - figs[f])
        out.append(comp)
    return out


@dataclass
class TargetCheck:
    """The issue's targets for one method (see the module docstring).

    Attributes
    ----------
    method : str
    shifts : dict
        Per stressed shift: (collision frames / nolearn's, reached minus nolearn's in
        points, dominated, all three met), or None when the shift was not run.
    nominal : tuple or None
        (success minus nolearn's in points, met) under ``nominal``.
    """

    method: str
    shifts: dict[str, tuple[float, float, bool, bool] | None]
    nominal: tuple[float, bool] | None

    @property
    def met(self) -> bool:
        """Every target met (every stressed shift run and met, nominal run and met)."""
        return (
            all(v is not None and v[3] for v in self.shifts.values())
            and self.nominal is not None
            and self.nominal[1]
        )


#: The shifts the targets stress, and the limits: collision frames at most this share of
#: nolearn's, the goal reached within this many points of nolearn's, nominal success
#: within this many points.
STRESSED = ("delay-0.5s", "noise-0.25m")
COLLISION_SHARE, REACH_POINTS, NOMINAL_POINTS = 0.5, 5.0, 2.0


def issue_targets(
    views: Mapping[str, Sequence[_Summary]],
    comparisons: Mapping[str, Sequence[GridComparison]],
    methods: Sequence[str],
    baseline: str = "nolearn",
) -> list[TargetCheck]:
    """The targets of the per-agent issue for each of ``methods``.

    Parameters
    ----------
    views : mapping
        shift -> its leaderboard rows.
    comparisons : mapping
        shift -> :func:`compare_with_grid`'s result.
    methods : sequence of str
        The dev-tuned adaptive methods checked.
    baseline : str
        The method the targets are relative to.
    """
    out = []
    for name in methods:
        shifts: dict[str, tuple[float, float, bool, bool] | None] = {}
        for sh in STRESSED:
            by = {s.method: s for s in views.get(sh, ())}
            comp = next((c for c in comparisons.get(sh, ()) if c.method == name), None)
            if name not in by or baseline not in by:
                shifts[sh] = None
                continue
            m, b = by[name], by[baseline]
            bf = _mean(b, "collision frames")
            ratio = _mean(m, "collision frames") / bf if bf > 0 else math.nan
            reach = 100 * (_mean(m, "reached") - _mean(b, "reached"))
            dominated = comp.dominated if comp is not None else False
            ok = (
                math.isfinite(ratio)
                and ratio <= COLLISION_SHARE
                and reach >= -REACH_POINTS
                and not dominated
                and comp is not None
            )
            shifts[sh] = (ratio, reach, dominated, ok)
        by = {s.method: s for s in views.get("nominal", ())}
        nominal = None
        if name in by and baseline in by:
            d = 100 * (_mean(by[name], "success") - _mean(by[baseline], "success"))
            nominal = (d, d >= -NOMINAL_POINTS)
        out.append(TargetCheck(name, shifts, nominal))
    return out
