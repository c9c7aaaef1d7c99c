"""The guarantee monitor as a figure: running average loss against target and bounds."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ...core.monitor import AgentMonitor, GuaranteeMonitor

__all__ = ["plot_agent_guarantee", "plot_guarantee"]


def plot_guarantee(
    monitor: GuaranteeMonitor | AgentMonitor,
    path: str | Path | None = None,
    *,
    title: str | None = None,
    lambda_unit: float = 1.0,
    lambda_label: str = "lambda",
) -> Figure:
    """Two panels: the running average loss with epsilon and the rule's bounds; lambda_k.

    Top: running average loss after each update, the target epsilon, the Theorem-2 bound
    epsilon + (lambda_1 - lambda_safe + eta)/(eta k) when it applies (fixed-step rules with
    lambda_safe; labelled with the monitor's verdict), and the band epsilon +- b_k for rules
    with a long-run bound b_k (decaying step, ACI, PID). The vertical axis stays within the
    loss range ``monitor.bounds``: the band is clipped to it, and a bound that never enters
    it (e.g. PID's b_k = 1.93 for losses in (-1/2, 1/2)) is written on the panel instead
    of drawn. Bottom: lambda_k (divided by ``lambda_unit``). A run with lambda per agent
    (an :class:`~conformal_control.core.monitor.AgentMonitor`) is drawn by
    :func:`plot_agent_guarantee`.

    Parameters
    ----------
    monitor : GuaranteeMonitor or AgentMonitor
        ``LoopResult.monitor`` of a finished run.
    path : path, optional
        Where to save the figure (PNG); the figure is returned either way.
    title : str, optional
        The figure's title.
    lambda_unit : float
        lambda_k is drawn divided by this (its SI value of the unit shown).
    lambda_label : str
        The label of lambda's axis.
    """
    from ...core.monitor import AgentMonitor
    from .run import SAVE_DPI, png_options, pyplot

    if isinstance(monitor, AgentMonitor):
        return plot_agent_guarantee(
            monitor, path, title=title, lambda_unit=lambda_unit, lambda_label=lambda_label
        )
    plt = pyplot()  # Agg outside Jupyter; keeps the inline backend in notebooks
    # a fixed layout (a layout engine would cost a second drawing pass): room on the left
    # for the tick labels and axis labels, below for the x label, above for the title
    fig: Figure
    fig, (ax, ax_l) = plt.subplots(
        2,
        1,
        figsize=(7, 5.5),
        sharex=True,
        gridspec_kw={"left": 0.95 / 7, "right": 6.85 / 7, "bottom": 0.59 / 5.5,
                     "top": 5.16 / 5.5, "hspace": 0.09},
    )  # fmt: skip
    k = np.arange(1, monitor.n + 1)
    if monitor.n:
        ax.plot(k, monitor.running_average(), color="C0", lw=1.5, label="running average loss")
        ax.plot(k, monitor.losses, color="C0", lw=0.5, alpha=0.3, label="loss $l_k$")
    ax.axhline(monitor.epsilon, color="k", ls="--", lw=1, label=r"target $\varepsilon$")
    lo, hi = monitor.bounds
    eps = monitor.epsilon
    # the y range: the losses, epsilon and the bounds where they say something, within the
    # loss range; a bound that leaves the loss range is annotated instead of drawn
    ys = [eps]
    if monitor.n:
        ys += [float(np.min(monitor.losses)), float(np.max(monitor.losses))]
    notes = []
    bound = monitor.bound_trace()
    if bound is not None:
        verdict = getattr(monitor, "verdict", None)
        held = (
            f"verdict: {verdict}" if verdict else ("holds" if monitor.bound_holds else "VIOLATED")
        )
        if bound[-1] < hi:
            shown = np.where(bound <= hi, bound, np.nan)  # enters from above the loss range
            ax.plot(k, shown, color="C3", lw=1.2, label=f"Theorem-2 bound ({held})")
            ys.append(float(bound[-1]))
        else:
            notes.append(
                f"Theorem-2 bound {bound[-1]:.3g} at k = {monitor.n} is above the largest "
                f"possible loss {hi:g}: vacuous ({held})"
            )
    band = monitor.long_run_trace()
    if band is not None and np.isfinite(band).any():
        held = "holds" if monitor.long_run_holds else "VIOLATED"
        last = float(band[np.isfinite(band)][-1])
        if eps - last <= lo and eps + last >= hi:
            notes.append(
                f"long-run bound |mean loss - eps| <= {last:.3g} covers the whole loss range "
                f"({lo:g}, {hi:g}): vacuous ({held})"
            )
        else:
            ax.fill_between(
                k,
                np.clip(eps - band, lo, hi),
                np.clip(eps + band, lo, hi),
                color="C2",
                alpha=0.15,
                label=f"long-run bound, clipped to the loss range ({held})",
            )
            ys += [max(lo, eps - last), min(hi, eps + last)]
    pad = 0.1 * (max(ys) - min(ys) + 1e-9)
    ax.set_ylim(max(lo, min(ys) - pad), min(hi, max(ys) + pad))
    for i, note in enumerate(notes):
        ax.text(
            0.01,
            0.03 + 0.09 * i,
            note,
            transform=ax.transAxes,
            fontsize=7,
            color="0.25",
            bbox={"facecolor": "white", "alpha": 0.8, "lw": 0},
        )
    res = monitor.identity_residual
    note = f"guarantee: {monitor.kind}" + (
        f", identity residual {res:.1e}" if res is not None else ""
    )
    ax.set_title(title or note, fontsize=9)
    ax.set_ylabel("loss (dimensionless)")
    ax.legend(fontsize=7, loc="upper right")
    if monitor.n:
        lams = np.asarray([*monitor.lambdas, monitor.lambda_next]) / lambda_unit
        ax_l.step(np.arange(1, lams.size + 1), lams, where="post", color="C1")
    ax_l.set_xlabel("update k")
    ax_l.set_ylabel(lambda_label)
    if path is not None:
        fig.savefig(path, dpi=SAVE_DPI, **png_options(path))
        plt.close(fig)
    return fig


def plot_agent_guarantee(
    monitor: AgentMonitor,
    path: str | Path | None = None,
    *,
    title: str | None = None,
    lambda_unit: float = 1.0,
    lambda_label: str = "lambda",
) -> Figure:
    """The guarantee of lambda run per agent: each agent's average loss against its number
    of losses, and each agent's lambda over the run.

    Top: one point per agent, its average loss against K_j (its scored intervals), agents
    with fewer than ``monitor.min_intervals`` losses hollow (their bound is of order 1/K_j);
    the target epsilon; the pooled average of every agent's losses; each agent's own bound
    (Theorem 2 with ``lambda_safe``, else the rule's long-run bound) as a red tick above
    its point, with the count of agents that meet it. Bottom: each agent's lambda at the
    intervals it was scored in (divided by ``lambda_unit``).

    Parameters
    ----------
    monitor : AgentMonitor
        ``LoopResult.monitor`` of a run with lambda per agent.
    path : path, optional
        Where to save the figure (PNG); the figure is returned either way.
    title : str, optional
        The figure's title.
    lambda_unit : float
        lambda is drawn divided by this (its SI value of the unit shown).
    lambda_label : str
        The label of lambda's axis.
    """
    from .run import SAVE_DPI, png_options, pyplot

    plt = pyplot()
    fig: Figure
    fig, (ax, ax_l) = plt.subplots(
        2,
        1,
        figsize=(7, 5.5),
        gridspec_kw={"left": 0.95 / 7, "right": 6.85 / 7, "bottom": 0.59 / 5.5,
                     "top": 5.16 / 5.5, "hspace": 0.35},
    )  # fmt: skip
    per = monitor.agents(min_intervals=1)
    eps = monitor.epsilon
    checked = per["n"] >= monitor.min_intervals
    ax.scatter(
        per["n"][checked],
        per["l_avg"][checked],
        s=18,
        color="C0",
        label=f"agent, >= {monitor.min_intervals} losses ({int(checked.sum())})",
    )
    ax.scatter(
        per["n"][~checked],
        per["l_avg"][~checked],
        s=18,
        facecolors="none",
        edgecolors="C0",
        label=f"agent, fewer losses ({int((~checked).sum())})",
    )
    ax.axhline(eps, color="k", ls="--", lw=1, label=r"target $\varepsilon$")
    if monitor.n:
        ax.axhline(
            monitor.average, color="C0", ls=":", lw=1, label=f"pooled average ({monitor.n} losses)"
        )
    has = np.isfinite(per["bound"])
    if has.any():
        met = int((per["l_avg"][has & checked] <= per["bound"][has & checked] + 1e-12).sum())
        ax.scatter(
            per["n"][has],
            per["bound"][has],
            marker="_",
            s=60,
            color="C3",
            label=f"each agent's bound (met by {met} of {int((has & checked).sum())})",
        )
    lo, hi = monitor.bounds  # the y range: points, epsilon and bounds, within the loss range
    inside = per["bound"][has][per["bound"][has] < hi]  # a bound above hi says nothing
    ys = [eps, *per["l_avg"].tolist(), *inside.tolist()]
    pad = 0.1 * (max(ys) - min(ys) + 1e-3)
    ax.set_ylim(max(lo, min(ys) - pad), min(hi, max(ys) + pad))
    ax.set_xlabel("losses of the agent (scored intervals K_j)")
    ax.set_ylabel("agent's average loss")
    res = monitor.identity_residual
    note = f"lambda per agent, guarantee per agent: {monitor.kind}" + (
        f", largest identity residual {res:.1e}" if res is not None else ""
    )
    clipped = [k for k, m in monitor.entries.items() if m.n_clipped]
    if clipped:  # a clipped agent's identity no longer holds: its loss stayed above epsilon
        sel = np.isin(per["key"], clipped)
        ax.scatter(per["n"][sel], per["l_avg"][sel], s=60, facecolors="none", edgecolors="C3",
                   label=f"lambda clipped at some update ({int(sel.sum())})")  # fmt: skip
    ax.set_title(title or note, fontsize=9)
    ax.legend(fontsize=7, loc="best")
    for i, key in enumerate(per["key"].tolist()):
        ks, lams = monitor.history(int(key))
        ax_l.plot(ks + 1, lams / lambda_unit, lw=0.8, color=f"C{i % 10}", marker=".", ms=2)
    floor = monitor.rule.lambda_min
    if np.isfinite(floor):
        ax_l.axhline(floor / lambda_unit, color="0.4", ls=":", lw=1, label="lambda_min (floor)")
        ax_l.legend(fontsize=7, loc="best")
    ax_l.set_xlabel("interval k")
    ax_l.set_ylabel(f"{lambda_label} (one line per agent)")
    if path is not None:
        fig.savefig(path, dpi=SAVE_DPI, **png_options(path))
        plt.close(fig)
    return fig
