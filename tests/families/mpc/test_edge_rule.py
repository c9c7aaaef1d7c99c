"""The sampling MPC at the edges (issue 30): the edge rule, lambda's ceiling, the margin."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.families.cbf.records import ControlState
from conformal_control.families.cbf.reference import AttractiveField
from conformal_control.families.cbf.stepwise import Stream
from conformal_control.families.mpc import SamplingMPC
from conformal_control.families.mpc.kernels import evaluate
from conformal_control.families.mpc.settings import Limits, Sampling
from conformal_control.families.mpc.stepwise import StepwiseMPC
from conformal_control.predictors import ConstantVelocityPredictor, PredictionQuery

FAST = {"sampling__n_samples": 60, "sampling__horizon": 6}
D_C = 1.0


def calm_then_standing(calm: int, **kw) -> tuple[float, float]:
    """``calm`` samples (0.1 s) with two pedestrians walking 3 m beside the robot (the
    loss stays below epsilon: lambda climbs), then one standing 4 m ahead on its path:
    (lambda when it appears, the robot's smallest distance to it over 6 s)."""
    ctrl = StepwiseMPC(family=("mpc", FAST), stream=Stream(tau=0.4, dt=0.1), **kw)
    x = np.zeros(4)
    stand: np.ndarray | None = None
    lam0, d_min = math.nan, math.inf
    for k in range(calm + 60):
        t = 0.1 * k
        if k < calm:
            ids, pos = [1, 2], x[:2] + np.array([[0.0, 3.0], [0.0, -3.0]])
            goal = x[:2] + np.array([10.0, 0.0])
        else:
            if stand is None:
                stand, lam0 = x[:2] + np.array([4.0, 0.0]), ctrl.lam
            ids, pos, goal = [3], stand[None], stand + np.array([6.0, 0.0])
        ctrl.observe(ids, pos, t=t)
        for j in range(ctrl.substeps):
            u = ctrl.step(x, t=t + j * ctrl.dt_control, goal=goal)
            x = np.r_[x[:2] + u * ctrl.dt_control, u]
            if stand is not None:
                d_min = min(d_min, float(np.hypot(*(x[:2] - stand))))
    return lam0, d_min


def test_lambda_cannot_wind_up_through_a_pedestrian_by_default() -> None:
    lam, d_min = calm_then_standing(250)
    assert lam <= 0.0  # the ceiling: margin = 0
    assert d_min >= D_C
    # the former default (no ceiling) winds up and passes inside the collision distance
    lam, d_min = calm_then_standing(250, lambda_max=math.inf)
    assert lam > 1.0 and d_min < D_C


def test_the_ceiling_follows_the_margin_and_a_floor_above_it_is_refused() -> None:
    ctrl = StepwiseMPC(family=("mpc", {**FAST, "margin": 0.3}))
    assert ctrl.stepper.rule.lambda_max == 0.3
    assert StepwiseMPC(family=("acp_mpc", FAST)).stepper.rule.lambda_max == math.inf
    with pytest.raises(ValueError, match="lambda_min") as info:
        StepwiseMPC(family=("mpc", FAST), lambda_min=0.5)
    assert "\n" not in str(info.value)


def test_a_negative_margin_is_a_one_line_error() -> None:
    with pytest.raises(ValueError, match="margin must be a finite distance >= 0") as info:
        ctrl = StepwiseMPC(family=("mpc", {**FAST, "margin": -5.0}))
        ctrl.observe([1], [[0.5, 0.0]], t=0.0)
        ctrl.step(np.zeros(4), t=0.0, goal=np.array([10.0, 0.0]))
    assert "\n" not in str(info.value)


def test_a_run_gets_the_ceiling_unless_it_gives_one() -> None:
    from conformal_control.data import load_scene
    from conformal_control.runs.build import build_flagship

    scene = load_scene("crossing", seed=0)
    fl = build_flagship(scene, {"barrier_margin": 0.2}, family="mpc", family_params=FAST)
    assert fl.rule.lambda_max == pytest.approx(0.2)
    fl = build_flagship(scene, {"lambda_max": 2.0}, family="mpc", family_params=FAST)
    assert fl.rule.lambda_max == 2.0  # an option may be looser


# ------------------------------------------------------------------------------ the edge rule
def planner(edge: str = "escape", fallback: str = "brake") -> SamplingMPC:
    mpc = SamplingMPC(
        ConstantVelocityPredictor(),
        VelocityTrackingDoubleIntegrator(K_acc=10.0),
        AttractiveField(K_att=1.0, v_max=1.5),
        sampling=Sampling(n_samples=80, horizon=5, dt_plan=0.3),
        d_c=D_C,
        limits=Limits(v_max=1.5),
        fallback=fallback,
        substeps=2,
        edge=edge,
    )
    mpc.reset()
    return mpc


@st.composite
def scenes(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Robot at the origin with some velocity; 1-4 pedestrians, the first within d_c."""
    n = draw(st.integers(1, 4))
    pos, vel = [], []
    for i in range(n):
        r = draw(st.floats(0.1, 0.95)) if i == 0 else draw(st.floats(0.3, 4.0))
        a = draw(st.floats(-math.pi, math.pi))
        pos.append([r * math.cos(a), r * math.sin(a)])
        vel.append([draw(st.floats(-1.0, 1.0)), draw(st.floats(-1.0, 1.0))])
    v_ego = np.array([draw(st.floats(-1.0, 1.0)), draw(st.floats(-1.0, 1.0))])
    lam = draw(st.sampled_from([0.0, -0.5, 0.8]))
    return np.array(pos), np.array(vel), v_ego, lam


@settings(max_examples=25, deadline=None)
@given(scenes(), st.sampled_from(["brake", "least_violation"]))
def test_no_plan_closes_in_on_an_overlapped_pedestrian_when_another_exists(case, fallback):
    pos, vel, v_ego, lam = case
    mpc = planner(fallback=fallback)
    hist = pos[:, None, :] + vel[:, None, :] * (np.arange(-4, 1)[None, :, None] * 0.1)
    mpc.begin_interval(PredictionQuery(ids=np.arange(len(pos)), history=hist, dt=0.1, horizon=2))
    state = ControlState(x=np.r_[0.0, 0.0, v_ego], t=0.0, step=0, goal=np.array([8.0, 0.0]))
    todo = mpc.plan_begin(state, lam)
    closing = mpc.edge_closing(todo)
    assert closing is not None
    plan = mpc.plan_end(todo, *evaluate(*todo.problem))
    i = int(np.flatnonzero((todo.commands == plan.commands).all(axis=(1, 2)))[0])
    if (closing <= 1e-9).any():
        assert closing[i] <= 1e-9
    else:
        assert closing[i] <= closing.min() + 1e-9
    assert mpc.stats()["n_edge"] == 1


def test_paper_mode_leaves_the_choice_to_the_safe_set() -> None:
    mpc = planner(edge="paper")
    hist = np.array([[[0.5, 0.0]] * 5])
    mpc.begin_interval(PredictionQuery(ids=np.arange(1), history=hist, dt=0.1, horizon=2))
    state = ControlState(x=np.zeros(4), t=0.0, step=0, goal=np.array([8.0, 0.0]))
    assert mpc.edge_closing(mpc.plan_begin(state, 0.0)) is None
    with pytest.raises(ValueError, match="edge must be"):
        planner(edge="off")
