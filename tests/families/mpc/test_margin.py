"""margin_miscoverage: the clearance error against brute force, the loss's threshold in
lambda, and lambda following the predictor's error in closed loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.core import registry
from conformal_control.families.cbf.controller import CBFIntervalRecord
from conformal_control.families.cbf.interp import interpolate_at_substeps
from conformal_control.families.cbf.loss import CBFTruth
from conformal_control.families.mpc.margin import (
    AgentMarginMiscoverageLoss,
    MarginMiscoverageLoss,
    agent_clearance_errors,
    clearance_errors,
)

DT, SUB = 0.4, 4


def interval(true: np.ndarray, pred: np.ndarray, x_ego: np.ndarray):
    s = x_ego.shape[0]
    xp, vp = interpolate_at_substeps(pred, DT, SUB, s)
    rec = CBFIntervalRecord(
        ids=np.arange(true.shape[0]),
        x_ego=x_ego,
        v_ego=np.zeros_like(x_ego),
        x_pred=xp,
        v_pred=vp,
        lam_applied=np.zeros(s),
        status=["optimal"] * s,
    )
    return rec, CBFTruth(true, DT, SUB)


def test_clearance_errors_equal_a_brute_force_evaluation():
    rng = np.random.default_rng(0)
    true = rng.uniform(-3, 3, (3, 2, 2))
    pred = true + rng.normal(0, 0.5, true.shape)
    pred[:, 0] = true[:, 0]
    x = np.column_stack([np.linspace(-1, 1, SUB), np.zeros(SUB)])
    rec, truth = interval(true, pred, x)
    for d_safe in (math.inf, 2.5):
        got = clearance_errors(rec, truth, d_safe)
        want = []
        for s in range(SUB):
            f = s / SUB
            y = true[:, 0] + f * (true[:, 1] - true[:, 0])
            yh = pred[:, 0] + f * (pred[:, 1] - pred[:, 0])
            dt_ = min(np.hypot(*(x[s] - p)) for p in y)
            dp_ = min(np.hypot(*(x[s] - p)) for p in yh)
            if min(dt_, dp_) <= d_safe:
                want.append(dp_ - dt_)
        np.testing.assert_allclose(got, want, atol=1e-12)


def test_the_loss_is_the_margin_threshold_in_lambda():
    true = np.array([[[1.0, 0.0], [1.0, 0.0]]])
    pred = np.array([[[1.0, 0.0], [2.0, 0.0]]])  # predicted to walk away: 0.75 m too far
    x = np.zeros((SUB, 2))
    rec, truth = interval(true, pred, x)
    e = clearance_errors(rec, truth)
    assert math.isclose(e.max(), 0.75)
    loss = MarginMiscoverageLoss(margin=0.25, d_safe=3.0)
    # missed when 0.75 > margin - lambda, i.e. lambda > -0.5
    assert [loss(rec, truth, lam) for lam in (-1.0, -0.5, -0.49, 0.0, 0.5)] == [
        0.0,
        0.0,
        1.0,
        1.0,
        1.0,
    ]
    far = MarginMiscoverageLoss(d_safe=0.5)  # nobody within 0.5 m: no loss, no update
    assert far(rec, truth, 0.0) is None


def test_bad_parameters_are_one_line_errors():
    rec, truth = MarginMiscoverageLoss._unit_test_inputs()[0]
    for kw, match in (({"d_safe": 0.0}, "d_safe"), ({"margin": math.nan}, "margin")):
        with pytest.raises(ValueError, match=match) as err:
            MarginMiscoverageLoss(**kw)(rec, truth, 0.0)
        assert "\n" not in str(err.value)


def test_lambda_follows_the_predictors_error_in_closed_loop():
    """The same crossing with a constant-velocity forecast, then with one 0.5 s late:
    the learned distance grows with the error (its mean lambda is lower)."""
    from conformal_control.families.mpc import Sampling, StepwiseMPC
    from conformal_control.predictors.shift import DelayedPredictor

    def run(delay: float) -> float:
        pred = (
            DelayedPredictor("constant_velocity", delay_s=delay) if delay else "constant_velocity"
        )
        family = ("mpc", {"sampling": Sampling(n_samples=150, horizon=8, dt_plan=DT)})
        ctrl = StepwiseMPC(
            pred,
            family=family,
            loss=registry.create("loss", "margin_miscoverage", d_safe=3.0),
            epsilon=0.1,
            eta=0.1,
            lambda_min=-1.0,
            lambda_max=1.0,
        )
        robot, goal = np.zeros(4), np.array([16.0, 0.0])
        rng = np.random.default_rng(1)
        peds = np.array([[6.0, -4.0], [9.0, 5.0], [12.0, -5.0], [4.0, 4.0]])
        vel = np.array([[0.1, 1.2], [-0.2, -1.3], [0.0, 1.4], [0.3, -1.1]])
        lams = []
        for k in range(70):
            ctrl.observe(np.arange(4), peds, t=k * ctrl.dt)
            lams.append(ctrl.lam)
            for j in range(ctrl.substeps):
                v = ctrl.step(robot, t=k * ctrl.dt + j * ctrl.dt_control, goal=goal)
                robot = ctrl.dynamics.step(robot, v, ctrl.dt_control)
            turn = rng.normal(0, 0.4, 4)  # pedestrians turn: a late forecast errs
            c, s = np.cos(turn), np.sin(turn)
            vel = np.stack([c * vel[:, 0] - s * vel[:, 1], s * vel[:, 0] + c * vel[:, 1]], 1)
            peds = peds + vel * ctrl.dt
        ctrl.observe(np.arange(4), peds, t=70 * ctrl.dt)
        ctrl.finish()
        return float(np.mean(lams))

    nominal, late = run(0.0), run(0.5)
    assert late < nominal - 0.1


def test_per_pedestrian_losses_move_only_the_badly_forecast_pedestrian():
    """Two pedestrians near the robot, one forecast exactly and one stale (predicted to
    stay while it walks 1 m closer): only the stale one misses its margin, and with one
    pedestrian the per-pedestrian loss is the scalar loss at every lambda."""
    true = np.array([[[1.5, 0.0], [1.5, 0.0]], [[0.0, 2.5], [0.0, 1.5]]])
    pred = np.array([[[1.5, 0.0], [1.5, 0.0]], [[0.0, 2.5], [0.0, 2.5]]])
    x = np.zeros((SUB, 2))
    rec, truth = interval(true, pred, x)
    loss = AgentMarginMiscoverageLoss(margin=0.25, d_safe=3.0)
    nearest = MarginMiscoverageLoss(margin=0.25, d_safe=3.0)
    keys, top = agent_clearance_errors(rec, truth, 3.0)
    assert keys.tolist() == [0, 1]
    assert top[0] == 0.0 and math.isclose(top[1], 0.75)  # 1 m late by the last instant (3/4)
    comp = loss.components(rec, truth, np.array([0.0, 0.0]))
    assert comp.values.tolist() == [0.0, 1.0]
    # pedestrian 1 covered once its own margin exceeds its error: lambda_1 <= -0.5
    assert loss.components(rec, truth, np.array([0.0, -0.5])).values.tolist() == [0.0, 0.0]
    assert comp.at is not None and comp.at(1, -0.49) == 1.0 and comp.at(1, -0.5) == 0.0
    # margin_miscoverage scores min-pred minus min-true: pedestrian 0 (nearest both ways)
    # hides pedestrian 1's error there; the per-pedestrian loss is the largest term
    assert nearest(rec, truth, 0.0) == 0.0
    assert loss(rec, truth, 0.0) == 1.0 == loss(rec, truth, np.array([0.0, 0.0]))
    for j in (0, 1):
        one, one_truth = interval(true[j : j + 1], pred[j : j + 1], x)
        for lam in (-1.0, -0.5, -0.49, 0.0, 0.3):
            assert loss.components(one, one_truth, np.array([lam])).values[0] == nearest(
                one, one_truth, lam
            )


def test_per_pedestrian_lambda_of_the_wrong_shape_is_a_one_line_error():
    rec, truth = MarginMiscoverageLoss._unit_test_inputs()[0]
    with pytest.raises(ValueError, match="lambda per agent has shape") as err:
        AgentMarginMiscoverageLoss().components(rec, truth, np.zeros(rec.ids.size + 1))
    assert "\n" not in str(err.value)
