"""Ego dynamics (plants). States are flat arrays ``(x, y, vx, vy)`` in SI units."""

from __future__ import annotations

import math

import numpy as np

from .roles import Dynamics

__all__ = ["DoubleIntegrator", "VelocityTrackingDoubleIntegrator"]


def _as_state(state: np.ndarray) -> np.ndarray:
    state = np.asarray(state, dtype=float)
    if state.shape != (4,):
        raise ValueError(f"state must have shape (4,) = (x, y, vx, vy), got {state.shape}")
    return state


def _check_dt(dt: float) -> float:
    if not (math.isfinite(dt) and dt >= 0):
        raise ValueError(f"dt must be a finite number >= 0, got {dt!r}")
    return float(dt)


class DoubleIntegrator(Dynamics):
    """Planar double integrator; the command is the acceleration, held over the step.

    Integrated exactly: x' = x + v dt + a dt^2/2, v' = v + a dt.
    """

    state_dim = 4

    def step(self, state: np.ndarray, command: np.ndarray, dt: float) -> np.ndarray:
        s = _as_state(state)
        dt = _check_dt(dt)
        a = np.asarray(command, dtype=float)
        out = np.empty(4)
        out[:2] = s[:2] + s[2:] * dt + 0.5 * a * dt * dt
        out[2:] = s[2:] + a * dt
        return out


class VelocityTrackingDoubleIntegrator(Dynamics):
    """Double integrator under the tracking law u = -K_acc (v - v_cmd).

    The command is the desired velocity ``v_cmd`` (the QP's safe velocity), held over the
    step while the tracking law acts continuously. The closed loop is linear and is
    integrated exactly::

        v(t) = v_cmd + (v0 - v_cmd) exp(-K t)
        x(t) = x0 + v_cmd t + (v0 - v_cmd) (1 - exp(-K t)) / K

    Parameters
    ----------
    K_acc : float
        Tracking gain in 1/s (> 0).
    """

    state_dim = 4

    def __init__(self, K_acc: float = 60.0) -> None:
        self.K_acc = K_acc

    def step(self, state: np.ndarray, command: np.ndarray, dt: float) -> np.ndarray:
        s = _as_state(state)
        dt = _check_dt(dt)
        k = float(self.K_acc)
        if not (math.isfinite(k) and k > 0):
            raise ValueError(f"K_acc must be a finite number > 0, got {self.K_acc!r}")
        v_cmd = np.asarray(command, dtype=float)
        dv = s[2:] - v_cmd
        decay = math.exp(-k * dt)
        out = np.empty(4)
        out[:2] = s[:2] + v_cmd * dt + dv * (-math.expm1(-k * dt)) / k
        out[2:] = v_cmd + dv * decay
        return out
