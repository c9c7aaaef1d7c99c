"""Compiled rollouts of the built-in plants: many command sequences from one state.

The sampling MPC rolls out hundreds of sequences per plan; these loops do it in one
compiled call each (the numpy versions spend their time in dozens of small array
operations per step). Each equals the plant's ``step`` applied in a loop to round-off,
which the contract kit checks (``check_dynamics_rollout``).
"""

from __future__ import annotations

import math

import numpy as np

from ...core.jit import kernel

__all__ = ["tracking_rollout", "unicycle_rollout"]

jit = kernel(cache=True, nogil=True)


@jit
def _wrap(theta: float) -> float:
    """theta in [-pi, pi) (a step turns by less than a few turns: a loop, no division)."""
    while theta >= math.pi:
        theta -= 2.0 * math.pi
    while theta < -math.pi:
        theta += 2.0 * math.pi
    return theta


@jit
def _unicycle_rollout(
    state: np.ndarray,
    v: np.ndarray,
    w: np.ndarray,
    chalf: np.ndarray,
    shalf: np.ndarray,
    dt: float,
    exact: bool,
) -> np.ndarray:
    n, h = v.shape
    out = np.empty((n, h, 5))
    c0 = math.cos(state[4])
    s0 = math.sin(state[4])
    for i in range(n):
        x = state[0]
        y = state[1]
        th = state[4]
        c = c0
        s = s0
        for j in range(h):
            vj = v[i, j]
            wj = w[i, j]
            half = 0.5 * wj * dt
            ch = chalf[i, j]
            sh = shalf[i, j]
            if exact:
                arc = vj * dt * (sh / half if abs(half) > 1e-9 else 1.0)
                x += arc * (c * ch - s * sh)
                y += arc * (s * ch + c * sh)
            else:
                x += vj * dt * c
                y += vj * dt * s
            # rotate by 2 half = w dt
            c2 = 1.0 - 2.0 * sh * sh
            s2 = 2.0 * sh * ch
            c, s = c * c2 - s * s2, s * c2 + c * s2
            th = _wrap(th + wj * dt)
            out[i, j, 0] = x
            out[i, j, 1] = y
            out[i, j, 2] = vj * c
            out[i, j, 3] = vj * s
            out[i, j, 4] = th
    return out


def unicycle_rollout(
    state: np.ndarray, v: np.ndarray, w: np.ndarray, dt: float, exact: bool
) -> np.ndarray:
    """Unicycle states (N, H, 5) under saturated commands ``v``, ``w`` of shape (N, H).

    The heading's cosine and sine are carried along and rotated by each step's turn,
    whose half-angle cosines and sines are computed beforehand in one vectorised call
    (the loop itself is then arithmetic only).

    Parameters
    ----------
    state : ndarray of shape (5,)
        The start state (x, y, vx, vy, heading): m, m/s, rad.
    v : ndarray of shape (N, H)
        Forward speeds (m/s), already saturated.
    w : ndarray of shape (N, H)
        Turn rates (rad/s), already saturated.
    dt : float
        Step duration (s).
    exact : bool
        Integrate each step exactly along its arc (constant v and w over the step;
        True) or by one Euler step (False).

    Returns
    -------
    ndarray of shape (N, H, 5)
        The state at the end of every step, heading wrapped to (-pi, pi].
    """
    half = 0.5 * dt * np.asarray(w, dtype=np.float64)
    out: np.ndarray = _unicycle_rollout(
        np.asarray(state, dtype=np.float64),
        np.ascontiguousarray(v, dtype=np.float64),
        np.ascontiguousarray(w, dtype=np.float64),
        np.cos(half),
        np.sin(half),
        float(dt),
        bool(exact),
    )
    return out


@jit
def tracking_rollout(
    state: np.ndarray, cmd: np.ndarray, dt: float, decay: float, gain: float
) -> np.ndarray:
    """Velocity-tracking double-integrator states (N, H, 4) under velocity commands
    ``cmd`` of shape (N, H, 2)."""
    n, h = cmd.shape[0], cmd.shape[1]
    out = np.empty((n, h, 4))
    for i in range(n):
        x = state[0]
        y = state[1]
        vx = state[2]
        vy = state[3]
        for j in range(h):
            cx = cmd[i, j, 0]
            cy = cmd[i, j, 1]
            dx = vx - cx
            dy = vy - cy
            x = x + cx * dt + dx * gain
            y = y + cy * dt + dy * gain
            vx = cx + dx * decay
            vy = cy + dy * decay
            out[i, j, 0] = x
            out[i, j, 1] = y
            out[i, j, 2] = vx
            out[i, j, 3] = vy
    return out
