"""The sampling MPC's choice in one compiled call (``kernels.choose_safe``) gives the numbers
of the numpy form it replaced (``SamplingMPC.edge_closing`` and the safe set's argmin in
``plan_end``), bit for bit: NaN costs, clearances, positions and predictions, ties, no agent,
the edge rule with and without an allowed plan."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.core.jit import compile_now
from conformal_control.families.cbf.records import ControlState
from conformal_control.families.mpc import SamplingMPC
from conformal_control.families.mpc.controller import PlanInputs
from conformal_control.families.mpc.kernels import choose_safe, evaluate
from conformal_control.predictors import PredictionQuery

from .test_edge_rule import planner, scenes

compile_now()


def reference(cost, clear, pos, x, pred, y0, d_c, dt_plan, edge):
    """The numpy form before the compiled choice (controller.py at 8b6afa2)."""
    safe = clear >= 0.0
    closing = None
    if edge and y0.shape[0]:
        d0 = np.hypot(*(np.asarray(x, dtype=float)[None, :2] - y0).T)
        near = d0 < float(d_c)
        if near.any():
            gap = pos[:, 0, None, :] - pred[None, near, 0, :]
            d1 = np.hypot(gap[..., 0], gap[..., 1])
            closing = ((d0[near][None, :] - d1) / float(dt_plan)).max(axis=1)
    allowed = None
    if closing is not None:
        allowed = closing <= 1e-9
        if not allowed.any():
            allowed = closing <= closing.min() + 1e-9
        safe &= allowed
    n_safe = int(safe.sum())
    i = int(np.argmin(np.where(safe, cost, np.inf))) if n_safe else -1
    return i, n_safe, allowed


@st.composite
def choices(draw: st.DrawFn):
    rng = np.random.default_rng(draw(st.integers(0, 10_000)))
    n, h, m = draw(st.integers(1, 40)), draw(st.integers(1, 4)), draw(st.integers(0, 6))
    x = rng.uniform(-1, 1, 2)
    y0 = x + rng.uniform(-1.5, 1.5, (m, 2))
    pred = y0[:, None, :] + rng.uniform(-0.5, 0.5, (m, h, 2))
    pos = x + rng.uniform(-0.6, 0.6, (n, h, 2))
    if draw(st.booleans()) and m:  # every candidate closes in on agent 0
        pred[0, 0] = y0[0] = x + 0.3
        pos[:, 0] = x + 0.3 * rng.uniform(0.1, 0.9, (n, 1))
    cost = rng.choice([0.0, 1.0, 2.0, 2.5], n) if draw(st.booleans()) else rng.uniform(0, 9, n)
    clear = rng.choice([-1.0, -0.0, 0.0, 0.5], n)
    for arr in (cost, clear, pos, pred, y0):
        if arr.size and draw(st.integers(0, 3)) == 0:  # a NaN somewhere
            arr.flat[int(rng.integers(arr.size))] = np.nan
    d_c = draw(st.sampled_from([0.3, 0.6, 1.0]))
    dt_plan = draw(st.sampled_from([0.1, 0.3, 0.4]))
    return cost, clear, pos, x, pred, y0, d_c, dt_plan, draw(st.booleans())


@settings(max_examples=150, deadline=None, derandomize=True)
@given(choices())
def test_the_compiled_choice_equals_the_numpy_form(case) -> None:
    want_i, want_n, want_allowed = reference(*case)
    for form in (choose_safe, choose_safe.py_func):
        allowed = np.empty(case[0].shape[0], dtype=np.bool_)
        i, n_safe, applied = form(*case, allowed)
        assert (i, n_safe) == (want_i, want_n)
        assert applied == (want_allowed is not None)
        if applied:
            np.testing.assert_array_equal(allowed, want_allowed)


class NumpyChoice(SamplingMPC):
    """The previous form: a family replacing ``edge_closing`` keeps the numpy choice."""

    def edge_closing(self, todo: PlanInputs) -> np.ndarray | None:
        return super().edge_closing(todo)


@settings(max_examples=25, deadline=None, derandomize=True)
@given(
    scenes(), st.sampled_from(["brake", "least_violation"]), st.sampled_from(["escape", "paper"])
)
def test_plan_end_chooses_as_the_numpy_form(case, fallback, edge) -> None:
    pos, vel, v_ego, lam = case
    plans, stats = [], []
    for cls in (SamplingMPC, NumpyChoice):
        mpc = planner(edge=edge, fallback=fallback)
        mpc.__class__ = cls
        hist = pos[:, None, :] + vel[:, None, :] * (np.arange(-4, 1)[None, :, None] * 0.1)
        mpc.begin_interval(
            PredictionQuery(ids=np.arange(len(pos)), history=hist, dt=0.1, horizon=2)
        )
        state = ControlState(x=np.r_[0.0, 0.0, v_ego], t=0.0, step=0, goal=np.array([8.0, 0.0]))
        todo = mpc.plan_begin(state, lam)
        plans.append(mpc.plan_end(todo, *evaluate(*todo.problem)))
        stats.append(mpc.stats())
    a, b = plans
    assert a.commands.tobytes() == b.commands.tobytes()
    assert a.positions.tobytes() == b.positions.tobytes()
    assert (a.status, a.n_safe) == (b.status, b.n_safe)
    assert np.array([a.cost, a.clearance]).tobytes() == np.array([b.cost, b.clearance]).tobytes()
    assert stats[0] == stats[1]
