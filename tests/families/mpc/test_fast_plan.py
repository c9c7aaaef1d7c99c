"""The plan's faster pieces give the numbers of the forms they replaced, bit for bit: the
evaluation step by step over all plans against the per-plan loop, and the compiled
prediction lookup against its numpy form."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.core.jit import compile_now
from conformal_control.families.mpc import sampling
from conformal_control.families.mpc.kernels import (
    agent_rows,
    evaluate,
    plan_predictions,
    predicted_at,
)
from conformal_control.families.mpc.sampling import sample_sequences

from .test_cut import _problem, _same

compile_now()  # the vectorised plan loop is what must not change a number


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 60),
    h=st.integers(1, 12),
    m=st.integers(0, 14),
    spread=st.sampled_from([0.5, 3.0, 15.0, 60.0]),
    shift=st.sampled_from([0.0, 1e3, 1e5]),
    continuous=st.booleans(),
    cut=st.booleans(),
)
def test_step_by_step_evaluation_equals_plan_by_plan(
    seed: int, n: int, h: int, m: int, spread: float, shift: float, continuous: bool, cut: bool
) -> None:
    p = _problem(seed, n, h, m, spread, shift, continuous)
    _same(evaluate(*p, cut=cut), evaluate(*p, cut=cut, by_plan=True))


def test_step_by_step_evaluation_with_nonfinite_and_degenerate_inputs() -> None:
    """NaN candidates (never safe: the comparisons skip them as the per-plan loop does),
    an agent sitting on the robot (no relative motion), no agent at all."""
    p = list(_problem(3, 40, 6, 7, 3.0, 0.0, True))
    pos = p[0].copy()
    pos[5, 2] = np.nan
    pos[9, :, 0] = np.inf
    p[0] = pos
    pred, y0 = p[3].copy(), p[4].copy()
    pred[2] = p[2]  # an agent that does not move, on the robot's start
    y0[2] = p[2]
    p[3], p[4] = pred, y0
    for continuous in (True, False):
        p[9] = continuous
        _same(evaluate(*p), evaluate(*p, by_plan=True))
    empty = (*p[:3], np.zeros((0, 6, 2)), np.zeros((0, 2)), *p[5:])
    got = evaluate(*empty)
    _same(got, evaluate(*empty, by_plan=True))
    assert (got[1] == np.inf).all() and (got[2] == 0).all()


def _predicted_at_numpy(samples: np.ndarray, dt: float, offsets: np.ndarray) -> np.ndarray:
    """The numpy form SamplingMPC.predicted_at had (the reference)."""
    last = samples.shape[1] - 1
    f = np.clip(np.asarray(offsets, dtype=float) / dt, 0.0, float(last))
    near = np.abs(f - np.rint(f)) < 1e-9
    f = np.where(near, np.rint(f), f)
    i0 = np.minimum(np.floor(f).astype(np.int64), max(last - 1, 0))
    i1 = np.minimum(i0 + 1, last)
    w = (f - i0)[None, :, None]
    out: np.ndarray = samples[:, i0] + w * (samples[:, i1] - samples[:, i0])
    return out


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    m=st.integers(1, 9),
    frames=st.integers(0, 20),
    dt=st.sampled_from([0.4, 0.1, 1.0 / 15.0, 1.0 / 2.5]),
    dt_plan=st.sampled_from([0.4, 0.25, 1.0 / 3.0]),
    h=st.integers(1, 14),
    start=st.sampled_from([0.0, 0.1, 0.4, 1.2, 1.0 / 3.0, 7.9]),
)
def test_the_compiled_predictions_equal_the_numpy_form(
    seed: int, m: int, frames: int, dt: float, dt_plan: float, h: int, start: float
) -> None:
    """At sample times (exactly the sample), between them, beyond the last (held), and as
    the evaluation's rows."""
    rng = np.random.default_rng(seed)
    samples = rng.normal(0.0, 20.0, (m, frames + 1, 2)) + 1e3 * (seed % 2)
    offsets = start + dt_plan * np.arange(0, h + 1)
    ref = _predicted_at_numpy(samples, dt, offsets)
    got = predicted_at(samples, dt, offsets)
    assert got.shape == ref.shape and got.tobytes() == ref.tobytes()
    pred, y0, *rows = plan_predictions(samples, dt, start, dt_plan, h)
    assert pred.tobytes() == ref[:, 1:].tobytes() and y0.tobytes() == ref[:, 0].tobytes()
    for a, b in zip(rows, agent_rows(ref[:, 1:], ref[:, 0]), strict=True):
        assert a.shape == b.shape and a.tobytes() == b.tobytes()
    # and the odd offsets: before the first sample, on a sample time up to rounding
    odd = np.array([-1.0, 0.0, dt * 3 * (1 + 1e-12), dt * 1e6, dt * 2.5])
    assert (
        predicted_at(samples, dt, odd).tobytes() == _predicted_at_numpy(samples, dt, odd).tobytes()
    )


def test_the_rows_given_to_evaluate_are_used() -> None:
    """evaluate(..., rows=...) reads the rows given (not pred and y0 again)."""
    p = _problem(11, 30, 5, 6, 3.0, 0.0, True)
    rows = agent_rows(p[3], p[4])
    _same(evaluate(*p, rows=rows), evaluate(*p))
    far = tuple(r + 1e3 for r in rows)
    assert not np.array_equal(evaluate(*p, rows=far)[1], evaluate(*p)[1])


def _sample_sequences_numpy(rng, n, horizon, hold, box=None, radius=1.0):
    """The numpy form sample_sequences had (the reference)."""
    import math

    blocks = math.ceil(horizon / hold)
    if box is not None:
        u = rng.uniform(box[0], box[1], size=(n, blocks, 2))
    else:
        speed = rng.uniform(0.0, radius, size=(n, blocks))
        angle = rng.uniform(-math.pi, math.pi, size=(n, blocks))
        u = np.stack([speed * np.cos(angle), speed * np.sin(angle)], axis=-1)
    return np.repeat(u, hold, axis=1)[:, :horizon]


@pytest.mark.parametrize("form", ["compiled", "python", "py_func"])
def test_the_samples_equal_the_numpy_form(form: str) -> None:
    """The same sequences, bit for bit, and the generator left in the same state: in a disc
    and in a box, holds that divide the horizon and holds that do not, into a new array or
    into the rows of the caller's; compiled, and the kernels' interpreted forms (numpy, and
    the loops themselves)."""
    held, polar = (
        (sampling._held_numpy, sampling._polar_held_numpy)
        if form == "python"
        else (sampling._held.py_func, sampling._polar_held.py_func)
    )
    box = (np.array([0.0, -1.2]), np.array([1.5, 1.2]))
    for seed, (n, h, hold) in enumerate([(500, 12, 2), (7, 5, 3), (1, 1, 1), (3, 4, 5), (0, 3, 1)]):
        for b in (None, box):
            a, r = np.random.default_rng(seed), np.random.default_rng(seed)
            ref = _sample_sequences_numpy(r, n, h, hold, box=b, radius=0.7)
            if form == "compiled":
                got = sample_sequences(a, n, h, hold, box=b, radius=0.7)
            else:  # the interpreted forms of the kernels
                got = np.empty((n, h, 2))
                if b is None:
                    speed = a.uniform(0.0, 0.7, size=(n, -(-h // hold)))
                    angle = a.uniform(-np.pi, np.pi, size=speed.shape)
                    polar(speed, np.cos(angle), np.sin(angle), hold, got)
                else:
                    held(a.uniform(*b, size=(n, -(-h // hold), 2)), hold, got)
            assert got.shape == ref.shape and got.tobytes() == ref.tobytes()
            assert a.random() == r.random()
            into = np.full((n + 2, h, 2), 7.0)
            a = np.random.default_rng(seed)
            sample_sequences(a, n, h, hold, box=b, radius=0.7, out=into[2:])
            assert into[2:].tobytes() == ref.tobytes() and (into[:2] == 7.0).all()
    with pytest.raises(ValueError, match="out must be"):
        sample_sequences(np.random.default_rng(0), 4, 3, 1, out=np.empty((4, 2, 2)))


def test_the_plant_step_in_floats_equals_the_array_form() -> None:
    """VelocityTrackingDoubleIntegrator.step (Python floats) against its numpy formula."""
    import math

    from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator

    rng = np.random.default_rng(0)
    for _ in range(2000):
        k = float(rng.choice([10.0, 60.0, rng.random() * 100 + 1e-3]))
        s = rng.normal(0.0, 10.0 ** rng.integers(-3, 4), 4)
        c = rng.normal(0.0, 2.0, 2)
        dt = float(rng.choice([0.1, 0.025, 1 / 60, 0.4 * rng.random()]))
        dv = s[2:] - c
        ref = np.empty(4)
        ref[:2] = s[:2] + c * dt + dv * (-math.expm1(-k * dt)) / k
        ref[2:] = c + dv * math.exp(-k * dt)
        got = VelocityTrackingDoubleIntegrator(K_acc=k).step(s, c, dt)
        assert got.tobytes() == ref.tobytes()


def test_the_positions_copy_equals_the_numpy_slice() -> None:
    """positions_of: compiled, its loops interpreted and its numpy form, for a 4- and a
    5-column state (a unicycle's), and a non-contiguous input."""
    from conformal_control.families.mpc.kernels import _positions_numpy, positions_of

    rng = np.random.default_rng(3)
    for states in (
        rng.normal(size=(37, 6, 4)),
        rng.normal(size=(5, 3, 5)),
        rng.normal(size=(8, 4, 6))[:, :, 1:],
    ):
        ref = np.ascontiguousarray(states[..., :2])
        for form in (positions_of, positions_of.py_func, _positions_numpy):
            got = form(states)
            assert got.flags.c_contiguous and got.shape == ref.shape
            assert got.tobytes() == ref.tobytes()
