"""One summary plot of a sweep (``summary.png``) instead of a plot per run.

The horizontal axis is the swept controller parameter (``epsilon`` first, then the other
parameters in the order of ``spec.PARAMETERS``, then predictor parameters, then the
seed); one line is drawn per value of another swept column with few values (predictor,
learn, label, scene, another parameter). Runs that share a point - other axes, seeds - are
averaged with their min-max range shaded (:func:`conformal_control.io.plotting.sweep.plot_sweep`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["SUMMARY_METRICS", "summary_axes", "write_summary_plot"]

#: Metrics of the summary plot, one panel each (those present in the results).
SUMMARY_METRICS = ("t_goal", "n_collide", "d_min", "l_avg")
_MAX_GROUPS = 6


def _varying(rows: Sequence[Mapping[str, Any]], col: str) -> list[Any]:
    values = []
    for r in rows:
        v = r.get(col)
        if v is not None and v not in values:
            values.append(v)
    return values if len(values) > 1 else []


def _numeric(values: Sequence[Any]) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)


def summary_axes(rows: Sequence[Mapping[str, Any]]) -> tuple[str | None, str | None]:
    """The column on the horizontal axis and the column of the lines (either may be None).

    Parameters
    ----------
    rows : list of dict
        Flat result rows of the ok runs (``ResultsStore.rows``).
    """
    from ..core.spec import PARAMETERS

    cols: list[str] = []
    for r in rows:
        cols += [c for c in r if c not in cols]
    params = [f"param.{p}" for p in ("epsilon", *PARAMETERS) if f"param.{p}" in cols]
    params = list(dict.fromkeys(params))
    pparams = sorted(c for c in cols if c.startswith("predictor_params."))
    x = None
    for col in [*params, *pparams, "seed"]:
        values = _varying(rows, col)
        if values and _numeric(values):
            x = col
            break
    if x is None:
        return None, None
    for col in ["predictor", "learn", "label", "scene", *params, *pparams]:
        values = _varying(rows, col)
        if col != x and 1 < len(values) <= _MAX_GROUPS:
            return x, col
    return x, None


def write_summary_plot(
    rows: Sequence[Mapping[str, Any]], path: str | os.PathLike[str]
) -> tuple[Path | None, str]:
    """Plot the ok runs of ``rows`` to ``path`` (PNG, written atomically).

    Returns
    -------
    (path or None, note)
        The file written, or None with the reason there is nothing to plot.
    """
    from ..io.plotting.run import pyplot
    from ..io.plotting.sweep import plot_sweep
    from .results import atomic_write

    ok = [dict(r) for r in rows if r.get("status") == "ok"]
    if not ok:
        return None, "no summary plot: no run finished ok"
    x, group = summary_axes(ok)
    if x is None:
        return None, "no summary plot: no numeric parameter varies across the ok runs"
    metrics = [m for m in SUMMARY_METRICS if any(r.get(m) is not None for r in ok)]
    if not metrics:
        return None, "no summary plot: the runs have none of " + ", ".join(SUMMARY_METRICS)

    def short(col: str) -> str:
        return col.removeprefix("param.")

    xs, gs = short(x), (short(group) if group else None)
    # the swept columns as they are (param.epsilon): a bare "epsilon" or "lambda_min" in
    # the results is a metric, never averaged over
    fig = plot_sweep(ok, x, metrics, group=group)
    try:
        atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110))
    finally:
        pyplot().close(fig)
    where = f"{xs} on the x axis" + (f", one line per {gs}" if gs else "")
    return Path(path), f"summary plot ({where}): {path}"
