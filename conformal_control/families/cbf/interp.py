"""Piecewise-linear interpolation of sampled trajectories at control instants.

Predicted and true trajectories are both sampled at the scene's frame rate. Between
samples the position is interpolated linearly and the velocity is the exact time
derivative of that interpolant (per second), so a perfect predictor reproduces the true
positions and velocities bit for bit.
"""

from __future__ import annotations

import numpy as np

__all__ = ["forward_fill", "interpolate_at_substeps"]


def interpolate_at_substeps(
    samples: np.ndarray, dt: float, substeps: int, n_steps: int
) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities at control instants ``s * dt / substeps``.

    Parameters
    ----------
    samples : ndarray of shape (N, F + 1, 2)
        Positions at times ``0, dt, ..., F dt`` (NaN where unknown).
    dt : float
        Sample spacing in seconds.
    substeps : int
        Control instants per sample interval.
    n_steps : int
        Number of control instants wanted (at most ``F * substeps``).

    Returns
    -------
    pos, vel : ndarrays of shape (n_steps, N, 2)
        NaN wherever one of the two bracketing samples is NaN.
    """
    _n_agents, n_samples, _ = samples.shape
    if n_steps > (n_samples - 1) * substeps:
        raise ValueError(
            f"{n_steps} control instants need {n_steps / substeps:.0f} sample intervals, "
            f"only {n_samples - 1} given"
        )
    steps = np.arange(n_steps)
    idx = steps // substeps
    frac = ((steps % substeps) / substeps)[:, None, None]
    p0 = samples[:, idx, :].transpose(1, 0, 2)
    p1 = samples[:, idx + 1, :].transpose(1, 0, 2)
    delta = p1 - p0
    return p0 + frac * delta, delta / dt


def forward_fill(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Replace non-finite samples by the last finite one along axis 1.

    The first sample of every row must be finite. Returns the filled copy and a boolean
    mask of shape (N,) telling which rows had a non-finite sample.
    """
    bad = ~np.isfinite(samples).all(axis=-1)
    rows = bad.any(axis=1)
    if not rows.any():
        return samples, rows
    if bad[:, 0].any():
        raise ValueError("forward_fill needs a finite first sample in every row")
    idx = np.where(bad, 0, np.arange(samples.shape[1])[None, :])
    idx = np.maximum.accumulate(idx, axis=1)
    filled = np.take_along_axis(samples, idx[:, :, None], axis=1)
    return filled, rows
