"""``conformal-control plot-sweep``: summary figure of a sweep's results table."""

from __future__ import annotations

import argparse
from pathlib import Path

from . import command


@command("plot-sweep", "plot metrics against a swept parameter from a results CSV")
def _plot_sweep_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("results", metavar="RESULTS_CSV", help="one row per run: parameters, metrics")
    p.add_argument("--x", default="epsilon", help="swept parameter on the x axis (epsilon)")
    p.add_argument(
        "--metric",
        action="append",
        default=None,
        help="metric column, one panel each (repeatable; default t_goal, n_collide, d_min, l_avg)",
    )
    p.add_argument(
        "--group",
        action="append",
        default=None,
        help="column whose values get separate lines (repeatable; default: every parameter "
        "that varies, besides --x; the others are averaged and the legend says so)",
    )
    p.add_argument(
        "--out", default=None, help="output image (default: sweep-<x>.png beside RESULTS_CSV)"
    )


@_plot_sweep_args.handler
def _plot_sweep(args: argparse.Namespace) -> int:
    from ...io.plotting.sweep import load_results, plot_sweep

    rows = load_results(args.results)
    metrics = args.metric or ["t_goal", "n_collide", "d_min", "l_avg"]
    out = Path(args.out) if args.out else Path(args.results).parent / f"sweep-{args.x}.png"
    plot_sweep(rows, args.x, metrics, group=args.group, path=out)
    print(f"{len(rows)} results plotted to {out}")
    return 0
