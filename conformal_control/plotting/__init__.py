"""Plotting (matplotlib). One module per kind of figure; all re-exported here."""

from .guarantee import plot_guarantee
from .run import plot_lambda_loss, plot_run, plot_scene

__all__ = ["plot_guarantee", "plot_lambda_loss", "plot_run", "plot_scene"]
