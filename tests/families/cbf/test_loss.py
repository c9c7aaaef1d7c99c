"""The gap loss (oracle => s(lambda) exactly), the fixed-eta identity, the monitor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.core.update_rules import FixedEtaRule
from conformal_control.families.cbf import (
    APFBarrier,
    CBFGapLoss,
    CBFIntervalRecord,
    CBFTruth,
    ConformalConstraint,
)
from conformal_control.runs.episode import run_episode


def s(lam: float, c: float) -> float:
    return math.atan(lam / c) / math.pi


@pytest.mark.parametrize("scene_fixture", ["crossing", "nexus4"])
def test_oracle_losses_equal_s_of_lambda(scene_fixture: str, request) -> None:
    scene = request.getfixturevalue(scene_fixture)
    params = {"epsilon": -0.2, "eta": 0.5} if scene.name == "nexus_4" else {"epsilon": -0.2}
    res = run_episode(scene, "oracle", params)
    c = res.config["params"]["si"]["loss_scale"]
    scored = res.loop.updates
    assert len(scored) > 20
    for iv in scored:
        assert iv.loss == pytest.approx(s(iv.lam, c), abs=1e-12)
        assert iv.diagnostics["max_gap"] == pytest.approx(0.0, abs=1e-12)
    # lambda actually moved, so the check is not trivially at lambda = 0
    assert len({round(iv.lam, 9) for iv in scored}) > 5


def test_gap_formula_on_a_hand_built_interval() -> None:
    barrier = APFBarrier(K_rep=1.0, rho0=5.0, d_c=0.5)
    a, c = 2.0, 1.5
    loss = CBFGapLoss(ConformalConstraint(barrier, a=a), scale=c)
    x_ego = np.array([[0.0, 0.0], [0.1, 0.0]])
    v_ego = np.array([[1.0, 0.0], [1.0, 0.2]])
    x_pred = np.array([[[2.0, 0.1]], [[2.0, 0.2]]])
    v_pred = np.array([[[-0.5, 0.0]], [[-0.5, 0.0]]])
    rec = CBFIntervalRecord(
        ids=np.array([7]),
        x_ego=x_ego,
        v_ego=v_ego,
        x_pred=x_pred,
        v_pred=v_pred,
        lam_applied=np.array([0.3, 0.3]),
    )
    # truth: agent moves from (2, 0) at 1 m/s upward; samples dt = 0.2, 2 substeps
    truth = CBFTruth(samples=np.array([[[2.0, 0.0], [2.0, 0.2]]]), dt=0.2, substeps=2)
    lam = 0.3
    expected = []
    for t in range(2):
        xt = np.array([2.0, 0.1 * t])
        vt = np.array([0.0, 1.0])
        h_p, gi_p, gj_p = barrier.evaluate(x_ego[t], x_pred[t, 0])
        h_t, gi_t, gj_t = barrier.evaluate(x_ego[t], xt)
        pred = gi_p @ v_ego[t] + gj_p @ v_pred[t, 0] + a * h_p
        true = gi_t @ v_ego[t] + gj_t @ vt + a * h_t
        expected.append(pred - true)
    np.testing.assert_allclose(loss.gaps(rec, truth)[:, 0], expected, rtol=1e-12)
    assert loss(rec, truth, lam) == pytest.approx(s(max(expected) + lam, c), rel=1e-12)
    assert loss.diagnostics(rec, truth, lam)["n_pairs"] == 2


def test_vanished_agent_is_left_out_and_counted() -> None:
    barrier = APFBarrier(K_rep=1.0, rho0=5.0, d_c=0.5)
    loss = CBFGapLoss(ConformalConstraint(barrier, a=1.0), scale=1.0)
    rec = CBFIntervalRecord(
        ids=np.array([1, 2]),
        x_ego=np.zeros((4, 2)),
        v_ego=np.zeros((4, 2)),
        x_pred=np.full((4, 2, 2), 2.0),
        v_pred=np.zeros((4, 2, 2)),
        lam_applied=np.zeros(4),
    )
    samples = np.full((2, 3, 2), 2.0)
    samples[1, 1:] = np.nan  # agent 2 vanishes after the first sample
    truth = CBFTruth(samples=samples, dt=0.1, substeps=2)
    d = loss.diagnostics(rec, truth, 0.0)
    assert d["n_pairs"] == 4 + 0 and d["n_truth_missing"] == 4
    samples[0, 1:] = np.nan
    assert loss(rec, CBFTruth(samples, 0.1, 2), 0.0) is None  # nothing left to score


def test_fixed_eta_identity_to_1e9() -> None:
    rng = np.random.default_rng(3)
    for eta in (0.01, 1.0, 100.0):
        rule = FixedEtaRule(epsilon=-0.1, eta=eta, lambda_init=0.7)
        lam1 = rule.reset()
        losses = rng.uniform(-0.5, 0.5, size=1000)
        for loss in losses:
            lam = rule.update(loss)
        rhs = -0.1 + (lam1 - lam) / (eta * len(losses))
        assert abs(losses.mean() - rhs) < 1e-9


def test_episode_reports_identity_residual(crossing) -> None:
    res = run_episode(crossing, "constant_velocity", {"epsilon": -0.1, "eta": 3.0})
    m = res.metrics
    assert m["n_updates"] > 10
    assert m["identity_residual"] < 1e-9
    lam1 = 0.0
    losses = res.loop.losses
    rhs = m["epsilon"] + (lam1 - m["lambda_final"]) / (m["eta"] * len(losses))
    assert abs(losses.mean() - rhs) < 1e-9


def test_clipping_breaks_identity_and_is_counted() -> None:
    rule = FixedEtaRule(epsilon=-0.4, eta=1.0, lambda_min=-0.5)
    rule.reset()
    for _ in range(50):
        rule.update(0.4)
    assert rule.value == -0.5 and rule.n_clipped_ > 0


@pytest.mark.parametrize(
    "kwargs",
    [
        {"eta": -1.0},
        {"eta": math.nan},
        {"epsilon": math.inf},
        {"lambda_min": 1.0, "lambda_max": 0.0},
    ],
)
def test_rule_rejects_nonsense(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        FixedEtaRule(**kwargs).reset()


def test_rule_rejects_non_finite_loss() -> None:
    rule = FixedEtaRule()
    rule.reset()
    with pytest.raises(ValueError, match="non-finite loss"):
        rule.update(math.nan)
