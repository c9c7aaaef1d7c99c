"""Python's ``math.hypot`` for two floats, compiled (numba), to the last bit.

Why this exists: the per-episode code takes some distances with Python's ``math.hypot``
(the attractive field's speed saturation, the environment's goal check), and a compiled
engine that must reproduce its decisions bit for bit needs the same function inside
numba. numba's ``math.hypot`` is the C library's ``hypot``, and CPython's is not: in CPython
3.10 and 3.11 it is CPython's own vector norm, which (1) scales the coordinates by a
power of two so the largest lies in [0.5, 1) (losslessly), (2) splits each scaled
coordinate in two halves of 26 bits (Veltkamp) so that its square is the exact sum
``hi*hi + 2*hi*lo + lo*lo``, (3) adds these parts to a running sum seeded with 1.0, each
part's rounding error collected in its own accumulator (compensated summation), (4)
takes the square root of the sum and applies one differential (Newton) correction,
``h + (sum - h**2) / (2 h)``, with ``h**2`` split and subtracted the same way, and (5)
scales back; where the scale would overflow (the largest coordinate below 2**-1023) it
divides by the largest coordinate instead. CPython 3.12 changed the algorithm (fma
products, one accumulator less), which rounds differently for some inputs: this module
is the one of the interpreter the project runs on (3.11). The two
results differ in the last bit for a fraction of inputs, which is enough to flip a
comparison such as ``distance <= goal_radius``. No library offers this function for
numba, so it is written here, following that algorithm step by step;
``tests/cbf/test_pyhypot.py`` checks it against ``math.hypot`` with exact equality.
"""

from __future__ import annotations

import math
import sys

import numba

__all__ = ["EXACT_FOR_THIS_PYTHON", "py_hypot"]

jit = numba.njit(cache=True, nogil=True, inline="always")

#: Veltkamp's splitting constant for doubles, 2**27 + 1.
_T27 = 134217729.0


@jit
def _norm(a: float, b: float, m: float) -> float:
    """The vector norm of the finite, non-negative ``a``, ``b``, ``m = max(a, b) > 0``."""
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
def py_hypot(x: float, y: float) -> float:
    """``math.hypot(x, y)`` as CPython 3.11 computes it, bit for bit.

    Infinite if either is infinite (even with a NaN), else NaN if either is NaN; exact for
    zeros; subnormals, huge values and everything between as CPython.
    """
    a = abs(x)
    b = abs(y)
    if math.isinf(a) or math.isinf(b):
        return math.inf
    if math.isnan(a) or math.isnan(b):
        return math.nan
    m = a if a > b else b
    if m == 0.0:
        return m
    return _norm(a, b, m)


#: Whether :func:`py_hypot` is this interpreter's ``math.hypot`` (the algorithm above is
#: CPython 3.11's; other versions round some inputs differently).
EXACT_FOR_THIS_PYTHON = sys.version_info[:2] == (3, 11)
