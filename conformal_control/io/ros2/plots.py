"""The shadow-mode figure: the recorded scene, commanded against recorded speed, lambda
and the loss."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from .bag import RecordedBag

__all__ = ["ShadowRun", "plot_shadow"]


class ShadowRun(Protocol):
    """What the figure reads of a shadow-mode result
    (:class:`~conformal_control.io.ros2.shadow.ShadowResult` is one; typed by what it holds,
    so the shadow module and its figure import each other in no direction but one)."""

    bag: RecordedBag
    commands: dict[str, np.ndarray]
    config: dict[str, Any]


def plot_shadow(res: ShadowRun, path: str | Path | None = None) -> Figure:
    """Three panels: the map (the robot's recorded path, the people's tracks, the goal,
    the commanded velocity every second as arrows); the recorded and the commanded speed
    over time, with the instants the controller fell back; lambda and the intervals' loss
    against epsilon.

    Parameters
    ----------
    res : ShadowRun
        A shadow-mode result (:class:`~conformal_control.io.ros2.shadow.ShadowResult`).
    path : path, optional
        Where to save the figure (PNG); it is returned either way.
    """
    from ..plotting.run import SAVE_DPI, png_options, pyplot

    plt = pyplot()
    fig: Figure
    fig, (ax_map, ax_v, ax_l) = plt.subplots(
        3, 1, figsize=(7, 10), gridspec_kw={"height_ratios": [2.2, 1, 1]}
    )
    people, odom, c = res.bag.people, res.bag.odometry, res.commands
    t0 = int(res.config["t0_ns"])
    in_span = (odom.stamps >= t0) & (odom.stamps <= t0 + int(c["t"][-1] * 1e9) + 1)
    for pid in range(len(people.names)):
        pts = [
            p[ids == pid][0]
            for ids, p in zip(people.ids, people.positions, strict=True)
            if (ids == pid).any()
        ]
        if pts:
            arr = np.array(pts)
            ax_map.plot(arr[:, 0], arr[:, 1], color="0.6", lw=0.8)
    ax_map.plot(*odom.xy[in_span].T, color="tab:blue", lw=2, label="robot (recorded)")
    goal = res.config["goal"]
    ax_map.plot(goal[0], goal[1], marker="*", ms=14, color="tab:green", ls="", label="goal")
    every = max(1, round(1.0 / max(c["t"][1] - c["t"][0], 1e-9))) if c["t"].size > 1 else 1
    xy = np.stack([np.interp(c["stamp_ns"], odom.stamps, odom.xy[:, j]) for j in (0, 1)], axis=1)
    ax_map.quiver(
        xy[::every, 0],
        xy[::every, 1],
        c["vx"][::every],
        c["vy"][::every],
        color="tab:orange",
        angles="xy",
        scale_units="xy",
        scale=1.0,
        width=0.004,
        label="command (1 s)",
    )
    ax_map.set_aspect("equal", adjustable="datalim")
    ax_map.set_xlabel(f"x (m, {res.config['frame']})")
    ax_map.set_ylabel("y (m)")
    ax_map.legend(loc="best", fontsize=8)
    ax_map.set_title(f"shadow mode: {res.bag.path.name} ({res.config['family']})")
    rec_speed = np.hypot(
        *np.stack([np.interp(c["stamp_ns"], odom.stamps, odom.velocity[:, j]) for j in (0, 1)])
    )
    ax_v.plot(c["t"], rec_speed, color="tab:blue", label="recorded")
    ax_v.plot(c["t"], np.hypot(c["vx"], c["vy"]), color="tab:orange", label="commanded")
    fb = c["fallback"] > 0
    if fb.any():
        ax_v.plot(
            c["t"][fb], np.hypot(c["vx"], c["vy"])[fb], "x", color="tab:red", label="fallback"
        )
    ax_v.set_ylabel("speed (m/s)")
    ax_v.legend(loc="best", fontsize=8)
    ax_l.plot(c["t"], c["lambda"], color="tab:purple", label="lambda")
    scored = np.isfinite(c["loss"])
    ax_l.plot(c["t"][scored], c["loss"][scored], "o", ms=3, color="tab:red", label="loss")
    eps = res.config.get("epsilon")
    if eps is not None and np.isfinite(eps):
        ax_l.axhline(eps, color="k", lw=0.8, ls="--", label="epsilon")
    ax_l.set_xlabel("t (s since the start)")
    ax_l.legend(loc="best", fontsize=8)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=SAVE_DPI, **png_options(path))
        plt.close(fig)
    return fig
