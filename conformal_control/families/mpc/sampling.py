"""Random control sequences for the sampling MPC, in the command space of the plant.

Commands are piecewise constant over blocks of ``hold`` plan steps (a plan of H steps has
``ceil(H / hold)`` free commands), drawn uniformly:

* a **unicycle** (``command_kind == "unicycle"``): ``(v, omega)`` uniform in the plant's box
  of limits (as the published sampling MPCs of the ETH/UCY planar protocol draw them);
* a **velocity** command: speed uniform in ``[0, v_max]`` and direction uniform in
  ``[-pi, pi)`` (every speed equally likely, so the samples reach the bound often);
* an **acceleration** command: the same in a disc of radius ``a_max``.

The draws are numpy's (``Generator.uniform``, then ``np.cos``/``np.sin``; compiled, both
from one call of the C library's ``sincos`` where it gives numpy's numbers,
:mod:`~conformal_control.families.mpc.sincos`); a compiled kernel forms the commands and
holds them (the products numpy formed, written straight into the
caller's array instead of stacked, repeated and concatenated: the same numbers,
``tests/families/mpc/test_fast_plan.py``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...core.jit import is_compiled, kernel

__all__ = ["sample_sequences"]


def _held_numpy(u: np.ndarray, hold: int, out: np.ndarray) -> None:
    out[...] = np.repeat(u, hold, axis=1)[:, : out.shape[1]]


@kernel(cache=True, nogil=True, python=_held_numpy)
def _held(u: np.ndarray, hold: int, out: np.ndarray) -> None:
    """``out[i, h] = u[i, h // hold]``: each drawn command held ``hold`` steps (a copy)."""
    for i in range(out.shape[0]):
        for h in range(out.shape[1]):
            out[i, h, 0] = u[i, h // hold, 0]
            out[i, h, 1] = u[i, h // hold, 1]


def _polar_held_numpy(
    speed: np.ndarray, cos: np.ndarray, sin: np.ndarray, hold: int, out: np.ndarray
) -> None:
    u = np.stack([speed * cos, speed * sin], axis=-1)
    out[...] = np.repeat(u, hold, axis=1)[:, : out.shape[1]]


@kernel(cache=True, nogil=True, python=_polar_held_numpy)
def _polar_held(
    speed: np.ndarray, cos: np.ndarray, sin: np.ndarray, hold: int, out: np.ndarray
) -> None:
    """``out[i, h] = speed * (cos, sin)`` of block ``h // hold`` of sequence i (the same
    products numpy's ``speed * np.cos(angle)`` forms, written once, held)."""
    for i in range(out.shape[0]):
        for b in range(speed.shape[1]):
            vx = speed[i, b] * cos[i, b]
            vy = speed[i, b] * sin[i, b]
            for h in range(b * hold, min((b + 1) * hold, out.shape[1])):
                out[i, h, 0] = vx
                out[i, h, 1] = vy


def sample_sequences(
    rng: np.random.Generator,
    n: int,
    horizon: int,
    hold: int,
    *,
    box: tuple[np.ndarray, np.ndarray] | None = None,
    radius: float = 1.0,
    out: np.ndarray | None = None,
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
    out : ndarray of shape (n, horizon, 2), optional
        Where to write them (float64, C-contiguous; returned); default a new array.
    """
    blocks = math.ceil(horizon / hold)
    if out is None:
        out = np.empty((n, horizon, 2))
    elif out.shape != (n, horizon, 2) or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError(
            f"out must be a C-contiguous float64 array of shape {(n, horizon, 2)}, got "
            f"{out.dtype} {out.shape}"
        )
    if box is not None:
        lo, hi = box
        _held(rng.uniform(lo, hi, size=(n, blocks, 2)), int(hold), out)
    else:
        fast = _sincos_kernel()
        if fast is not None and math.isfinite(radius):  # (else uniform raises)
            # the doubles both uniform calls draw, in one call; cos and sin of each angle
            # in one C call: the same numbers (sincos.py)
            u = rng.random(2 * n * blocks)
            fast(u, float(radius), -math.pi, math.pi - (-math.pi), int(hold), out)
        else:
            speed = rng.uniform(0.0, radius, size=(n, blocks))
            angle = rng.uniform(-math.pi, math.pi, size=(n, blocks))
            _polar_held(speed, np.cos(angle), np.sin(angle), int(hold), out)
    return out


_SINCOS: list[Any] = []


def _sincos_kernel() -> Any:
    """:func:`~conformal_control.families.mpc.sincos.polar_held` in a process that runs
    its kernels compiled (None otherwise, or where ``sincos`` is not numpy's)."""
    if _SINCOS:
        return _SINCOS[0]
    if not is_compiled():
        return None
    from .sincos import polar_held

    _SINCOS.append(polar_held())
    return _SINCOS[0]
