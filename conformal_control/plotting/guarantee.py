"""The guarantee monitor as a figure: running average loss against target and bounds."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..monitor import GuaranteeMonitor

__all__ = ["plot_guarantee"]


def plot_guarantee(
    monitor: GuaranteeMonitor,
    path: str | Path | None = None,
    *,
    title: str | None = None,
    lambda_unit: float = 1.0,
    lambda_label: str = "lambda",
) -> Figure:
    """Two panels: the running average loss with epsilon and the rule's bounds; lambda_k.

    Top: running average loss after each update, the target epsilon, the Theorem-2 bound
    epsilon + (lambda_1 - lambda_safe + eta)/(eta k) when it applies (fixed-step rules with
    lambda_safe), and the band epsilon +- b_k for rules with a long-run bound b_k
    (decaying step, ACI, PID). Bottom: lambda_k (divided by ``lambda_unit``).

    Parameters
    ----------
    monitor : GuaranteeMonitor
        ``LoopResult.monitor`` of a finished run.
    path : path, optional
        Where to save the figure (PNG); the figure is returned either way.
    """
    from .run import _mpl

    plt = _mpl()  # Agg outside Jupyter; keeps the inline backend in notebooks
    fig, (ax, ax_l) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    k = np.arange(1, monitor.n + 1)
    if monitor.n:
        ax.plot(k, monitor.running_average(), color="C0", lw=1.5, label="running average loss")
        ax.plot(k, monitor.losses, color="C0", lw=0.5, alpha=0.3, label="loss $l_k$")
    ax.axhline(monitor.epsilon, color="k", ls="--", lw=1, label=r"target $\varepsilon$")
    bound = monitor.bound_trace()
    if bound is not None:
        held = "holds" if monitor.bound_holds else "VIOLATED"
        ax.plot(k, bound, color="C3", lw=1.2, label=f"Theorem-2 bound ({held})")
    band = monitor.long_run_trace()
    if band is not None:
        held = "holds" if monitor.long_run_holds else "VIOLATED"
        ax.fill_between(
            k,
            monitor.epsilon - band,
            monitor.epsilon + band,
            color="C2",
            alpha=0.15,
            label=f"long-run bound ({held})",
        )
    lo, hi = monitor.bounds
    if monitor.n:
        losses = np.asarray(monitor.losses)
        pad = 0.1 * (losses.max() - losses.min() + 1e-9)
        ax.set_ylim(max(lo, losses.min() - pad), min(hi, losses.max() + pad))
    res = monitor.identity_residual
    note = f"guarantee: {monitor.kind}" + (
        f", identity residual {res:.1e}" if res is not None else ""
    )
    ax.set_title(title or note, fontsize=9)
    ax.set_ylabel("loss")
    ax.legend(fontsize=7, loc="upper right")
    if monitor.n:
        lams = np.asarray([*monitor.lambdas, monitor.lambda_next]) / lambda_unit
        ax_l.step(np.arange(1, lams.size + 1), lams, where="post", color="C1")
    ax_l.set_xlabel("update k")
    ax_l.set_ylabel(lambda_label)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig
