"""Sweep summaries: a metric against a swept parameter (epsilon, eta, tau, ...)."""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["load_results", "plot_sweep"]

_LABELS = {
    "t_goal": "t_goal (s)",
    "n_collide": "collision frames",
    "d_min": "d_min (m)",
    "l_avg": "average loss",
    "fallback_share": "fallback share",
    "lambda_final": "final lambda",
}


def _num(v: Any) -> float:
    if v is None or v == "":
        return math.nan
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def load_results(source: str | Path | Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Rows of a sweep: a list of dicts as is, or the rows of a CSV file."""
    if isinstance(source, (str, Path)):
        with Path(source).open(newline="") as fh:
            return [dict(r) for r in csv.DictReader(fh)]
    return [dict(r) for r in source]


def plot_sweep(
    results: str | Path | Iterable[Mapping[str, Any]],
    x: str = "epsilon",
    metrics: Sequence[str] = ("t_goal", "n_collide", "d_min", "l_avg"),
    *,
    group: str | None = None,
    path: str | Path | None = None,
) -> Figure:
    """One panel per metric, the metric against ``x``; one line per value of ``group``.

    Rows with the same ``x`` (and group) are averaged, with their min-max range shaded
    (e.g. several seeds). When ``x`` is ``epsilon`` and ``l_avg`` is plotted, the line
    ``l_avg = epsilon`` that the CDT guarantee aims at is drawn dashed.

    Parameters
    ----------
    results : list of dict, or path to a CSV
        One row per run with the swept parameters and the metrics as keys/columns.
    x : str
        The swept parameter on the horizontal axis.
    metrics : sequence of str
        Metric keys, one panel each.
    group : str, optional
        Column whose values get separate lines (e.g. ``"predictor"`` or ``"eta"``).
    path : path, optional
        Save the figure there (and close it).

    Raises
    ------
    ValueError
        If there are no rows, or ``x`` or a metric is missing from every row.
    """
    from .run import _mpl

    rows = load_results(results)
    if not rows:
        raise ValueError("plot_sweep needs at least one result")
    for key in (x, *metrics):
        if not any(key in r for r in rows):
            raise ValueError(f"no result has the key {key!r}; keys: {sorted(rows[0])}")
    plt = _mpl()
    fig, axes = plt.subplots(
        1, len(metrics), figsize=(3.6 * len(metrics), 3.2), constrained_layout=True, squeeze=False
    )
    groups: dict[Any, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(r.get(group) if group else None, []).append(r)
    for ax, metric in zip(axes[0], metrics, strict=True):
        for gval, grows in groups.items():
            xs = np.array([_num(r.get(x)) for r in grows])
            ys = np.array([_num(r.get(metric)) for r in grows])
            ux = np.unique(xs[np.isfinite(xs)])
            mean, lo, hi = [], [], []
            for u in ux:
                v = ys[(xs == u) & np.isfinite(ys)]
                mean.append(v.mean() if v.size else np.nan)
                lo.append(v.min() if v.size else np.nan)
                hi.append(v.max() if v.size else np.nan)
            label = f"{group} = {gval}" if group else None
            ax.plot(ux, mean, "o-", ms=4, label=label)
            if any(a != b for a, b in zip(lo, hi, strict=True)):
                ax.fill_between(ux, lo, hi, alpha=0.2)
        if metric == "l_avg" and x == "epsilon":
            xx = np.array([_num(r.get(x)) for r in rows])
            xx = xx[np.isfinite(xx)]
            if xx.size:
                ax.plot(
                    [xx.min(), xx.max()],
                    [xx.min(), xx.max()],
                    "k--",
                    lw=0.8,
                    label="l_avg = epsilon",
                )
        ax.set_xlabel(x)
        ax.set_ylabel(_LABELS.get(metric, metric))
        ax.grid(alpha=0.3)
        if group or (metric == "l_avg" and x == "epsilon"):
            ax.legend(fontsize=7)
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig
