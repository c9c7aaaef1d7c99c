"""``render()`` of the RL environments: the world now as an RGB array (matplotlib)."""

from __future__ import annotations

import numpy as np

from ..world.multi import MultiRobotWorld

__all__ = ["render_world"]


def render_world(world: MultiRobotWorld, width: float = 4.8, dpi: int = 80) -> np.ndarray:
    """The pedestrians, the robots (their sensing radius dashed) and their goals."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle

    sc = world.scene
    x = world.positions
    n = x.shape[0]
    fig = Figure(figsize=(width, 0.6 * width), dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0.08, 0.1, 0.9, 0.85))
    peds = world.pedestrians()[world.frame_index]
    ok = np.isfinite(peds[:, 0])
    ax.scatter(peds[ok, 0], peds[ok, 1], s=10, c="0.35")
    colours = [f"C{i % 10}" for i in range(n)]
    for i in range(n):
        ax.add_patch(Circle(tuple(x[i, :2]), sc.robot_radius, color=colours[i]))
        ax.add_patch(
            Circle(
                tuple(x[i, :2]), world.sensing_radius, fill=False, ls="--", lw=0.5, color=colours[i]
            )
        )
        g = world.current_goal(i)
        ax.plot(g[0], g[1], "*", color=colours[i], ms=8)
    if sc.extent is not None:
        ax.set_xlim(0, sc.extent[0])
        ax.set_ylim(sc.extent[1], 0)
    else:
        lo = np.nanmin(x[:, :2], axis=0) - world.sensing_radius
        hi = np.nanmax(x[:, :2], axis=0) + world.sensing_radius
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(hi[1], lo[1])
    ax.set_aspect("equal")
    ax.set_title(f"t = {world.t:.2f} s", fontsize=8)
    canvas.draw()  # type: ignore[no-untyped-call]
    rgba = np.asarray(canvas.buffer_rgba())  # type: ignore[no-untyped-call]
    return np.ascontiguousarray(rgba[..., :3])
