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
    "n_collide": "collision frames (count)",
    "d_min": "d_min (m)",
    "l_avg": "average loss (dimensionless)",
    "fallback_share": "fallback share (fraction of control steps)",
    "lambda_final": "final lambda (scene units)",
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


#: Columns naming what a run is, besides its parameters (sweep ``results.csv``).
_IDENTITY = ("scene", "predictor", "learn", "max_frames", "rule")
#: Columns of repeated runs of the same configuration: averaged, and the legend says so.
_REPLICATES = ("seed",)
_PREFIXES = ("param.", "predictor_params.", "rule_params.")


def _column(rows: Sequence[Mapping[str, Any]], name: str) -> str:
    """The column holding ``name``: itself, or ``param.<name>`` in a sweep's results.csv."""
    for cand in (name, *(p + name for p in _PREFIXES)):
        if any(cand in r for r in rows):
            return cand
    raise ValueError(f"no result has the key {name!r}; keys: {sorted(rows[0])}")


def _short(col: str) -> str:
    for p in _PREFIXES:
        if col.startswith(p):
            return col[len(p) :]
    return col


def _value_key(v: Any) -> Any:
    f = _num(v)
    return f if math.isfinite(f) else ("" if v is None else str(v))


def _fmt_value(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _parameter_columns(rows: Sequence[Mapping[str, Any]], exclude: set[str]) -> list[str]:
    """Columns that are parameters of the runs (not metrics, not bookkeeping).

    In a sweep's ``results.csv`` the parameters are the ``param.*`` columns, and a bare
    column named like a parameter is a metric (``lambda_min``: the lowest lambda reached;
    ``epsilon``, ``eta``: the values used, in SI); in plain rows without such columns a
    column named after a controller parameter is that parameter. A column that names the
    same parameter as one of ``exclude`` (the x axis, the lines) is never another one.
    """
    from ...core.spec import PARAMETERS

    cols = list(dict.fromkeys(k for r in rows for k in r))
    prefixed = any(c.startswith(_PREFIXES) for c in cols)
    taken = {_short(c) for c in exclude}
    out = []
    for col in cols:
        if col in exclude or col in _REPLICATES or _short(col) in taken:
            continue
        if col.startswith(_PREFIXES) or col in _IDENTITY or (col in PARAMETERS and not prefixed):
            out.append(col)
    return out


def _x_label(x: str) -> str:
    name = _short(x)
    if name == "epsilon":
        return "epsilon (target average loss, dimensionless)"
    if name in ("v_max",):
        return f"{name} (m/s)"
    if name in ("robot_radius", "agent_radius", "goal_radius"):
        return f"{name} (m)"
    return f"{name} (scene units: px, frames on SDD; SI otherwise)"


def plot_sweep(
    results: str | Path | Iterable[Mapping[str, Any]],
    x: str = "epsilon",
    metrics: Sequence[str] = ("t_goal", "n_collide", "d_min", "l_avg"),
    *,
    group: str | Sequence[str] | None = None,
    path: str | Path | None = None,
    title: str | None = None,
) -> Figure:
    """One panel per metric, the metric against ``x``; nothing is averaged silently.

    Lines: one per combination of the values of every parameter that varies across the
    results and is not on the x axis (``group`` restricts the lines to those columns; the
    other varying parameters are then averaged, and the line under the title names them
    with their values). Repeated runs of one configuration (``seed``) are averaged with
    their min-max range shaded, and the line under the title says over how many (or "one
    run"). Lines differ in style and marker as well as colour, so lines that
    coincide stay visible; the panels share one x label. Parameters are the sweep's
    ``param.*`` / ``predictor_params.*`` columns, ``scene``, ``predictor``, ``learn``,
    ``max_frames``, ``rule``, and any column named after a controller parameter (so in
    plain rows ``eta`` or ``tau`` count, metrics do not). ``x`` and ``group`` may name a
    parameter without its ``param.`` prefix. When ``x`` is ``epsilon`` and ``l_avg`` is
    plotted, the line ``l_avg = epsilon`` that the CDT guarantee aims at is drawn dashed;
    collision frames get an integer axis from 0.

    Parameters
    ----------
    results : list of dict, or path to a CSV
        One row per run with the swept parameters and the metrics as keys/columns.
    x : str
        The swept parameter on the horizontal axis.
    metrics : sequence of str
        Metric keys, one panel each.
    group : str or list of str, optional
        The columns whose values get separate lines (default: every varying parameter).
    path : path, optional
        Save the figure there (and close it).
    title : str, optional
        Figure title (default: the scene(s), what is plotted and the number of runs).

    Raises
    ------
    ValueError
        If there are no rows, or ``x``, a metric or a group column is missing from every row.
    """
    from matplotlib.ticker import MaxNLocator

    from .run import pyplot

    rows = load_results(results)
    if not rows:
        raise ValueError("plot_sweep needs at least one result")
    x = _column(rows, x)
    metrics = [_column(rows, m) for m in metrics]
    if group is None:
        params = _parameter_columns(rows, {x, *metrics})
        lines = [c for c in params if len({_value_key(r.get(c)) for r in rows}) > 1]
    else:
        lines = [_column(rows, g) for g in ([group] if isinstance(group, str) else group)]
    params = _parameter_columns(rows, {x, *metrics, *lines})
    varying = [c for c in params if len({_value_key(r.get(c)) for r in rows}) > 1]
    averaged = [c for c in varying if c not in lines]
    replicates = [
        c for c in _REPLICATES if c not in lines and len({_value_key(r.get(c)) for r in rows}) > 1
    ]

    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(tuple(_value_key(r.get(c)) for c in lines), []).append(r)
    notes = []
    for c in replicates:
        n = len({_value_key(r.get(c)) for r in rows})
        notes.append(f"mean over {n} {c}s (min-max shaded)")
    for c in averaged:
        vals = sorted({_value_key(r.get(c)) for r in rows}, key=str)
        notes.append(f"averaged over {_short(c)} in {{{', '.join(map(_fmt_value, vals))}}}")
    if not notes:
        notes.append("one run")

    plt = pyplot()
    fig: Figure
    fig, axes = plt.subplots(
        1, len(metrics), figsize=(3.8 * len(metrics), 3.9), constrained_layout=True, squeeze=False
    )
    styles = list(zip(("-", "--", ":", "-.") * 3, "osD^vP<>*hXp", strict=True))
    for ax, metric in zip(axes[0], metrics, strict=True):
        for i, (gval, grows) in enumerate(groups.items()):
            xs = np.array([_num(r.get(x)) for r in grows])
            ys = np.array([_num(r.get(metric)) for r in grows])
            ux = np.unique(xs[np.isfinite(xs)])
            mean, lo, hi = [], [], []
            for u in ux:
                v = ys[(xs == u) & np.isfinite(ys)]
                mean.append(v.mean() if v.size else np.nan)
                lo.append(v.min() if v.size else np.nan)
                hi.append(v.max() if v.size else np.nan)
            label = ", ".join(
                f"{_short(c)} = {_fmt_value(v)}" for c, v in zip(lines, gval, strict=True)
            )
            ls, mk = styles[i % len(styles)]  # lines that coincide stay visible
            (line,) = ax.plot(ux, mean, ls=ls, marker=mk, ms=4, label=label or "all runs")
            if any(a != b for a, b in zip(lo, hi, strict=True)):
                ax.fill_between(ux, lo, hi, alpha=0.2, color=line.get_color())
        if _short(metric) == "l_avg" and _short(x) == "epsilon":
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
        if _short(metric) == "n_collide":
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
            top = np.nanmax([_num(r.get(metric)) for r in rows] + [0.0])
            ax.set_ylim(0, max(1.0, 1.1 * top))
        ax.set_ylabel(_LABELS.get(_short(metric), _short(metric)))
        ax.grid(alpha=0.3)
    fig.supxlabel(_x_label(x), fontsize=10)  # one label for the panels: none overlaps
    axes[0][-1].legend(fontsize=7)
    if title is None:
        scenes = sorted({str(r["scene"]) for r in rows if r.get("scene") not in (None, "")})
        what = ", ".join(_short(m) for m in metrics)
        title = f"{' / '.join(scenes) + ': ' if scenes else ''}{what} against {_short(x)}"
        title += f" ({len(rows)} runs)"
    # what each point is, under the title: exactly what was averaged (or nothing)
    fig.suptitle(f"{title}\neach point: {'; '.join(notes)}", fontsize=10)
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig
