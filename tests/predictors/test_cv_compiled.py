"""The compiled constant-velocity extrapolation gives the previous numpy form's numbers bit
for bit (agents absent, appearing, disappearing, NaN/inf samples, any window and horizon)."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.predictors import ConstantVelocityPredictor, PredictionQuery
from conformal_control.predictors import constant_velocity as cv
from conformal_control.predictors.constant_velocity import trailing_valid

#: the kernel compiled as the package compiles it (numba, no fast-math, numpy's errors)
COMPILED = numba.njit(nogil=True, error_model="numpy")(cv._extrapolate.py_func)


def _previous(window: int, query: PredictionQuery) -> tuple[np.ndarray, int]:
    """ConstantVelocityPredictor.predict before the compiled form (commit e86ae03)."""
    hist = np.asarray(query.history[:, -(int(window) + 1) :], dtype=float)
    n, t, _ = hist.shape
    steps = np.arange(1, query.horizon + 1, dtype=float)
    w = int(window)
    if t == w + 1 and np.isfinite(hist).all():
        last = hist[:, -1, :]
        vel = (last - hist[:, 0, :]) / (w * query.dt)
        return last[:, None, :] + vel[:, None, :] * (steps[None, :, None] * query.dt), 0
    run = trailing_valid(hist)
    k = np.maximum(np.minimum(run - 1, int(window)), 0)
    last = hist[:, -1, :]
    past = hist[np.arange(n), t - 1 - k, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        vel = np.where(k[:, None] > 0, (last - past) / (np.maximum(k, 1)[:, None] * query.dt), 0.0)
    pos = last[:, None, :] + vel[:, None, :] * (steps[None, :, None] * query.dt)
    return pos, int((k == 0).sum())


def _history(rng: np.random.Generator, n: int, t: int, kind: str) -> np.ndarray:
    """Positions with agents appearing (NaN at the front), disappearing (NaN at the end,
    the last sample absent), gaps, one coordinate missing, infinities, -0.0 and exact
    repeats (zero velocity)."""
    hist = rng.normal(0.0, 10.0, (n, t, 2))
    if kind == "clean":
        return hist
    for i in range(n):
        r = rng.random()
        if r < 0.2:  # appeared a few samples ago
            hist[i, : int(rng.integers(0, t + 1))] = np.nan
        elif r < 0.3:  # disappeared (the last samples absent)
            hist[i, int(rng.integers(0, t)) :] = np.nan
        elif r < 0.4:  # one coordinate missing somewhere
            hist[i, int(rng.integers(0, t)), int(rng.integers(0, 2))] = np.nan
        elif r < 0.5:
            hist[i, int(rng.integers(0, t))] = rng.choice([np.inf, -np.inf])
        elif r < 0.6:  # standing still, signed zeros
            hist[i] = rng.choice([0.0, -0.0])
    hist[rng.random((n, t)) < 0.1] = np.nan
    return hist


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 12),
    t=st.integers(1, 14),
    w=st.integers(1, 8),
    horizon=st.sampled_from([0, 1, 2, 7, 40, 148]),
    dt=st.sampled_from([1 / 30, 1 / 25, 0.1, 0.4, 1 / 2.5]),
    kind=st.sampled_from(["clean", "messy"]),
)
def test_compiled_and_interpreted_forms_equal_the_previous_form(seed, n, t, w, horizon, dt, kind):
    rng = np.random.default_rng(seed)
    q = PredictionQuery(np.arange(n), _history(rng, n, t, kind), dt=dt, horizon=horizon)
    want, want_short = _previous(w, q)
    hist = np.ascontiguousarray(q.history[:, -(w + 1) :], dtype=float)
    for form in (COMPILED, cv._extrapolate_numpy):
        got, short = form(hist, w, dt, horizon)
        assert got.shape == want.shape and got.dtype == want.dtype
        # bit for bit: same bytes (so -0.0 and NaN payloads too)
        assert got.tobytes() == np.ascontiguousarray(want).tobytes()
        assert int(short) == want_short


@pytest.mark.parametrize("compiled", [True, False])
def test_predict_through_either_form_equals_the_previous_predict(monkeypatch, compiled):
    monkeypatch.setattr(cv, "_extrapolate", COMPILED if compiled else cv._extrapolate_numpy)
    rng = np.random.default_rng(7)
    for _ in range(300):
        n, t, w = int(rng.integers(1, 9)), int(rng.integers(1, 125)), int(rng.integers(1, 7))
        # dt as a numpy float64 and the horizon as a numpy integer too (both compiled)
        dt = [1 / 30, np.float64(0.4)][int(rng.integers(0, 2))]
        horizon = [int(rng.integers(0, 150)), np.int64(rng.integers(0, 150))][int(rng.integers(2))]
        q = PredictionQuery(np.arange(n), _history(rng, n, t, "messy"), dt=dt, horizon=horizon)
        f = ConstantVelocityPredictor(window=w).predict(q)
        want, short = _previous(w, q)
        assert f.positions.tobytes() == np.ascontiguousarray(want).tobytes()
        assert f.info == {"n_short_history": short}


def test_other_dt_types_keep_numpys_promotion():
    """A float32 dt (or a non-integer horizon) takes the numpy form: the same promotion as
    before (``w * dt`` stays float32 there)."""
    rng = np.random.default_rng(3)
    hist = rng.normal(0.0, 1.0, (4, 6, 2))
    q = PredictionQuery(np.arange(4), hist, dt=np.float32(0.1), horizon=12)
    got = ConstantVelocityPredictor().predict(q)
    want, _ = _previous(5, q)
    assert got.positions.tobytes() == want.tobytes()
    # and it differs from the float64 dt's numbers (so the test could fail)
    q64 = PredictionQuery(np.arange(4), hist, dt=float(np.float32(0.1)), horizon=12)
    assert ConstantVelocityPredictor().predict(q64).positions.tobytes() != want.tobytes()
