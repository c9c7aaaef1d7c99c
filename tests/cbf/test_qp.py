"""QP safety filter: KKT conditions, fast path, infeasibility fallbacks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import linprog, nnls

from conformal_control.cbf import QPSafetyFilter


def make(fallback: str = "lambda_search", v_max: float = 2.0, sides: int = 16) -> QPSafetyFilter:
    f = QPSafetyFilter(v_max=v_max, fallback=fallback, speed_sides=sides)
    f.reset()
    return f


def all_rows(f: QPSafetyFilter, A: np.ndarray, b: np.ndarray, lam: float):
    """Every constraint as G v <= h (conformal rows then the speed polygon)."""
    return np.vstack([-A, f._S]), np.concatenate([b + lam, f._s])


def assert_kkt(f, nominal, A, b, lam, v, tol=1e-6):
    G, h = all_rows(f, A, b, lam)
    slack = h - G @ v
    assert np.all(slack >= -tol), f"primal infeasible: {slack.min()}"
    active = slack <= 1e-5 * max(1.0, np.abs(h).max())
    grad = 2.0 * (v - nominal)
    if not active.any():
        np.testing.assert_allclose(grad, 0.0, atol=tol)
        return
    # stationarity with non-negative multipliers on the active rows only
    mu, resid = nnls(G[active].T, -grad)
    assert resid <= 1e-5 * max(1.0, np.linalg.norm(grad)), f"stationarity residual {resid}"
    assert np.all(mu >= 0)


def test_kkt_on_random_feasible_problems() -> None:
    rng = np.random.default_rng(0)
    f = make()
    n_constrained = 0
    for _ in range(300):
        m = int(rng.integers(1, 25))
        A = rng.normal(size=(m, 2))
        v_feas = rng.uniform(-1, 1, size=2)
        b = -(A @ v_feas) + rng.uniform(0, 1, size=m)  # v_feas strictly feasible at lam=0
        nominal = rng.uniform(-3, 3, size=2)
        res = f.solve(nominal, A, b, 0.0)
        assert res.status in ("optimal", "unconstrained")
        assert res.lambda_applied == 0.0
        if res.status == "optimal":
            n_constrained += 1
        assert_kkt(f, nominal, A, b, 0.0, res.decision)
    assert n_constrained > 100
    assert f.n_fallback_ == 0


def test_speed_bound_is_exact() -> None:
    f = make(v_max=1.5)
    res = f.solve(np.array([10.0, 3.0]), np.zeros((0, 2)), np.zeros(0), 0.0)
    assert np.linalg.norm(res.decision) <= 1.5 + 1e-9
    box = make(v_max=1.5, sides=0)
    res = box.solve(np.array([10.0, 3.0]), np.zeros((0, 2)), np.zeros(0), 0.0)
    np.testing.assert_allclose(res.decision, [1.5, 1.5], atol=1e-6)


def test_nominal_returned_without_solving_when_feasible() -> None:
    f = make()
    nominal = np.array([0.3, -0.2])
    res = f.solve(nominal, np.array([[1.0, 0.0]]), np.array([1.0]), 0.0)
    assert res.status == "unconstrained"
    np.testing.assert_array_equal(res.decision, nominal)
    assert f.n_solves_ == 0


def infeasible_problem():
    # v_x >= 3 and v_x <= -3 (and a far-agent row 0 v + 0.5 + lam >= 0)
    A = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 0.0]])
    b = np.array([-3.0, -3.0, 0.5])
    return A, b


def test_lambda_search_uses_smallest_feasible_lambda() -> None:
    f = make()
    A, b = infeasible_problem()
    res = f.solve(np.array([1.0, 0.0]), A, b, 0.0)
    assert res.status == "fallback" and res.fallback == "lambda_search"
    assert f.n_infeasible_ == 1 and f.n_fallback_ == 1
    # independent LP (scipy/HiGHS) for min lambda s.t. A v + b + lam >= 0, |v| in polygon
    G = np.vstack([np.hstack([-A, -np.ones((3, 1))]), np.hstack([f._S, np.zeros((16, 1))])])
    h = np.concatenate([b, f._s])
    lp = linprog([0, 0, 1], A_ub=G, b_ub=h, bounds=[(None, None)] * 3, method="highs")
    assert lp.status == 0
    assert res.lambda_applied == pytest.approx(lp.fun, abs=1e-5)
    assert res.lambda_applied >= lp.fun
    assert np.all(A @ res.decision + b + res.lambda_applied >= -1e-7)


def test_lambda_search_never_lowers_lambda() -> None:
    f = make()
    A, b = infeasible_problem()
    res = f.solve(np.zeros(2), A, b, 10.0)  # feasible at lambda = 10 already
    assert res.status in ("optimal", "unconstrained") and res.lambda_applied == 10.0


def test_brake_and_hold_fallbacks_are_counted() -> None:
    A, b = infeasible_problem()
    brake = make("brake")
    res = brake.solve(np.array([1.0, 0.0]), A, b, 0.0)
    assert res.fallback == "brake" and np.all(res.decision == 0) and math.isnan(res.lambda_applied)
    hold = make("hold")
    first = hold.solve(np.array([0.5, 0.5]), np.zeros((0, 2)), np.zeros(0), 0.0).decision
    res = hold.solve(np.array([1.0, 0.0]), A, b, 0.0)
    assert res.fallback == "hold"
    np.testing.assert_array_equal(res.decision, first)
    assert brake.n_fallback_ == 1 and hold.n_fallback_ == 1


def test_non_finite_inputs_are_rejected_clearly() -> None:
    f = make()
    with pytest.raises(ValueError, match="non-finite"):
        f.solve(np.zeros(2), np.array([[np.nan, 0.0]]), np.array([0.0]), 0.0)
    with pytest.raises(ValueError, match="non-finite"):
        f.solve(np.zeros(2), np.zeros((1, 2)), np.array([0.0]), math.inf)


@pytest.mark.parametrize("kwargs", [{"v_max": 0}, {"fallback": "pray"}, {"speed_sides": 2}])
def test_bad_parameters(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        QPSafetyFilter(**kwargs).reset()
