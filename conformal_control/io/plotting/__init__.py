"""Plotting (matplotlib). One module per kind of figure; all re-exported here.

* :mod:`.run` - the scene with the robot's path, lambda(t) and loss(t), the run figure;
* :mod:`.distance` - distance to the nearest pedestrian with the collision threshold;
* :mod:`.guarantee` - running average loss against epsilon and the rule's bounds;
* :mod:`.sweep` - sweep summaries (a metric against epsilon, eta, tau, ...);
* :mod:`.reproduce` - the figures of ``conformal-control reproduce``;
* :mod:`.animation` - frames of a run for ``conformal-control animate``.
"""

from .animation import render_animation
from .distance import plot_distance
from .guarantee import plot_guarantee
from .reproduce import plot_lambda_loss_rows, plot_lavg_vs_epsilon, plot_paths_grid
from .run import plot_lambda_loss, plot_run, plot_scene
from .sweep import load_results, plot_sweep

__all__ = [
    "load_results",
    "plot_distance",
    "plot_guarantee",
    "plot_lambda_loss",
    "plot_lambda_loss_rows",
    "plot_lavg_vs_epsilon",
    "plot_paths_grid",
    "plot_run",
    "plot_scene",
    "plot_sweep",
    "render_animation",
]
