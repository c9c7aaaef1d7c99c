"""Safety filters (every registered backend): KKT conditions, fast path, infeasibility
fallbacks, robustness to badly scaled and stale problems."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import linprog, nnls

from conformal_control.core import registry
from conformal_control.families.cbf import QPSafetyFilter, VelocityFilter

#: every registered velocity safety-filter backend (qp, exact2d, and any plugin's)
BACKENDS = [
    cls
    for cls in (registry.get("safety_filter", n) for n in registry.names("safety_filter"))
    if issubclass(cls, VelocityFilter)
]


@pytest.fixture(params=BACKENDS, ids=lambda c: c.__name__)
def backend(request):
    return request.param


@pytest.fixture
def make(backend):
    def build(fallback="lambda_search", v_max: float = 2.0, sides: int = 16) -> VelocityFilter:
        f = backend(v_max=v_max, fallback=fallback, speed_sides=sides)
        f.reset()
        return f

    return build


def test_both_core_backends_are_registered() -> None:
    assert {"QPSafetyFilter", "Exact2DSafetyFilter"} <= {c.__name__ for c in BACKENDS}


def all_rows(f: VelocityFilter, A: np.ndarray, b: np.ndarray, lam: float):
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


def test_kkt_on_random_feasible_problems(make) -> None:
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


def test_speed_bound_is_exact(make) -> None:
    f = make(v_max=1.5)
    res = f.solve(np.array([10.0, 3.0]), np.zeros((0, 2)), np.zeros(0), 0.0)
    assert np.linalg.norm(res.decision) <= 1.5 + 1e-9
    # the projection onto the polygon: on the side facing the nominal
    assert f._S[0] @ res.decision == pytest.approx(f._s[0], abs=1e-9)
    box = make(v_max=1.5, sides=0)
    res = box.solve(np.array([10.0, 3.0]), np.zeros((0, 2)), np.zeros(0), 0.0)
    np.testing.assert_allclose(res.decision, [1.5, 1.5], atol=1e-6)


def test_nominal_returned_without_solving_when_feasible(make) -> None:
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


def test_lambda_search_uses_smallest_feasible_lambda(make) -> None:
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


def test_lambda_search_never_lowers_lambda(make) -> None:
    f = make()
    A, b = infeasible_problem()
    res = f.solve(np.zeros(2), A, b, 10.0)  # feasible at lambda = 10 already
    assert res.status in ("optimal", "unconstrained") and res.lambda_applied == 10.0


def test_brake_and_hold_fallbacks_are_counted(make) -> None:
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


def test_non_finite_inputs_are_rejected_clearly(make) -> None:
    f = make()
    with pytest.raises(ValueError, match="non-finite"):
        f.solve(np.zeros(2), np.array([[np.nan, 0.0]]), np.array([0.0]), 0.0)
    with pytest.raises(ValueError, match="non-finite"):
        f.solve(np.zeros(2), np.zeros((1, 2)), np.array([0.0]), math.inf)


@pytest.mark.parametrize("kwargs", [{"v_max": 0}, {"fallback": "pray"}, {"speed_sides": 2}])
def test_bad_parameters(backend, kwargs: dict) -> None:
    with pytest.raises(ValueError):
        backend(**kwargs).reset()


def test_stats_report_every_counter(make) -> None:
    f = make("brake")
    A, b = infeasible_problem()
    f.solve(np.array([1.0, 0.0]), A, b, 0.0)
    st = f.stats()
    assert st["n_infeasible"] == st["n_fallback"] == st["n_fallback_brake"] == 1
    assert st["n_fallback_lambda_search"] == st["n_fallback_relax"] == 0
    assert st["n_solver_failure"] == 0 and "n_solves" in st


# ------------------------------------------------------------------ robustness (issue 9.4)
def test_zero_rows_after_a_fallback_with_a_fast_reference(make) -> None:
    # failed before: after a fallback the lambda LP was solved for zero rows (unbounded)
    f = make()
    A, b = infeasible_problem()
    assert f.solve(np.array([0.3, 0.1]), A, b, 0.0).status == "fallback"
    res = f.solve(np.array([5.0, 1.0]), np.zeros((0, 2)), np.zeros(0), 0.0)
    fresh = make().solve(np.array([5.0, 1.0]), np.zeros((0, 2)), np.zeros(0), 0.0)
    assert res.status == fresh.status == "optimal"
    np.testing.assert_allclose(res.decision, fresh.decision, atol=1e-12)


@pytest.mark.parametrize(
    "scale_A, scale_b", [(1e10, 1e10), (1e10, 1.0), (1.0, 1e10), (1e-10, 1e-10)]
)
def test_badly_scaled_rows_never_raise(make, scale_A, scale_b) -> None:
    # failed before for ||A|| ~ 1e10 (the lambda LP: max iterations, primal/dual infeasible)
    rng = np.random.default_rng(11)
    f = make()
    for _ in range(40):
        m = int(rng.integers(1, 6))
        A = rng.normal(size=(m, 2)) * scale_A
        b = rng.normal(size=m) * scale_b
        for lam in (0.0, -scale_b):
            res = f.solve(rng.uniform(-3, 3, 2), A, b, lam)
            assert res.status in ("unconstrained", "optimal", "fallback")
            lam_ok = res.lambda_applied
            r = A @ res.decision + b + lam_ok
            # met to round-off of the row's own terms (velocities are O(v_max) = O(1))
            size = np.hypot(A[:, 0], A[:, 1]) * 2.0 + np.abs(b)
            assert np.all(r >= -1e-9 * (1.0 + size + abs(lam_ok))), r
            if res.status == "fallback":
                # the smallest feasible lambda, as an independent LP says (rows normalised)
                lam_star, _ = f.min_lambda(A, b)
                assert lam_ok >= lam_star
    assert f.stats()["n_solver_failure"] == 0


def test_piqp_failure_is_retried_then_answered_exactly(monkeypatch) -> None:
    import piqp

    f = QPSafetyFilter()
    f.reset()
    calls = []
    real = piqp.DenseSolver.solve

    def flaky(self):
        calls.append(1)
        return piqp.PIQP_MAX_ITER_REACHED

    monkeypatch.setattr(piqp.DenseSolver, "solve", flaky)
    A, b = np.array([[-1.0, 0.0]]), np.array([0.5])
    res = f.solve(np.array([1.5, 0.3]), A, b, 0.0)
    assert len(calls) == 2  # warm solver, then a fresh one
    assert res.status == "optimal" and f.n_solver_failure_ == 1
    np.testing.assert_allclose(res.decision, [0.5, 0.3], atol=1e-12)
    monkeypatch.setattr(piqp.DenseSolver, "solve", real)
    res = f.solve(np.array([1.5, 0.3]), A, b, 0.0)
    np.testing.assert_allclose(res.decision, [0.5, 0.3], atol=1e-9)
