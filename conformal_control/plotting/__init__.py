"""Plotting (matplotlib). One module per kind of figure; all re-exported here."""

from .reproduce import plot_lambda_loss_rows, plot_lavg_vs_epsilon, plot_paths_grid
from .run import plot_lambda_loss, plot_run, plot_scene

__all__ = [
    "plot_lambda_loss",
    "plot_lambda_loss_rows",
    "plot_lavg_vs_epsilon",
    "plot_paths_grid",
    "plot_run",
    "plot_scene",
]
