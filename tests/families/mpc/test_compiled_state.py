"""acp_mpc's and ecp_mpc's compiled bookkeeping (the errors scored, the sorted windows, the
rolling calibration pairs, the misses of past plans, the quantiles kept by rank) equal the
forms they replace, bit for bit, on random cases (hypothesis, derandomized), compiled and
interpreted."""

from __future__ import annotations

import itertools
import math
from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.core.jit import compile_now
from conformal_control.families.cbf.controller import ControlState
from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.families.mpc import ACPMPC, ECPMPC, Sampling, acp, ecp
from conformal_control.predictors.base import Forecast, PredictionQuery, Predictor

compile_now()  # the compiled kernels are what must equal the forms they replace

DT = 0.4


class Drift(Predictor):
    """Every agent keeps its current position plus a fixed drift per step (rounded to a
    lattice on request: many equal errors)."""

    def __init__(self, lattice: bool = False) -> None:
        self.lattice = lattice

    def predict(self, query: PredictionQuery) -> Forecast:
        steps = np.arange(1, query.horizon + 1)[None, :, None]
        out = query.current[:, None, :] + 0.3 * steps * np.array([1.0, -0.5])
        return Forecast(np.round(out) if self.lattice else out)


def _observations(seed: int, n: int, agents: int, sub: int, lattice: bool) -> list:
    """Agents on random walks sampled every DT / sub; each present at times, in a random
    order, with gaps (NaN) in their histories."""
    rng = np.random.default_rng(seed)
    cols = 12
    walk = np.cumsum(rng.normal(0.0, 0.4, (agents, n * sub + cols, 2)), axis=1)
    if lattice:
        walk = np.round(walk)
    out = []
    for k in range(n):
        here = np.flatnonzero(rng.random(agents) < 0.75)
        here = rng.permutation(here)
        end = k * sub + cols
        hist = walk[here, end - cols : end].copy()
        gaps = rng.random(hist.shape[:2]) < 0.08
        gaps[:, -1] = False
        hist[gaps] = np.nan
        out.append(
            PredictionQuery(
                ids=here.astype(np.int64),
                history=hist,
                dt=DT / sub,
                horizon=sub,
                t=k * DT,
                frame=k,
                scene="t",
            )
        )
    return out


# ---------------------------------------------------------------------------- acp_mpc
def _add_scores_with_insert(fam: ACPMPC, steps: np.ndarray, errors: np.ndarray) -> None:
    """The sorted windows as first kept (numpy.delete / numpy.insert per step): the form
    the compiled merge replaces."""
    sorted_ = list(fam._sorted)
    for h in range(len(fam.scores_)):
        new = errors[steps == h + 1]
        if not new.size:
            continue
        win = fam.scores_[h]
        old = sorted_[h]
        cap = int(fam.window)
        gone = max(len(win) + new.size - cap, 0)
        fresh = (
            old.size != len(win)
            or gone > len(win)
            or not np.isfinite(new).all()
            or bool(old.size and np.isnan(old[-1]))
        )
        if not fresh and gone:
            out = np.sort(np.fromiter(itertools.islice(win, gone), float, count=gone))
            at = np.searchsorted(old, out, "left")
            at += np.arange(gone) - np.searchsorted(out, out, "left")
            old = np.delete(old, at)
        win.extend(new.tolist())
        if fresh:
            sorted_[h] = np.sort(np.fromiter(win, float))
        else:
            add = np.sort(new)
            sorted_[h] = np.insert(old, np.searchsorted(old, add, "left"), add)
    fam._sorted = tuple(sorted_)


def _acp(window: int, horizon: int, lattice: bool = False) -> ACPMPC:
    fam = ACPMPC(
        Drift(lattice),
        VelocityTrackingDoubleIntegrator(10.0),
        sampling=Sampling(n_samples=10, horizon=horizon, dt_plan=DT),
        substeps=1,
        window=window,
    )
    fam.reset()
    return fam


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 10_000),
    window=st.integers(1, 12),
    horizon=st.integers(2, 5),
    agents=st.integers(0, 7),
    sub=st.sampled_from([1, 2, 3]),
    lattice=st.booleans(),
)
def test_acp_scoring_and_windows_equal_the_numpy_forms(
    seed: int, window: int, horizon: int, agents: int, sub: int, lattice: bool
) -> None:
    """The compiled scoring equals the vectorised numpy scoring (errors, their order,
    counters, what stays pending), and the merged windows equal numpy.delete/insert,
    interval by interval."""
    fam, ref = _acp(window, horizon, lattice), _acp(window, horizon, lattice)
    ref._score = ref._score_numpy  # type: ignore[method-assign]
    ref._add_scores = lambda s, e: _add_scores_with_insert(ref, s, e)  # type: ignore[method-assign]
    for obs in _observations(seed, 16, agents, sub, lattice):
        fam.begin_interval(obs)
        ref.begin_interval(obs)
        for a, b in zip(fam._scored, ref._scored, strict=True):
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes()
        assert (fam.n_scored_, fam.n_unscored_) == (ref.n_scored_, ref.n_unscored_)
        assert [(e[0], e[3]) for e in fam._pending] == [(e[0], e[3]) for e in ref._pending]
        for x, y, win in zip(fam._sorted, ref._sorted, fam.scores_, strict=True):
            assert x.tobytes() == y.tobytes()
            assert x.tobytes() == np.sort(np.fromiter(win, float)).tobytes()
        assert [list(w) for w in fam.scores_] == [list(w) for w in ref.scores_]


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 10_000),
    window=st.integers(1, 9),
    horizon=st.integers(2, 4),
)
def test_acp_windows_equal_numpy_insert_with_ties_non_finite_errors_and_outside_fills(
    seed: int, window: int, horizon: int
) -> None:
    """Batches of errors on a lattice (ties), more than a window at once, inf and NaN
    among them, windows filled from outside: the merged windows equal the first form."""
    rng = np.random.default_rng(seed)
    fam, ref = _acp(window, horizon), _acp(window, horizon)
    for _ in range(25):
        n = int(rng.integers(0, 3 * window + 2))
        steps = rng.integers(1, horizon + 1, n)
        errors = np.round(rng.uniform(0.0, 4.0, n) * 2) / 2
        errors[rng.random(n) < 0.03] = np.inf
        errors[rng.random(n) < 0.02] = np.nan
        h = int(rng.integers(horizon))
        extra = np.round(rng.uniform(0, 4, int(rng.integers(1, 4)))).tolist()
        if rng.random() < 0.15 and len(fam.scores_[h]) + len(extra) <= window:
            fam.scores_[h].extend(extra)  # filled from outside (its length changes)
            ref.scores_[h].extend(extra)
        fam._add_scores(steps, errors)
        _add_scores_with_insert(ref, steps, errors)
        for x, y in zip(fam._sorted, ref._sorted, strict=True):
            assert x.tobytes() == y.tobytes()


def test_acp_non_integer_ids_take_the_numpy_scoring() -> None:
    """Float ids are scored by the numpy form (the compiled one takes integer ids), with
    the same errors as integer ids."""
    obs = _observations(3, 12, 5, 2, False)
    fam, ref = _acp(50, 3), _acp(50, 3)
    for q in obs:
        ref.begin_interval(q)
        fam.begin_interval(
            PredictionQuery(
                ids=q.ids.astype(float),
                history=q.history,
                dt=q.dt,
                horizon=q.horizon,
                t=q.t,
                frame=q.frame,
                scene=q.scene,
            )
        )
        assert fam._scored[1].tobytes() == ref._scored[1].tobytes()
    assert fam.n_scored_ == ref.n_scored_ > 0


# ---------------------------------------------------------------------------- ecp_mpc
def _ecp(horizon: int, size: int, m: int, lattice: bool) -> ECPMPC:
    fam = ECPMPC(
        Drift(lattice),
        VelocityTrackingDoubleIntegrator(10.0),
        sampling=Sampling(n_samples=12, horizon=horizon, dt_plan=DT * m),
        substeps=1,
        calibration_size=size,
    )
    fam.reset()
    return fam


def _pair(obs: dict, made: dict, h: int) -> tuple[np.ndarray, np.ndarray]:
    """Observed positions at ``obs`` and the step-h predictions of ``made`` for the
    pedestrians in both (numpy.intersect1d, as first written)."""
    _, i_obs, i_pred = np.intersect1d(
        obs["ids"], made["ids"], assume_unique=True, return_indices=True
    )
    return obs["cur"][i_obs], made["pred"][i_pred, h - 1]


def _pairs_afresh(fam: ECPMPC) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The calibration arrays computed afresh from the kept sampling times, every pair of
    times by numpy.intersect1d: the form the rolling arrays replace."""
    past = fam._past
    h_n, b_max = int(fam.sampling.horizon), int(fam.calibration_size)
    pairs = []
    width = 0
    for h in range(1, h_n + 1):
        row = []
        for b in range(b_max):
            i_obs = len(past) - 1 - b
            i_made = i_obs - h * fam._m
            if i_made < 0:
                break
            y, yhat = _pair(past[i_obs], past[i_made], h)
            row.append((y, yhat))
            width = max(width, y.shape[0])
        pairs.append(row)
    cal_pred = np.zeros((h_n, b_max, max(width, 1), 2))
    cal_obs = np.zeros_like(cal_pred)
    cal_n = np.zeros((h_n, b_max), dtype=np.int64)
    cal_b = np.array([len(r) for r in pairs], dtype=np.int64)
    for h, row in enumerate(pairs):
        for b, (y, yhat) in enumerate(row):
            k = y.shape[0]
            cal_obs[h, b, :k] = y
            cal_pred[h, b, :k] = yhat
            cal_n[h, b] = k
    return cal_pred, cal_obs, cal_n, cal_b


@settings(max_examples=25, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 10_000),
    horizon=st.integers(2, 4),
    size=st.integers(1, 6),
    m=st.sampled_from([1, 2]),
    agents=st.integers(0, 8),
    lattice=st.booleans(),
)
def test_ecp_rolling_calibration_and_misses_equal_the_pairs_afresh(
    seed: int, horizon: int, size: int, m: int, agents: int, lattice: bool
) -> None:
    """At every interval, the rolling calibration pairs equal the pairs computed afresh
    from the kept sampling times, and the misses of past plans equal ``_missed`` on the
    pairs of numpy.intersect1d."""
    fam = _ecp(horizon, size, m, lattice)
    for k, obs in enumerate(_observations(seed, 14, agents, m, lattice)):
        fam.begin_interval(obs)
        cal_pred, cal_obs, cal_n, cal_b = fam._cal  # type: ignore[misc]
        want_pred, want_obs, want_n, want_b = _pairs_afresh(fam)
        assert cal_b.tolist() == want_b.tolist()
        for h in range(horizon):
            for b in range(cal_b[h]):
                c = cal_n[h, b]
                assert c == want_n[h, b]
                assert cal_pred[h, b, :c].tobytes() == want_pred[h, b, :c].tobytes()
                assert cal_obs[h, b, :c].tobytes() == want_obs[h, b, :c].tobytes()
        want = []
        past = fam._past
        for h in range(1, horizon + 1):
            if h * m >= len(past):
                break
            made = past[-1 - h * m]
            if made["pos"] is None:
                continue
            y, yhat = _pair(past[-1], made, h)
            if y.shape[0]:
                want.append(ecp._missed(made["pos"][:, h - 1], yhat, y, made["q"][:, h - 1]))
        want_missed = np.concatenate(want) if want else np.zeros(0, dtype=bool)
        assert fam._missed.tolist() == want_missed.tolist()
        state = ControlState(np.array([0.0, 0.0, 0.0, 0.0]), obs.t, k, np.array([6.0, 1.0]))
        fam.decide(state, 0.1 + 0.05 * (k % 3))


def test_ecp_repeated_ids_are_a_one_line_error() -> None:
    """Ids repeated in an observation cannot be paired with another time's: a one-line
    error naming the time (numpy.intersect1d indexed out of bounds before)."""
    fam = _ecp(2, 3, 1, False)
    obs = _observations(5, 3, 4, 1, False)
    fam.begin_interval(obs[0])
    q = obs[1]
    ids = np.concatenate([q.ids, q.ids[:1]])
    hist = np.concatenate([q.history, q.history[:1]])
    rep = PredictionQuery(ids=ids, history=hist, dt=q.dt, horizon=1, t=q.t, frame=1, scene="t")
    with pytest.raises(ValueError, match="distinct pedestrian ids") as info:
        fam.begin_interval(rep)
    assert "\n" not in str(info.value) and "t = 0.4 s" in str(info.value)


def _quantiles_sorted(pos, cal_pred, cal_obs, cal_n, cal_b, lam):  # type: ignore[no-untyped-def]
    """Every score stored and sorted (numpy, the same arithmetic as the kernel), the k-th
    smallest taken."""
    n_plans, horizon = pos.shape[:2]
    out = np.empty((n_plans, horizon))
    for h in range(horizon):
        b_n = int(cal_b[h])
        if lam >= 1.0:
            out[:, h] = -np.inf
            continue
        k = math.ceil((b_n + 1) * (1.0 - lam))
        if lam <= 0.0 or b_n == 0 or k > b_n:
            out[:, h] = np.inf
            continue
        scores = np.zeros((b_n, n_plans))
        for b in range(b_n):
            c = cal_n[h, b]
            if c == 0:
                continue
            d = pos[:, h, None, :] - cal_pred[h, b, None, :c]
            dp = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]).min(axis=1)
            d = pos[:, h, None, :] - cal_obs[h, b, None, :c]
            do = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]).min(axis=1)
            s = np.sqrt(dp) - np.sqrt(do)
            scores[b] = np.where(s > 0.0, s, 0.0)
        out[:, h] = np.sort(scores, axis=0)[max(k, 1) - 1]
    return out


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 10_000),
    b_max=st.integers(1, 20),
    m=st.integers(1, 6),
    lattice=st.booleans(),
)
def test_ecp_quantiles_kept_by_rank_equal_sorting_every_score(
    seed: int, b_max: int, m: int, lattice: bool
) -> None:
    """The quantiles kept while the scores come (the largest two or the smallest two)
    and those selected from stored scores equal sorting every score, at levels that give
    every rank from either end."""
    rng = np.random.default_rng(seed)
    h = 3
    pos = rng.normal(0.0, 2.0, (15, h, 2))
    cal_pred = rng.normal(0.0, 2.0, (h, b_max, m, 2))
    cal_obs = cal_pred + rng.normal(0.0, 0.7, (h, b_max, m, 2))
    if lattice:
        pos, cal_pred, cal_obs = np.round(pos), np.round(cal_pred), np.round(cal_obs)
    cal_n = rng.integers(0, m + 1, (h, b_max))
    cal_b = rng.integers(0, b_max + 1, h)
    for rank in range(1, b_max + 2):  # k = rank: lam just below 1 - rank / (B + 1)
        lam = 1.0 - (rank - 0.5) / (b_max + 1)
        args = (pos, cal_pred, cal_obs, cal_n, cal_b, lam)
        want = _quantiles_sorted(*args)
        for cut in (True, False):
            got = ecp.egocentric_quantiles(*args, cut=cut)
            assert got.tobytes() == want.tobytes(), (rank, cut)


@settings(max_examples=30, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 40),
    m=st.integers(1, 8),
    shift=st.sampled_from([0.0, 1e4]),
    lattice=st.booleans(),
)
def test_ecp_misses_at_a_step_equal_missed(
    seed: int, n: int, m: int, shift: float, lattice: bool
) -> None:
    """``_missed_at`` (no copies, the exact cut) equals ``_missed`` (every pedestrian)."""
    rng = np.random.default_rng(seed)
    pos = rng.normal(0.0, 2.0, (n, 3, 2)) + shift
    pred = rng.uniform(-8, 8, (m + 2, 2)) + shift
    obs = pred + rng.normal(0.0, 0.6, pred.shape)
    if lattice:
        pos, pred, obs = np.round(pos), np.round(pred), np.round(obs)
    q = rng.uniform(-0.2, 1.0, (n, 3))
    q[rng.random((n, 3)) < 0.1] = np.inf
    for h in range(3):
        got = ecp._missed_at(pos, q, h, pred, obs, m)
        want = ecp._missed(pos[:, h], pred[:m], obs[:m], q[:, h])
        assert got.tolist() == want.tolist()


def test_the_interpreted_kernels_equal_the_compiled_ones() -> None:
    """Each new kernel's Python form gives the compiled form's numbers."""
    rng = np.random.default_rng(11)
    pos = rng.normal(0, 2, (20, 3, 2))
    cal = rng.normal(0, 2, (3, 7, 4, 2)), rng.normal(0, 2, (3, 7, 4, 2))
    cal_n = rng.integers(0, 5, (3, 7))
    cal_b = np.array([7, 5, 6])
    for lam in (0.05, 0.1, 0.2, 0.5):
        args = (pos, *cal, cal_n, cal_b, lam, True)
        assert ecp._quantiles(*args).tobytes() == ecp._quantiles.py_func(*args).tobytes()
    q = rng.uniform(0, 1, (20, 3))
    args2 = (pos, q, 1, cal[0][0, 0], cal[1][0, 0], 4)
    assert ecp._missed_at(*args2).tolist() == ecp._missed_at.py_func(*args2).tolist()
    roll = [np.array([3, 1, 7], dtype=np.int64), rng.normal(0, 1, (3, 2))]
    made = [np.array([7, 3, 2, 1], dtype=np.int64), np.array([0, 4, 4], dtype=np.int64)]
    made_pred = rng.normal(0, 1, (4, 2))
    outs = []
    for f in (ecp._roll_pairs, ecp._roll_pairs.py_func):
        bufs = np.zeros((2, 3, 3, 2)), np.zeros((2, 3, 3, 2)), np.zeros((2, 3), dtype=np.int64)
        for _ in range(3):
            assert f(*roll, *made, made_pred, *bufs)
        outs.append([x.tobytes() for x in bufs])
    assert outs[0] == outs[1]
    fams = []
    for compiled in (True, False):
        fam = _acp(4, 3, True)
        if not compiled:
            acp_kernels = acp._score_kernel, acp._merge_windows
            acp._score_kernel = acp._score_kernel.py_func
            acp._merge_windows = acp._merge_windows.py_func
        try:
            for obs in _observations(2, 12, 5, 2, True):
                fam.begin_interval(obs)
        finally:
            if not compiled:
                acp._score_kernel, acp._merge_windows = acp_kernels
        fams.append(fam)
    assert [x.tobytes() for x in fams[0]._sorted] == [x.tobytes() for x in fams[1]._sorted]
    assert fams[0].n_scored_ == fams[1].n_scored_ > 0
    assert isinstance(fams[0].scores_[0], deque)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10_000), horizon=st.integers(1, 6))
def test_acp_region_radii_equal_the_radius_step_by_step(seed: int, horizon: int) -> None:
    """The radii of all steps at once equal ``region_radii`` (``conformal_radius`` per
    step), at levels around every rank and at the edges."""
    from conformal_control.families.cbf.acp import region_radii

    rng = np.random.default_rng(seed)
    scores = tuple(
        np.sort(np.round(rng.uniform(0, 3, int(rng.integers(0, 25))), 1)) for _ in range(horizon)
    )
    levels = [-0.5, 0.0, 1e-9, 0.04, 0.1, 0.25, 0.5, 0.9, 1 - 1e-12, 1.0, 2.0]
    levels += [1 - r / 26 for r in range(27)] + [-math.inf]
    for lam in levels:
        got = acp._region_radii(scores, lam)
        assert got.tobytes() == region_radii(scores, lam).tobytes(), lam
