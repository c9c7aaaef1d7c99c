"""Python's ``math.hypot`` for two floats, compiled (numba), to the last bit.

Why this exists: the per-episode code takes some distances with Python's ``math.hypot``
(the attractive field's speed saturation, the environment's goal check), and a compiled
engine that must reproduce its decisions bit for bit needs the same function inside
numba. numba's ``math.hypot`` is the C library's ``hypot``, and CPython's is not: since
3.10 it is CPython's own vector norm, which (1) scales the coordinates by a power of two
so the largest lies in [0.5, 1) (losslessly), (2) squares each scaled coordinate exactly,
(3) adds the squares to a running sum seeded with 1.0, the rounding errors collected apart
(compensated summation), (4) takes the square root and applies one differential (Newton)
correction, ``h + (sum - h**2) / (2 h)``, with ``h**2`` again exact, and (5) scales back.
CPython 3.10 and 3.11 square by splitting a coordinate into two halves of 26 bits
(Veltkamp) and keep three error accumulators (``hi*hi``, ``2*hi*lo``, ``lo*lo``); 3.12 and
later take each square as an exact pair (``fma``; Dekker's product gives the same pair)
with two accumulators. The two round differently for a few inputs (e.g. ``hypot(2.88,
1.2)``), and the C library's ``hypot`` for others, which is enough to flip a comparison such
as ``distance <= goal_radius``. No library offers this function for numba, so both
variants are written here, step by step as CPython's ``Modules/mathmodule.c`` does them;
:func:`py_hypot` is the one of the running interpreter. ``tests/families/cbf/test_pyhypot.py``
checks it against ``math.hypot`` with exact equality.
"""

from __future__ import annotations

import math
import sys

import numpy as np

from ...core.jit import kernel

__all__ = ["EXACT_FOR_THIS_PYTHON", "c_hypot", "hypot_fma", "hypot_split", "py_hypot"]

jit = kernel(cache=True, nogil=True, inline="always")

#: Veltkamp's splitting constant for doubles, 2**27 + 1.
_T27 = 134217729.0
#: The smallest positive normal double (C's DBL_MIN).
_DBL_MIN = 2.2250738585072014e-308


@jit
def _norm_split(a: float, b: float, m: float) -> float:
    """CPython 3.10 / 3.11: the norm of the finite, non-negative ``a``, ``b`` with
    ``m = max(a, b) > 0``."""
    e = math.frexp(m)[1]
    csum = 1.0
    frac1 = 0.0
    if e < -1023:  # ldexp(1.0, -e) would overflow: divide by the largest instead
        x = a / m
        x = x * x
        old = csum
        csum += x
        frac1 += (old - csum) + x
        x = b / m
        x = x * x
        old = csum
        csum += x
        frac1 += (old - csum) + x
        return m * math.sqrt(csum - 1.0 + frac1)
    scale = math.ldexp(1.0, -e)
    frac2 = 0.0
    frac3 = 0.0
    for i in range(2):
        x = (a if i == 0 else b) * scale  # lossless scaling into [0, 1)
        t = x * _T27  # Veltkamp split: x == hi + lo, each of 26 bits
        hi = t - (t - x)
        lo = x - hi
        x = hi * hi  # exact; |csum| >= |x|, so the error of each sum is exact
        old = csum
        csum += x
        frac1 += (old - csum) + x
        x = 2.0 * hi * lo
        old = csum
        csum += x
        frac2 += (old - csum) + x
        frac3 += lo * lo  # below half an ulp of csum: kept apart
    h = math.sqrt(csum - 1.0 + (frac1 + frac2 + frac3))
    # differential correction: subtract h**2 (split likewise) from the sum
    x = h
    t = x * _T27
    hi = t - (t - x)
    lo = x - hi
    x = -hi * hi
    old = csum
    csum += x
    frac1 += (old - csum) + x
    x = -2.0 * hi * lo
    old = csum
    csum += x
    frac2 += (old - csum) + x
    x = -lo * lo
    old = csum
    csum += x
    frac3 += (old - csum) + x
    x = csum - 1.0 + (frac1 + frac2 + frac3)
    return (h + x / (2.0 * h)) / scale


@jit
def _exact_product_error(x: float, y: float, z: float) -> float:
    """``x * y - z`` exactly, for ``z = x * y`` (Dekker's product, Veltkamp's split)."""
    t = x * _T27
    xh = t - (t - x)
    xl = x - xh
    t = y * _T27
    yh = t - (t - y)
    yl = y - yh
    return ((xh * yh - z) + xh * yl + xl * yh) + xl * yl


@jit
def _norm_fma(a: float, b: float, m: float) -> float:
    """CPython 3.12 and later: the norm of the finite, non-negative ``a``, ``b`` with
    ``m = max(a, b) > 0``."""
    e = math.frexp(m)[1]
    tiny = e < -1023
    if tiny:  # ldexp(1.0, -e) would overflow: make subnormals normal (undone at the end)
        a /= _DBL_MIN
        b /= _DBL_MIN
        e = math.frexp(m / _DBL_MIN)[1]
    scale = math.ldexp(1.0, -e)
    csum = 1.0
    frac1 = 0.0
    frac2 = 0.0
    for i in range(2):
        x = (a if i == 0 else b) * scale  # lossless scaling into [0, 1)
        hi = x * x  # the square as the exact pair hi + lo
        lo = _exact_product_error(x, x, hi)
        s = csum + hi  # |csum| >= hi: the sum's error is exact
        frac1 += lo
        frac2 += (csum - s) + hi
        csum = s
    h = math.sqrt(csum - 1.0 + (frac1 + frac2))
    # differential correction: subtract h**2 (an exact pair) from the sum
    hi = -h * h
    lo = _exact_product_error(-h, h, hi)
    s = csum + hi
    frac1 += lo
    frac2 += (csum - s) + hi
    csum = s
    x = csum - 1.0 + (frac1 + frac2)
    h += x / (2.0 * h)
    if tiny:
        return _DBL_MIN * (h / scale)
    return h / scale


@jit
def _special(a: float, b: float) -> float:
    """The result for an infinite or NaN coordinate or two zeros, else -1.0."""
    if math.isinf(a) or math.isinf(b):
        return math.inf
    if math.isnan(a) or math.isnan(b):
        return math.nan
    if a == 0.0 and b == 0.0:
        return 0.0
    return -1.0


@jit
def hypot_split(x: float, y: float) -> float:
    """``math.hypot(x, y)`` as CPython 3.10 and 3.11 compute it."""
    a = abs(x)
    b = abs(y)
    r = _special(a, b)
    if r != -1.0:
        return r
    return _norm_split(a, b, a if a > b else b)


@jit
def hypot_fma(x: float, y: float) -> float:
    """``math.hypot(x, y)`` as CPython 3.12 and later compute it."""
    a = abs(x)
    b = abs(y)
    r = _special(a, b)
    if r != -1.0:
        return r
    return _norm_fma(a, b, a if a > b else b)


#: Which variant the running interpreter's ``math.hypot`` is (a compile-time constant).
_FMA = sys.version_info >= (3, 12)


@kernel(cache=True, nogil=True, inline="always", python=math.hypot)
def py_hypot(x: float, y: float) -> float:
    """``math.hypot(x, y)`` as the running CPython computes it, bit for bit.

    Infinite if either is infinite (even with a NaN), else NaN if either is NaN; exact for
    zeros; subnormals, huge values and everything between as CPython. Interpreted (see
    :mod:`conformal_control.core.jit`), it is ``math.hypot`` itself.
    """
    if _FMA:
        return hypot_fma(x, y)
    return hypot_split(x, y)


def _c_hypot_python(x: float, y: float) -> float:
    return float(np.hypot(x, y))  # numpy's hypot is the C library's


@kernel(cache=True, nogil=True, inline="always", python=_c_hypot_python)
def c_hypot(x: float, y: float) -> float:
    """The C library's ``hypot(x, y)``: numba's ``math.hypot`` compiled, ``numpy.hypot``
    interpreted (the one the per-episode code's ``numpy.hypot`` distances take); kernels
    call it rather than ``math.hypot``, which is another function in Python."""
    return math.hypot(x, y)


#: Whether :func:`py_hypot` is checked to be this interpreter's ``math.hypot`` (CPython
#: 3.10 to 3.13; a later version may change the algorithm again).
EXACT_FOR_THIS_PYTHON = (3, 10) <= sys.version_info[:2] <= (3, 13)
