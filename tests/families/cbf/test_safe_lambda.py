"""A derived lambda_safe for the CBF gap loss: the bound, its tightness, its errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.families.cbf.barriers import APFBarrier
from conformal_control.families.cbf.constraint import ConformalConstraint
from conformal_control.families.cbf.loss import CBFGapLoss
from conformal_control.families.cbf.safe_lambda import (
    barrier_slope_bound,
    derive_lambda_safe,
    gap_bound,
)


def _unit(angle: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1)


def test_the_slope_bound_is_the_closed_form_far_from_rho0():
    # rho0 -> inf: phi'(rho) = 4 K rho / (2 rho^2 + K)^2, largest at rho^2 = K / 6:
    # M_h = (9 / 4) / sqrt(6 K)
    for K in (0.05, 0.2, 1.0):
        got = barrier_slope_bound(APFBarrier(K_rep=K, rho0=1e7, d_c=1.0))
        assert got == pytest.approx(2.25 / math.sqrt(6.0 * K), rel=1e-6)


def test_the_slope_bound_is_the_barriers_largest_gradient():
    b = APFBarrier(K_rep=0.2, rho0=16.0, d_c=1.0)
    d = np.linspace(0.0, 20.0, 400_001)
    _, grad, _ = b.evaluate(np.stack([d, np.zeros_like(d)], -1), np.zeros(2))
    largest = float(np.hypot(grad[:, 0], grad[:, 1]).max())
    m_h = barrier_slope_bound(b)
    assert largest <= m_h + 1e-12 and largest >= m_h * (1 - 1e-6)


def test_the_gap_bound_holds_for_any_prediction_within_the_speed_bounds():
    rng = np.random.default_rng(0)
    con = ConformalConstraint(APFBarrier(K_rep=0.2, rho0=16.0, d_c=1.0), a=100.0)
    v_i, v = 2.0, 3.0
    g = gap_bound(con, v_i, v)
    n = 200_000
    x_ego = rng.uniform(-5, 5, (n, 2))
    # agents near the robot (where the slope is largest) and anywhere
    x_true = x_ego + _unit(rng.uniform(0, 2 * np.pi, n))[:, :] * rng.uniform(0, 3, (n, 1))
    x_pred = x_ego + _unit(rng.uniform(0, 2 * np.pi, n)) * rng.uniform(0, 20, (n, 1))
    v_ego = _unit(rng.uniform(0, 2 * np.pi, n)) * rng.uniform(0, v_i, (n, 1))
    v_true = _unit(rng.uniform(0, 2 * np.pi, n)) * rng.uniform(0, v, (n, 1))
    v_pred = _unit(rng.uniform(0, 2 * np.pi, n)) * rng.uniform(0, v, (n, 1))
    gap = con.value(x_ego, v_ego, x_pred, v_pred) - con.value(x_ego, v_ego, x_true, v_true)
    assert gap.max() <= g
    assert gap.max() > 0.9 * 100.0  # the a-term dominates: the bound is not loose by much


def test_lambda_safe_is_exact_on_the_constructed_worst_case():
    # no motion: G = a (h_max - h_min) = a; predicted far (h = 1/2), truly overlapping
    # (h = -1/2): the gap is a exactly and the loss at lambda_safe is epsilon exactly
    a, c, eps = 100.0, 30.0, -0.05
    con = ConformalConstraint(APFBarrier(K_rep=0.2, rho0=16.0, d_c=1.0), a=a)
    safe = derive_lambda_safe(con, c, eps, robot_speed=0.0, agent_speed=0.0)
    assert safe.gap_bound == pytest.approx(a, abs=1e-12)
    assert safe.value == pytest.approx(c * math.tan(math.pi * eps) - a, abs=1e-12)
    zero = np.zeros((1, 1, 2))
    far, overlap = np.array([[[20.0, 0.0]]]), np.array([[[0.5, 0.0]]])
    gap = con.value(zero, zero, far, zero) - con.value(zero, zero, overlap, zero)
    assert float(gap[0, 0]) == pytest.approx(a, abs=1e-12)
    loss = CBFGapLoss(con, scale=c)
    assert float(loss.squash(gap[0, 0] + safe.value)) == pytest.approx(eps, abs=1e-12)
    # and one step above lambda_safe the loss exceeds epsilon
    assert float(loss.squash(gap[0, 0] + safe.value + 1e-6)) > eps


def test_the_derived_value_on_the_crossing_suites():
    con = ConformalConstraint(APFBarrier(K_rep=0.2, rho0=16.0, d_c=1.0), a=100.0)
    safe = derive_lambda_safe(con, 30.0, -0.05, robot_speed=2.0)  # pedestrians <= 3 m/s
    m_h = barrier_slope_bound(con.barrier)
    assert safe.gap_bound == pytest.approx(m_h * (2 * 2.0 + 3.0 + 3.0) + 100.0)
    assert safe.value == pytest.approx(30.0 * math.tan(-0.05 * math.pi) - safe.gap_bound)
    assert -126.0 < safe.value < -125.5
    assert "pedestrians true and predicted <= 3 m/s" in safe.source


def test_a_position_error_bound_tightens_the_a_term():
    con = ConformalConstraint(APFBarrier(K_rep=0.2, rho0=16.0, d_c=1.0), a=100.0)
    m_h = barrier_slope_bound(con.barrier)
    g = gap_bound(con, 2.0, 3.0, position_error=0.1)
    assert g == pytest.approx(m_h * 10.0 + 100.0 * m_h * 0.1)
    assert gap_bound(con, 2.0, 3.0, position_error=10.0) == gap_bound(con, 2.0, 3.0)


class _Radial:
    """A barrier that is not the APF one."""

    d_c = 1.0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"robot_speed": -1.0}, "robot_speed must be a finite number of m/s >= 0"),
        ({"robot_speed": 2.0, "agent_speed": math.inf}, "agent_speed must be a finite"),
        ({"robot_speed": 2.0, "agent_speed": True}, "agent_speed must be a number"),
    ],
)
def test_bad_speeds_are_one_line_errors(kwargs, message):
    con = ConformalConstraint(APFBarrier(), a=1.0)
    with pytest.raises(ValueError, match=message):
        gap_bound(con, **kwargs)


def test_other_barriers_and_bad_targets_are_refused():
    with pytest.raises(ValueError, match="no lambda_safe is derived for the barrier _Radial"):
        gap_bound(ConformalConstraint(_Radial(), a=1.0), 1.0)  # type: ignore[arg-type]
    con = ConformalConstraint(APFBarrier(), a=1.0)
    with pytest.raises(ValueError, match="epsilon must lie in"):
        derive_lambda_safe(con, 1.0, 0.5, 1.0)
    with pytest.raises(ValueError, match="loss_scale must be"):
        derive_lambda_safe(con, 0.0, 0.0, 1.0)
