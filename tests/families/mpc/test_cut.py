"""The evaluation's exact cut (agents that cannot be a step's nearest are skipped) gives the
uncut kernel's numbers bit for bit, and it does skip agents."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.core.jit import compile_now
from conformal_control.families.mpc import kernels
from conformal_control.families.mpc.kernels import evaluate, evaluate_many

# the compiled kernels: the vectorised agent loops are what the cut must not change
compile_now()


def _problem(seed: int, n: int, h: int, m: int, spread: float, shift: float, continuous: bool):
    """A sampling-MPC evaluation: candidates fanning out from p0 (random walks), agents
    near and far (some on the candidates' paths, some tied in distance, some frozen, some
    duplicated), everything shifted by ``shift`` metres (large coordinates)."""
    rng = np.random.default_rng(seed)
    p0 = rng.normal(0.0, 1.0, 2)
    cmds = rng.uniform(-1.0, 1.0, (n, h, 2))
    pos = p0 + np.cumsum(0.4 * cmds, axis=1)
    y0 = rng.uniform(-spread, spread, (m, 2))
    vel = rng.normal(0.0, 1.0, (m, 2)) * (rng.random((m, 1)) < 0.8)  # some frozen
    pred = y0[:, None] + vel[:, None] * 0.4 * np.arange(1, h + 1)[None, :, None]
    if m >= 3:
        pred[0] = pos[rng.integers(n)]  # an agent on a candidate's path
        y0[0] = p0
        pred[1], y0[1] = pred[2], y0[2]  # a duplicate (a tie at every step)
    if m >= 4:  # the mirror image of agent 3 about p0 at every step: tied distances at h=0
        pred[m - 1] = 2 * p0 - pred[3]
        y0[m - 1] = 2 * p0 - y0[3]
    radius = rng.uniform(0.3, 1.5, (n, h)) if seed % 2 else rng.uniform(0.3, 1.5, h)
    off = np.array([shift, -shift])
    return (
        pos + off, cmds, p0 + off, pred + off, y0 + off, radius, rng.normal(0.0, 5.0, 2) + off,
        (1.0, 10.0, 0.01, 0.1 * (seed % 3)), rng.normal(size=2), continuous,
    )  # fmt: skip


def _same(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...]) -> None:
    for x, y, what in zip(a, b, ("cost", "clearance", "violation"), strict=True):
        assert x.dtype == y.dtype and x.shape == y.shape, what
        assert x.tobytes() == y.tobytes(), what  # bit for bit (inf and -0.0 included)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 40),
    h=st.integers(1, 8),
    m=st.integers(0, 14),
    spread=st.sampled_from([0.5, 3.0, 15.0, 60.0]),
    shift=st.sampled_from([0.0, 1e3, 1e5]),
    continuous=st.booleans(),
)
def test_the_cut_gives_the_uncut_numbers_bit_for_bit(
    seed: int, n: int, h: int, m: int, spread: float, shift: float, continuous: bool
) -> None:
    p = _problem(seed, n, h, m, spread, shift, continuous)
    _same(evaluate(*p, cut=True), evaluate(*p, cut=False))


def test_the_cut_in_one_call_for_many_problems_and_with_offsets() -> None:
    problems = [_problem(s, 30, 6, 9, 20.0, 0.0, s % 2 == 0) for s in range(5)]
    problems[3] = (*problems[3], np.linspace(-0.3, 0.4, 9))  # lambda per agent: not cut
    cut = evaluate_many(problems, cut=True)
    for p, got, uncut in zip(problems, cut, evaluate_many(problems, cut=False), strict=True):
        _same(got, uncut)
        _same(got, evaluate(*p, cut=False))


def test_the_cut_skips_the_agents_no_candidate_can_reach() -> None:
    """Far agents are dropped per step (so the cut does work), the nearest never is, and an
    agent just beyond the bound (within the rounding margin) is kept."""
    n, h = 50, 4
    p = _problem(7, n, h, 0, 1.0, 0.0, True)
    pos, p0 = p[0], p[2]
    near = pos[:, -1].mean(axis=0)  # an agent among the candidates, still
    far = near + np.array([200.0, 0.0])
    ex = np.array([[near[0], far[0], far[0] + 1.0]] * h)
    ey = np.array([[near[1], far[1], far[1]]] * h)
    args = (pos, p0, ex, ey, ex.copy(), ey.copy(), True, 0, n, 0, 3)
    kx, _, _, _, cnt = kernels._kept_agents(*args, True)
    assert cnt.tolist() == [1] * h and (kx[:, 0] == near[0]).all()
    assert kernels._kept_agents(*args, False)[4].tolist() == [3] * h
    # an agent whose distance bound equals the nearest's farthest corner exactly is kept
    lo, hi = pos[:, 0].min(axis=0), pos[:, 0].max(axis=0)
    corner = float(np.max(np.abs(np.stack([hi - near, near - lo])), axis=0).max())
    edge = np.array([[near[0], hi[0] + corner * 0.999]] * h)
    two = (pos, p0, edge, ey[:, :2], edge.copy(), ey[:, :2].copy(), True, 0, n, 0, 2, True)
    assert kernels._kept_agents(*two)[4][0] == 2


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 30),
    h=st.integers(1, 5),
    m=st.integers(1, 12),
    spread=st.sampled_from([1.0, 10.0, 40.0]),
    shift=st.sampled_from([0.0, 1e4]),
    lattice=st.booleans(),
)
def test_the_egocentric_quantiles_cut_gives_the_uncut_numbers_bit_for_bit(
    seed: int, n: int, h: int, m: int, spread: float, shift: float, lattice: bool
) -> None:
    """ecp_mpc's regions: each score's two nearest distances over the pedestrians that can
    be a candidate's nearest (a near crowd and a far one, ties on a lattice)."""
    from conformal_control.families.mpc.ecp import egocentric_quantiles

    rng = np.random.default_rng(seed)
    b_max = int(rng.integers(1, 16))
    pos = rng.normal(0.0, 1.5, (n, h, 2)) * np.arange(1, h + 1)[None, :, None]
    cal_pred = rng.uniform(-spread, spread, (h, b_max, m, 2))
    cal_obs = cal_pred + rng.normal(0.0, 0.5, (h, b_max, m, 2))
    if lattice:
        pos, cal_pred, cal_obs = np.round(pos), np.round(cal_pred), np.round(cal_obs)
    pos, cal_pred, cal_obs = pos + shift, cal_pred + shift, cal_obs + shift
    cal_n = rng.integers(0, m + 1, (h, b_max))
    cal_b = rng.integers(0, b_max + 1, h)
    for lam in (0.05, 0.1, 0.3, 0.9):
        args = (pos, cal_pred, cal_obs, cal_n, cal_b, lam)
        got = egocentric_quantiles(*args, cut=True)
        assert got.tobytes() == egocentric_quantiles(*args, cut=False).tobytes(), lam


def test_the_egocentric_cut_skips_far_pedestrians() -> None:
    from conformal_control.families.mpc.ecp import _nearest_candidates

    pts = np.array([[0.5, 0.0], [100.0, 0.0], [0.0, 2.5], [0.0, 3.0], [-1.0, -1.0]])
    keep = np.empty(5, dtype=np.int64)
    k = _nearest_candidates(pts, 5, -1.0, 1.0, -1.0, 1.0, 1e-9, keep)
    # every candidate is within 1.80 m of the first (its farthest corner), at least 2 m
    # from (0, 3) and 99 m from (100, 0): never the nearest; (0, 2.5) may be
    assert keep[:k].tolist() == [0, 2, 4]
    assert _nearest_candidates(pts, 5, -1.0, 1.0, -1.0, 1.0, np.inf, keep) == 5
