"""The compiled hypot is Python's math.hypot, bit for bit."""

from __future__ import annotations

import math
import sys

import numba
import numpy as np
import pytest

from conformal_control.core.jit import compile_now
from conformal_control.families.cbf.pyhypot import (
    EXACT_FOR_THIS_PYTHON,
    hypot_fma,
    hypot_split,
    py_hypot,
)

# the compiled kernels (interpreted, py_hypot is math.hypot itself; see conformal_control.core.jit)
compile_now()


@numba.njit(cache=False)
def _many(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = py_hypot(x[i], y[i])
    return out


def _reference(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.fromiter(map(math.hypot, x.tolist(), y.tolist()), float, x.size)


def _assert_same_bits(x: np.ndarray, y: np.ndarray) -> None:
    got, want = _many(x, y), _reference(x, y)
    differ = got.view(np.int64) != want.view(np.int64)
    assert not differ.any(), [
        (x[i], y[i], got[i], want[i]) for i in np.flatnonzero(differ)[:5].tolist()
    ]


def test_random_pairs_across_magnitudes() -> None:
    rng = np.random.default_rng(20261123)
    n = 1_000_000
    # mantissas in [-1, 1), exponents spanning the whole double range (incl. subnormals)
    ex = rng.integers(-1074, 1024, n)
    # the second coordinate mostly within a few binades of the first (where the last bit
    # is decided), sometimes anywhere
    near = rng.integers(-60, 61, n)
    ey = np.where(
        rng.random(n) < 0.8, np.clip(ex + near, -1074, 1023), rng.integers(-1074, 1024, n)
    )
    x = np.ldexp(rng.uniform(-1.0, 1.0, n), ex)
    y = np.ldexp(rng.uniform(-1.0, 1.0, n), ey)
    _assert_same_bits(x, y)


def test_random_pairs_of_everyday_size() -> None:
    # the engine's use: metre-scale offsets, many of them near a threshold
    rng = np.random.default_rng(7)
    x = rng.normal(0.0, 5.0, 500_000)
    y = rng.normal(0.0, 5.0, 500_000)
    _assert_same_bits(x, y)
    _assert_same_bits(np.round(x, 2), np.round(y, 2))  # few significant bits


@pytest.mark.parametrize(
    ("x", "y"),
    [
        (0.0, 0.0),
        (-0.0, 0.0),
        (0.0, -0.0),
        (3.0, 4.0),
        (-3.0, 4.0),
        (1.0, 0.0),
        (0.0, -2.5),
        (5e-324, 0.0),
        (5e-324, 5e-324),
        (2.2250738585072014e-308, 5e-324),
        (1e-310, 3e-310),
        (2.0**-1023, 2.0**-1024),
        (2.0**-1022, 2.0**-1023),
        (sys.float_info.max, sys.float_info.max),
        (sys.float_info.max, 1.0),
        (1e308, 1e308),
        (1e300, 1e-300),
        (1.0, 1e-17),
        (math.inf, 0.0),
        (0.0, -math.inf),
        (math.inf, math.nan),
        (math.nan, -math.inf),
        (math.nan, 1.0),
        (1.0, math.nan),
        (math.nan, math.nan),
    ],
)
def test_edge_cases(x: float, y: float) -> None:
    got, want = _many(np.array([x]), np.array([y]))[0], math.hypot(x, y)
    if math.isnan(want):
        assert math.isnan(got)
    else:
        assert np.float64(got).view(np.int64) == np.float64(want).view(np.int64), (got, want)


def test_differs_from_the_c_library_somewhere() -> None:
    # the reason the module exists: libm's hypot (numpy's, numba's math.hypot) is not
    # Python's; if they agreed everywhere the port would be unnecessary
    rng = np.random.default_rng(1)
    x, y = rng.normal(0, 5, 200_000), rng.normal(0, 5, 200_000)
    assert (np.hypot(x, y) != _reference(x, y)).any()


#: math.hypot of CPython 3.10 / 3.11 and of 3.12 / 3.13 where they differ (float.hex of each
#: interpreter's result): the variant this interpreter does not run is checked against them.
OTHER_VERSIONS = [
    ((-2.88, -1.2), "0x1.8f5c28f5c28f6p+1", "0x1.8f5c28f5c28f5p+1"),
    ((-4.92, -3.69), "0x1.8999999999999p+2", "0x1.899999999999ap+2"),
    ((-0.6, 1.44), "0x1.8f5c28f5c28f6p+0", "0x1.8f5c28f5c28f5p+0"),
    ((0.15, 0.36), "0x1.8f5c28f5c28f6p-2", "0x1.8f5c28f5c28f5p-2"),
]


@pytest.mark.parametrize(("args", "split", "fma"), OTHER_VERSIONS)
def test_both_cpython_variants(args, split, fma) -> None:
    assert hypot_split(*args) == float.fromhex(split)
    assert hypot_fma(*args) == float.fromhex(fma)
    assert EXACT_FOR_THIS_PYTHON
    assert math.hypot(*args) == py_hypot(*args)  # one of the two, this interpreter's


@numba.njit(cache=False)
def _many_fma(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = hypot_fma(x[i], y[i])
    return out


def test_the_two_variants_agree_nearly_everywhere() -> None:
    # the variants differ on few inputs (each is CPython's on its versions): across
    # magnitudes, including subnormals (the rescaled path), at most a handful of ulps apart
    rng = np.random.default_rng(3)
    ex = rng.integers(-1074, 1024, 200_000)
    x = np.ldexp(rng.uniform(-1, 1, ex.size), ex)
    y = np.ldexp(
        rng.uniform(-1, 1, ex.size), np.clip(ex + rng.integers(-30, 31, ex.size), -1074, 1023)
    )
    a, b = _many(x, y), _many_fma(x, y)
    assert (a != b).mean() < 1e-3
    assert np.all(np.abs(a - b) <= np.spacing(np.maximum(a, b)))
