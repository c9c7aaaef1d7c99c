"""``SamplingMPC.plan`` runs the work after the rollout as one compiled call
(``kernels.plan_choice``) for a family that shares one safe distance and has no peers' lines:
the plan, the counts, the candidates and the random stream of the two-step form it replaced
(``plan_begin``, ``evaluate``, ``plan_end``), bit for bit, with the edge rule, both fallbacks,
continuous and end-point checks, a warm start and no agent."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.core.jit import compile_now
from conformal_control.families.cbf.records import ControlState
from conformal_control.families.mpc import SamplingMPC, controller
from conformal_control.families.mpc.acp import ACPMPC
from conformal_control.families.mpc.kernels import evaluate
from conformal_control.predictors import PredictionQuery

from .test_edge_rule import planner, scenes

compile_now()


def _two_step(mpc: SamplingMPC, state: ControlState, lam: float) -> controller.Plan:
    """The form before the compiled call (controller.py at e43769b)."""
    todo = mpc.plan_begin(state, lam)
    return mpc.plan_end(todo, *evaluate(*todo.problem, rows=todo.agent_rows()))


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    scenes(),
    st.sampled_from(["brake", "least_violation"]),
    st.sampled_from(["escape", "paper"]),
    st.booleans(),
    st.booleans(),
)
def test_plan_in_one_call_equals_the_two_step_form(case, fallback, edge, continuous, alone) -> None:
    pos, vel, v_ego, lam = case
    calls = []
    real = controller.plan_choice

    def counted(*args):
        calls.append(1)
        return real(*args)

    plans, stats, rngs, cands = [], [], [], []
    for fast in (True, False):
        mpc = planner(edge=edge, fallback=fallback)
        mpc.continuous = continuous
        mpc.reset()
        n = 0 if alone else len(pos)
        hist = pos[:n, None, :] + vel[:n, None, :] * (np.arange(-4, 1)[None, :, None] * 0.1)
        mpc.begin_interval(PredictionQuery(ids=np.arange(n), history=hist, dt=0.1, horizon=2))
        got = []
        for k in range(3):  # the second and third plans start from the last (warm start)
            state = ControlState(
                x=np.r_[0.05 * k, 0.0, v_ego], t=0.1 * k, step=k, goal=np.array([8.0, 0.0])
            )
            if fast:
                controller.plan_choice, before = counted, len(calls)
                try:
                    plan = mpc.plan(state, lam)
                finally:
                    controller.plan_choice = real
                assert len(calls) == before + 1  # the compiled call was used
            else:
                plan = _two_step(mpc, state, lam)
            mpc._warm, mpc._warm_t, mpc._last_cmd = plan.commands, state.t, plan.commands[0]
            got.append(plan)
        plans.append(got)
        stats.append(mpc.stats())
        rngs.append(mpc._rng.bit_generator.state)
        cands.append(mpc._candidates.tobytes())
    for a, b in zip(*plans, strict=True):
        assert a.commands.tobytes() == b.commands.tobytes()
        assert a.positions.tobytes() == b.positions.tobytes()
        assert (a.status, a.n_safe) == (b.status, b.n_safe)
        pair = np.array([a.cost, a.clearance]), np.array([b.cost, b.clearance])
        assert pair[0].tobytes() == pair[1].tobytes()
    assert stats[0] == stats[1]
    assert rngs[0] == rngs[1]
    assert cands[0] == cands[1]


def test_the_cases_the_compiled_call_does_not_take() -> None:
    assert controller._plans_in_one_call(SamplingMPC)
    assert not controller._plans_in_one_call(ACPMPC)  # its own safe_radius

    class Closing(SamplingMPC):
        def edge_closing(self, todo):  # type: ignore[no-untyped-def]
            return super().edge_closing(todo)

    assert not controller._plans_in_one_call(Closing)


def test_lambda_per_agent_keeps_the_two_step_form(monkeypatch: pytest.MonkeyPatch) -> None:
    mpc = planner()
    hist = np.array([[[1.0, 0.0]] * 5, [[0.0, 1.5]] * 5])
    mpc.begin_interval(PredictionQuery(ids=np.arange(2), history=hist, dt=0.1, horizon=2))

    def refused(*args):  # pragma: no cover - must not run
        raise AssertionError("plan_choice used with offsets per agent")

    monkeypatch.setattr(controller, "plan_choice", refused)
    state = ControlState(x=np.zeros(4), t=0.0, step=0, goal=np.array([8.0, 0.0]))
    plan = mpc.plan(state, np.array([0.1, 0.3]))
    assert plan.commands.shape == (5, 2)
