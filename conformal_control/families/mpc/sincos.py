"""The candidates' directions with the C library's ``sincos``: both of an angle's
trigonometric values in one call, the same bits as numpy's ``np.sin`` and ``np.cos``.

Why this exists: the sampling MPC draws ~3,000 directions per plan and numpy takes
``np.cos`` and ``np.sin`` of them in two passes (about half of
:func:`~conformal_control.families.mpc.sampling.sample_sequences`). glibc's ``sincos`` shares
the argument reduction and the polynomial code of its ``sin`` and ``cos`` (``s_sincos.c``
includes ``s_sin.c``), and numpy's float64 ``sin``/``cos`` call that ``sin``/``cos`` on this
platform, so one ``sincos`` call gives the same two numbers for about the cost of one. No
library exposes ``sincos`` to numba (numba's ``math.sin``/``math.cos`` are two calls), so a
small numba intrinsic declares it here.

It is used only where it is known to agree: :func:`polar_held` is ``None`` when the C
library has no ``sincos`` (not glibc), when numba cannot be used, or when ``sincos``
differs from numpy's ``sin``/``cos`` on a probe of angles checked at first use (then the
sampler keeps numpy's two passes: same numbers, slower). ``tests/families/mpc/test_fast_plan.py``
checks the samples against numpy's form bit for bit.

Imported only by :func:`~conformal_control.families.mpc.sampling.sample_sequences` in a
process that runs its kernels compiled (numba is imported here, at import).
"""

from __future__ import annotations

import ctypes
import ctypes.util
from collections.abc import Callable
from typing import Any, cast

import llvmlite.binding as llvm
import numpy as np
from llvmlite import ir
from numba.core import cgutils as _cgutils
from numba.core import types as _types
from numba.extending import intrinsic

from ...core.compiled import njit

__all__ = ["polar_held", "sincos_address"]


def sincos_address() -> int | None:
    """The address of the C math library's ``sincos``, None when it has none."""
    name = ctypes.util.find_library("m")
    try:
        fn = ctypes.CDLL(name).sincos
    except (OSError, AttributeError, TypeError):
        return None
    address = ctypes.cast(fn, ctypes.c_void_p).value
    return None if address is None else int(address)


_ADDRESS = sincos_address()
if _ADDRESS is not None:  # numba links "sincos" to it (before any code using it is loaded)
    llvm.add_symbol("sincos", _ADDRESS)


cgutils: Any = _cgutils  # (numba ships no type stubs)
types: Any = _types


@intrinsic
def _sincos_intrinsic(typingctx: Any, x: Any) -> Any:
    """``(sin(x), cos(x))`` from one call of the C library's ``sincos``."""
    sig = types.UniTuple(types.float64, 2)(types.float64)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        dbl = ir.DoubleType()
        fnty = ir.FunctionType(ir.VoidType(), [dbl, dbl.as_pointer(), dbl.as_pointer()])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "sincos")
        s = cgutils.alloca_once(builder, dbl)
        c = cgutils.alloca_once(builder, dbl)
        builder.call(fn, [args[0], s, c])
        pair = [builder.load(s), builder.load(c)]
        return context.make_tuple(builder, signature.return_type, pair)

    return sig, codegen


_sincos = cast(Callable[[float], "tuple[float, float]"], _sincos_intrinsic)


@njit(nogil=True)
def _polar_held(
    u: np.ndarray, radius: float, low: float, span: float, hold: int, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    n, blocks = out.shape[0], -(-out.shape[1] // hold)
    m = n * blocks
    for i in range(n):
        for b in range(blocks):
            speed = 0.0 + radius * u[i * blocks + b]  # numpy's uniform(0, radius)
            s, c = _sincos(low + span * u[m + i * blocks + b])  # uniform(low, low + span)
            vx = speed * c
            vy = speed * s
            for h in range(b * hold, min((b + 1) * hold, out.shape[1])):
                out[i, h, 0] = vx
                out[i, h, 1] = vy


@njit(nogil=True)
def _sincos_of(x: np.ndarray, s: np.ndarray, c: np.ndarray) -> None:  # pragma: no cover
    for i in range(x.size):
        s[i], c[i] = _sincos(x[i])


def _agrees() -> bool:
    """Whether ``sincos`` gives numpy's ``sin`` and ``cos`` on a probe of angles: a grid
    over the sampler's range [-pi, pi] with its ends, 20,000 uniform draws, and some
    outside it."""
    rng = np.random.default_rng(20261129)
    x = np.concatenate(
        [
            np.linspace(-np.pi, np.pi, 4097),
            rng.uniform(-np.pi, np.pi, 20000),
            rng.uniform(-100.0, 100.0, 2000),
            [0.0, -0.0, 1e-300, np.nextafter(np.pi, 0.0), -np.nextafter(np.pi, 0.0)],
        ]
    )
    s, c = np.empty_like(x), np.empty_like(x)
    _sincos_of(x, s, c)
    return bool(
        np.array_equal(s.view(np.int64), np.sin(x).view(np.int64))
        and np.array_equal(c.view(np.int64), np.cos(x).view(np.int64))
    )


_STATE: list[Any] = []  # [the kernel or None], decided at first use


def polar_held() -> Any:
    """The compiled ``(u, radius, low, span, hold, out) -> None`` forming the disc's
    commands from ``2 n blocks`` uniform doubles ``u`` (``Generator.random``: the first
    ``n blocks`` the speeds, as ``uniform(0, radius)`` forms them, ``0 + radius u``, the rest
    the directions, ``low + span u``, the same doubles two ``uniform`` calls draw) and writing
    ``out[i, h] = speed * (cos, sin)(direction)`` of block ``h // hold`` (the products numpy's
    ``speed * np.cos(angle)`` and ``speed * np.sin(angle)`` form); or None when ``sincos``
    cannot be used or does not agree with numpy (see the module docstring)."""
    if not _STATE:
        _STATE.append(_polar_held if _ADDRESS is not None and _agrees() else None)
    return _STATE[0]
