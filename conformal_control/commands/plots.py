"""``conformal-control plot-sweep``: summary figure of a sweep's results table."""

from __future__ import annotations

import argparse

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
    p.add_argument("--group", default=None, help="column whose values get separate lines")
    p.add_argument("--out", default="sweep.png", help="output image (default sweep.png)")


@_plot_sweep_args.handler
def _plot_sweep(args: argparse.Namespace) -> int:
    from ..plotting.sweep import load_results, plot_sweep

    rows = load_results(args.results)
    metrics = args.metric or ["t_goal", "n_collide", "d_min", "l_avg"]
    plot_sweep(rows, args.x, metrics, group=args.group, path=args.out)
    print(f"{len(rows)} results plotted to {args.out}")
    return 0
