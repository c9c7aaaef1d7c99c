"""The candidates' directions from the C library's ``sincos`` (families/mpc/sincos.py):
the same bits as numpy's ``np.sin``/``np.cos``, the same samples as numpy's two passes, and
the fallback to numpy's passes when ``sincos`` would not agree."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.core.jit import compile_now
from conformal_control.families.mpc import sampling, sincos
from conformal_control.families.mpc.sampling import sample_sequences

compile_now()


def _bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype=np.float64).tobytes()


def test_sincos_is_used_here_and_agrees_with_numpy() -> None:
    """On this platform (glibc) the sampler takes the sincos kernel; sincos gives numpy's
    sin and cos bit for bit on 200,000 angles of the sampler's range and 20,000 wider."""
    assert sincos.sincos_address() is not None
    assert sincos.polar_held() is not None
    assert sampling._sincos_kernel() is sincos.polar_held()
    rng = np.random.default_rng(7)
    x = np.concatenate([rng.uniform(-math.pi, math.pi, 200_000), rng.uniform(-1e4, 1e4, 20_000)])
    s, c = np.empty_like(x), np.empty_like(x)
    sincos._sincos_of(x, s, c)
    assert _bits(s) == _bits(np.sin(x)) and _bits(c) == _bits(np.cos(x))


@settings(max_examples=60, deadline=None, derandomize=True)
@given(
    n=st.integers(0, 40),
    blocks=st.integers(1, 7),
    hold=st.integers(1, 4),
    cut=st.integers(0, 3),
    radius=st.sampled_from([1.0, 0.7, 2.3, 1e-3, 0.0]),
    seed=st.integers(0, 2**32 - 1),
)
def test_the_sincos_kernel_equals_numpys_draws_and_two_passes(
    n: int, blocks: int, hold: int, cut: int, radius: float, seed: int
) -> None:
    """polar_held on one Generator.random call writes what two Generator.uniform calls and
    _polar_held(speed, cos(angle), sin(angle)) write, holds dividing the horizon or not
    (cut), and leaves the generator in the same state."""
    a, r = np.random.default_rng(seed), np.random.default_rng(seed)
    horizon = max(blocks * hold - cut, (blocks - 1) * hold + 1)
    got = np.full((n, horizon, 2), 7.0)
    ref = np.full((n, horizon, 2), 7.0)
    fast = sincos.polar_held()
    assert fast is not None
    fast(a.random(2 * n * blocks), radius, -math.pi, 2 * math.pi, hold, got)
    speed = r.uniform(0.0, radius, size=(n, blocks))
    angle = r.uniform(-math.pi, math.pi, size=(n, blocks))
    sampling._polar_held(speed, np.cos(angle), np.sin(angle), hold, ref)
    assert _bits(got) == _bits(ref)
    assert a.random() == r.random()


def test_the_samples_are_the_same_with_and_without_sincos(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """sample_sequences with the sincos kernel and with numpy's passes (the fallback): the
    same sequences and generator state; and the fallback is chosen when sincos disagrees."""
    fast = sampling._sincos_kernel()
    assert fast is not None
    outs = []
    for kernel in (fast, None):
        monkeypatch.setattr(sampling, "_SINCOS", [kernel])
        rng = np.random.default_rng(3)
        outs.append((sample_sequences(rng, 500, 12, 2, radius=0.9), rng.random()))
    assert _bits(outs[0][0]) == _bits(outs[1][0]) and outs[0][1] == outs[1][1]
    monkeypatch.setattr(sampling, "_SINCOS", [fast])
    with pytest.raises(OverflowError):  # numpy's uniform refuses an infinite range, still
        sample_sequences(np.random.default_rng(0), 3, 4, 2, radius=math.inf)

    def wrong(x: np.ndarray, s: np.ndarray, c: np.ndarray) -> None:
        s[:] = np.sin(x)
        c[:] = np.cos(x)
        c[-1] = np.nextafter(c[-1], 2.0)  # one last bit off

    monkeypatch.setattr(sincos, "_sincos_of", wrong)
    assert not sincos._agrees()
    monkeypatch.setattr(sincos, "_STATE", [])
    assert sincos.polar_held() is None
