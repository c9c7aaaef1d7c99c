"""Random control sequences for the sampling MPC, in the command space of the plant.

Commands are piecewise constant over blocks of ``hold`` plan steps (a plan of H steps has
``ceil(H / hold)`` free commands), drawn uniformly:

* a **unicycle** (``command_kind == "unicycle"``): ``(v, omega)`` uniform in the plant's box
  of limits (as the published sampling MPCs of the ETH/UCY planar protocol draw them);
* a **velocity** command: speed uniform in ``[0, v_max]`` and direction uniform in
  ``[-pi, pi)`` (every speed equally likely, so the samples reach the bound often);
* an **acceleration** command: the same in a disc of radius ``a_max``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["sample_sequences"]


def sample_sequences(
    rng: np.random.Generator,
    n: int,
    horizon: int,
    hold: int,
    *,
    box: tuple[np.ndarray, np.ndarray] | None = None,
    radius: float = 1.0,
) -> np.ndarray:
    """``n`` random command sequences of ``horizon`` steps, shape (n, horizon, 2).

    Parameters
    ----------
    rng : numpy Generator
    n, horizon, hold : int
        Sequences, steps per sequence, steps each drawn command is held for.
    box : (low, high), optional
        Draw each command uniformly in this box (a unicycle's limits) ...
    radius : float
        ... else in the disc of this radius: speed uniform in [0, radius], direction
        uniform.
    """
    blocks = math.ceil(horizon / hold)
    if box is not None:
        lo, hi = box
        u = rng.uniform(lo, hi, size=(n, blocks, 2))
    else:
        speed = rng.uniform(0.0, radius, size=(n, blocks))
        angle = rng.uniform(-math.pi, math.pi, size=(n, blocks))
        u = np.stack([speed * np.cos(angle), speed * np.sin(angle)], axis=-1)
    out: np.ndarray = np.repeat(u, hold, axis=1)[:, :horizon]
    return out
