"""The sampling MPC's interval start reads its forecast at the control instants with a
compiled kernel (``kernels.substep_states``): the numbers of
:func:`~conformal_control.families.cbf.interp.interpolate_at_substeps`, bit for bit."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.core.jit import compile_now
from conformal_control.families.cbf.interp import interpolate_at_substeps
from conformal_control.families.mpc.kernels import substep_states

compile_now()


@settings(max_examples=80, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(0, 7),
    f=st.integers(1, 12),
    substeps=st.integers(1, 6),
    dt=st.sampled_from([0.1, 1 / 30, 0.4, 1 / 2.5]),
    scale=st.sampled_from([1.0, 50.0, 1e4]),
    data=st.data(),
)
def test_the_compiled_substeps_equal_the_numpy_interpolation(
    seed: int, n: int, f: int, substeps: int, dt: float, scale: float, data
) -> None:
    rng = np.random.default_rng(seed)
    samples = scale * rng.uniform(-1, 1, (n, f + 1, 2))
    if n and data.draw(st.booleans()):  # unknown samples
        samples[rng.random((n, f + 1)) < 0.2] = np.nan
    n_steps = data.draw(st.integers(0, f * substeps))
    want = interpolate_at_substeps(samples, dt, substeps, n_steps)
    for form in (substep_states, substep_states.py_func):
        got = form(samples, dt, substeps, n_steps)
        for g, w in zip(got, want, strict=True):
            assert g.shape == w.shape and g.dtype == w.dtype
            assert g.tobytes() == np.ascontiguousarray(w).tobytes()
