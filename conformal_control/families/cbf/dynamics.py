"""Ego dynamics (plants). States are flat arrays starting ``(x, y, vx, vy)`` in SI units.

==========================  =====================================  =====================
plant                       command                                state
==========================  =====================================  =====================
``DoubleIntegrator``        acceleration (m/s^2)                   (x, y, vx, vy)
``VelocityTracking...``     desired velocity (m/s)                 (x, y, vx, vy)
``Unicycle``                speed v (m/s), turn rate (rad/s)       (x, y, vx, vy, theta)
``UnicycleLookahead``       velocity of a point ahead (m/s)        (x, y, vx, vy, theta)
==========================  =====================================  =====================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ...core.base import CompiledForm
from .roles import CommandKind, Dynamics
from .rollouts import tracking_rollout, unicycle_rollout

__all__ = [
    "DoubleIntegrator",
    "Unicycle",
    "UnicycleLookahead",
    "VelocityTrackingDoubleIntegrator",
    "VelocityTrackingForm",
]


def _as_state(state: np.ndarray) -> np.ndarray:
    state = np.asarray(state, dtype=float)
    if state.shape != (4,):
        raise ValueError(f"state must have shape (4,) = (x, y, vx, vy), got {state.shape}")
    return state


def _commands(commands: np.ndarray) -> np.ndarray:
    cmd = np.asarray(commands, dtype=float)
    if cmd.ndim != 3 or cmd.shape[2] != 2:
        raise ValueError(f"commands must have shape (N, H, 2), got {cmd.shape}")
    return cmd


def _check_dt(dt: float) -> float:
    if not (math.isfinite(dt) and dt >= 0):
        raise ValueError(f"dt must be a finite number >= 0, got {dt!r}")
    return float(dt)


class DoubleIntegrator(Dynamics):
    """Planar double integrator; the command is the acceleration, held over the step.

    Integrated exactly: x' = x + v dt + a dt^2/2, v' = v + a dt.
    """

    state_dim = 4
    command_kind = "acceleration"

    def step(self, state: np.ndarray, command: np.ndarray, dt: float) -> np.ndarray:
        s = _as_state(state)
        dt = _check_dt(dt)
        a = np.asarray(command, dtype=float)
        out = np.empty(4)
        out[:2] = s[:2] + s[2:] * dt + 0.5 * a * dt * dt
        out[2:] = s[2:] + a * dt
        return out

    def rollout(self, state: np.ndarray, commands: np.ndarray, dt: float) -> np.ndarray:
        s = _as_state(state)
        dt = _check_dt(dt)
        a = _commands(commands)
        v = s[2:] + np.cumsum(a, axis=1) * dt  # velocity after each step
        v_before = np.concatenate([np.broadcast_to(s[2:], a[:, :1].shape), v[:, :-1]], axis=1)
        x = s[:2] + np.cumsum(v_before * dt + 0.5 * a * dt * dt, axis=1)
        return np.concatenate([x, v], axis=2)


@dataclass(frozen=True)
class VelocityTrackingForm(CompiledForm):
    """The velocity-tracking plant as the compiled step reads it.

    Attributes
    ----------
    K_acc : float
        Tracking gain (1/s, finite, > 0).
    """

    kernel = "velocity_tracking"
    K_acc: float


class VelocityTrackingDoubleIntegrator(
    Dynamics, compiled="velocity_tracking", run_values={"K_acc": "K_acc"}
):
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

    def compiled_state(self) -> VelocityTrackingForm:
        """The gain, validated (``ValueError`` as :meth:`step` raises)."""
        k = float(self.K_acc)
        if not (math.isfinite(k) and k > 0):
            raise ValueError(f"K_acc must be a finite number > 0, got {self.K_acc!r}")
        return VelocityTrackingForm(k)

    def step(self, state: np.ndarray, command: np.ndarray, dt: float) -> np.ndarray:
        s = _as_state(state)
        dt = _check_dt(dt)
        k = float(self.K_acc)
        if not (math.isfinite(k) and k > 0):
            raise ValueError(f"K_acc must be a finite number > 0, got {self.K_acc!r}")
        v_cmd = np.asarray(command, dtype=float)
        decay = math.exp(-k * dt)
        if v_cmd.shape == (2,):  # in Python floats: the same operations, in the same order
            x, y, vx, vy = s.tolist()
            cx, cy = v_cmd.tolist()
            dx, dy, g = vx - cx, vy - cy, -math.expm1(-k * dt)
            return np.array(
                [
                    x + cx * dt + dx * g / k,
                    y + cy * dt + dy * g / k,
                    cx + dx * decay,
                    cy + dy * decay,
                ]
            )
        dv = s[2:] - v_cmd
        out = np.empty(4)
        out[:2] = s[:2] + v_cmd * dt + dv * (-math.expm1(-k * dt)) / k
        out[2:] = v_cmd + dv * decay
        return out

    def rollout(self, state: np.ndarray, commands: np.ndarray, dt: float) -> np.ndarray:
        s = _as_state(state)
        dt = _check_dt(dt)
        cmd = _commands(commands)
        k = float(self.K_acc)
        if not (math.isfinite(k) and k > 0):
            raise ValueError(f"K_acc must be a finite number > 0, got {self.K_acc!r}")
        decay, gain = math.exp(-k * dt), (-math.expm1(-k * dt)) / k
        out: np.ndarray = tracking_rollout(s, np.ascontiguousarray(cmd), dt, decay, gain)
        return out


def _wrap(theta: np.ndarray | float) -> np.ndarray:
    """Angles in [-pi, pi)."""
    out: np.ndarray = (np.asarray(theta) + math.pi) % (2.0 * math.pi) - math.pi
    return out


class Unicycle(Dynamics, run_values={"v_max": "v_max"}):
    """Unicycle (differential-drive) robot: command (v, omega), heading in the state.

    The state is ``(x, y, vx, vy, theta)``: position (m), world-frame velocity
    ``v (cos theta, sin theta)`` over the last step (m/s) and heading (rad, wrapped to
    [-pi, pi)). The command
    ``(v, omega)`` is held over the step; the plant saturates it at its limits (``v`` in
    ``[v_min, v_max]``, ``|omega| <= omega_max``), as motor drivers do.

    ``integrator="exact"`` follows the arc of constant (v, omega) exactly::

        theta' = theta + omega dt
        (x', y') = (x, y) + v dt sinc(omega dt / 2) (cos, sin)(theta + omega dt / 2)

    ``"euler"`` is the forward-Euler step the published ETH/UCY planar protocol uses::

        (x', y') = (x, y) + v dt (cos theta, sin theta),   theta' = theta + omega dt

    Parameters
    ----------
    v_min : float
        Lowest forward speed (m/s, <= 0; negative = the robot may reverse).
    v_max : float
        Highest forward speed (m/s, >= 0).
    omega_max : float
        Largest turn rate magnitude (rad/s, >= 0).
    integrator : {"exact", "euler"}
        How a step is integrated.
    """

    state_dim = 5
    command_kind: ClassVar[CommandKind] = "unicycle"

    def __init__(
        self,
        v_min: float = -0.8,
        v_max: float = 0.8,
        omega_max: float = 0.7,
        integrator: str = "exact",
    ) -> None:
        self.v_min = v_min
        self.v_max = v_max
        self.omega_max = omega_max
        self.integrator = integrator

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, object]]:
        return [{}, {"v_min": 0.0, "v_max": 1.5, "omega_max": 1.0, "integrator": "euler"}]

    def _checked(self) -> tuple[float, float, float, bool]:
        lo, hi, w = float(self.v_min), float(self.v_max), float(self.omega_max)
        if not all(math.isfinite(x) for x in (lo, hi, w)):
            raise ValueError(
                f"v_min, v_max and omega_max must be finite, got {self.v_min!r}, "
                f"{self.v_max!r}, {self.omega_max!r}"
            )
        if not (lo <= 0.0 <= hi):
            raise ValueError(
                f"need v_min <= 0 <= v_max (standing still must be possible), got "
                f"v_min={lo:g}, v_max={hi:g}"
            )
        if w < 0:
            raise ValueError(f"omega_max must be >= 0, got {w:g}")
        if self.integrator not in ("exact", "euler"):
            raise ValueError(f"integrator must be 'exact' or 'euler', got {self.integrator!r}")
        return lo, hi, w, self.integrator == "exact"

    def _state(self, state: np.ndarray) -> np.ndarray:
        s = np.asarray(state, dtype=float)
        if s.shape != (5,):
            raise ValueError(f"state must have shape (5,) = (x, y, vx, vy, theta), got {s.shape}")
        return s

    def initial_state(self, position: np.ndarray, heading: float = 0.0) -> np.ndarray:
        out = np.zeros(5)
        out[:2] = np.asarray(position, dtype=float)[:2]
        out[4] = float(_wrap(float(heading)))
        return out

    def heading(self, state: np.ndarray) -> float:
        """Heading (rad) of a state."""
        return float(np.asarray(state, dtype=float)[4])

    def command_limits(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi, w, _ = self._checked()
        return np.array([lo, -w]), np.array([hi, w])

    def _shift(self, cur: np.ndarray, vw: np.ndarray, dt: float) -> np.ndarray:
        """One unicycle step of N states at once (the rows of ``cur``) under commands ``vw``."""
        lo, hi, wmax, _ = self._checked()
        v = np.clip(vw[:, 0], lo, hi)
        w = np.clip(vw[:, 1], -wmax, wmax)
        x, y, th = self._advance(cur[:, 0], cur[:, 1], cur[:, 4], v, w, dt)
        th = _wrap(th)
        return np.stack([x, y, v * np.cos(th), v * np.sin(th), th], axis=-1)

    def _advance(
        self, x: np.ndarray, y: np.ndarray, th: np.ndarray, v: np.ndarray, w: np.ndarray, dt: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self.integrator == "exact":
            half = 0.5 * w * dt
            mid = th + half
            arc = v * dt * np.sinc(half / math.pi)  # np.sinc(z) = sin(pi z) / (pi z)
            return x + arc * np.cos(mid), y + arc * np.sin(mid), th + w * dt
        return x + v * dt * np.cos(th), y + v * dt * np.sin(th), th + w * dt

    def step(self, state: np.ndarray, command: np.ndarray, dt: float) -> np.ndarray:
        s = self._state(state)
        dt = _check_dt(dt)
        lo, hi, wmax, _ = self._checked()
        if dt == 0.0:  # the state's velocity is that of the last step: nothing happened
            same: np.ndarray = s.copy()
            return same
        c = np.asarray(command, dtype=float)
        v = min(max(float(c[0]), lo), hi)
        w = min(max(float(c[1]), -wmax), wmax)
        x, y, th = self._advance(
            np.asarray(s[0]), np.asarray(s[1]), np.asarray(s[4]), np.asarray(v), np.asarray(w), dt
        )
        th = _wrap(th)
        return np.array([float(x), float(y), v * math.cos(th), v * math.sin(th), float(th)])

    def rollout(self, state: np.ndarray, commands: np.ndarray, dt: float) -> np.ndarray:
        s = self._state(state)
        dt = _check_dt(dt)
        cmd = _commands(commands)
        lo, hi, wmax, exact = self._checked()
        v = np.clip(cmd[..., 0], lo, hi)
        w = np.clip(cmd[..., 1], -wmax, wmax)
        out: np.ndarray = unicycle_rollout(s, v, w, dt, exact)
        return out


class UnicycleLookahead(Unicycle):
    """Unicycle driven by a world-frame velocity: the look-ahead (near-identity) transform.

    Controllers that decide a planar velocity (the CBF safety filter) can drive a unicycle
    through the standard transformation: the point ``p = (x, y) + l (cos theta,
    sin theta)`` a distance ``l`` ahead of the wheel axis is fully actuated, and the
    command ``u`` (its desired velocity, m/s) is realised exactly by::

        v = cos(theta) u_x + sin(theta) u_y,    omega = (-sin(theta) u_x + cos(theta) u_y) / l

    then saturated at the unicycle's limits and integrated as :class:`Unicycle` does. The
    robot's centre is never further than ``l`` from the point whose velocity is controlled:
    a safety filter that reasons about the centre needs ``l`` of extra margin (e.g. the
    run's ``barrier_margin``) for its guarantee to cover the body.

    Parameters
    ----------
    v_min, v_max, omega_max, integrator
        As for :class:`Unicycle`.
    lookahead : float
        Distance ``l`` of the controlled point ahead of the centre (m, > 0).
    """

    command_kind: ClassVar[CommandKind] = "velocity"

    def __init__(
        self,
        v_min: float = -0.8,
        v_max: float = 0.8,
        omega_max: float = 0.7,
        integrator: str = "exact",
        lookahead: float = 0.2,
    ) -> None:
        super().__init__(v_min, v_max, omega_max, integrator)
        self.lookahead = lookahead

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, object]]:
        return [{}, {"lookahead": 0.5, "integrator": "euler"}]

    def _ell(self) -> float:
        ell = float(self.lookahead)
        if not (math.isfinite(ell) and ell > 0):
            raise ValueError(f"lookahead must be a finite distance > 0, got {self.lookahead!r}")
        return ell

    def command_limits(self) -> None:  # type: ignore[override]  # a velocity: the run's bound
        return None

    def unicycle_command(self, state: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """``(v, omega)`` realising the look-ahead point's velocity ``velocity`` (before
        saturation)."""
        th = float(self._state(state)[4])
        u = np.asarray(velocity, dtype=float)
        c, s = math.cos(th), math.sin(th)
        return np.array([c * u[0] + s * u[1], (-s * u[0] + c * u[1]) / self._ell()])

    def step(self, state: np.ndarray, command: np.ndarray, dt: float) -> np.ndarray:
        return super().step(state, self.unicycle_command(state, command), dt)

    def rollout(self, state: np.ndarray, commands: np.ndarray, dt: float) -> np.ndarray:
        # the transformation depends on the heading reached at each step: per step
        s = self._state(state)
        dt = _check_dt(dt)
        cmd = _commands(commands)
        ell = self._ell()
        n, h = cmd.shape[:2]
        out = np.empty((n, h, 5))
        cur = np.broadcast_to(s, (n, 5))
        for j in range(h):
            c, sn = np.cos(cur[:, 4]), np.sin(cur[:, 4])
            u = cmd[:, j]
            vw = np.stack([c * u[:, 0] + sn * u[:, 1], (-sn * u[:, 0] + c * u[:, 1]) / ell], -1)
            cur = out[:, j] = self._shift(cur, vw, dt)
        return out
