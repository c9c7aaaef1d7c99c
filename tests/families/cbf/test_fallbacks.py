"""Fallbacks as plugins: by name or instance, counted, and the relax fallback's guarantees."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.optimize import linprog, nnls

from conformal_control.core import registry
from conformal_control.families.cbf import (
    Exact2DSafetyFilter,
    Fallback,
    FilterResult,
    LambdaSearch,
    QPSafetyFilter,
    Relax,
)
from conformal_control.families.cbf.fallbacks import GoalAware
from conformal_control.testing import check_fallback

BACKENDS = [QPSafetyFilter, Exact2DSafetyFilter]


def make(backend, fallback="relax", **kw):
    f = backend(fallback=fallback, **kw)
    f.reset()
    return f


# ------------------------------------------------------------------ plumbing
def test_core_fallbacks_are_registered_and_pass_the_contract_kit() -> None:
    assert {"lambda_search", "relax", "brake", "hold"} <= set(registry.names("fallback"))
    for name in ("lambda_search", "relax", "brake", "hold"):
        check_fallback(registry.get("fallback", name))


@pytest.mark.parametrize("backend", BACKENDS)
def test_fallback_by_instance_and_per_fallback_counts(backend) -> None:
    class Stop(Fallback):
        """Zero velocity under another name."""

        name = "stop"

        def decide(self, step, solver):
            solver.count("stop_called")
            return FilterResult(np.zeros(2), "fallback", math.nan, self.name)

    f = make(backend, Stop())
    A, b = np.array([[1.0, 0.0], [-1.0, 0.0]]), np.array([-5.0, -5.0])
    res = f.solve(np.array([1.0, 0.0]), A, b, 0.0)
    assert res.fallback == "stop" and np.all(res.decision == 0)
    st = f.stats()
    assert st["n_fallback"] == st["n_infeasible"] == st["n_fallback_stop"] == 1
    assert st["n_stop_called"] == 1 and st["n_fallback_lambda_search"] == 0


@pytest.mark.parametrize("backend", BACKENDS)
def test_unknown_fallback_name_is_a_clear_error(backend) -> None:
    with pytest.raises(ValueError, match="lambda_serch"):
        backend(fallback="lambda_serch").reset()


# ------------------------------------------------------------------ relax: exact IIS test
def _infeasible(G: np.ndarray, h: np.ndarray, tol: float = 1e-9) -> bool:
    """Whether at most 3 half-planes ``G v <= h`` have an empty intersection (Farkas:
    some y >= 0 with y G = 0 and y h < 0; in the plane 3 vectors always have such a y)."""
    k = len(h)
    if k == 1:
        return bool(np.linalg.norm(G[0]) <= tol and h[0] < -tol)
    if k == 2:
        if _infeasible(G[:1], h[:1], tol) or _infeasible(G[1:], h[1:], tol):
            return True
        n0, n1 = np.linalg.norm(G[0]), np.linalg.norm(G[1])
        cross = G[0, 0] * G[1, 1] - G[0, 1] * G[1, 0]
        if abs(cross) <= tol * n0 * n1 and G[0] @ G[1] < 0:
            return bool(h[0] / n0 + h[1] / n1 < -tol)
        return False
    for pair in itertools.combinations(range(3), 2):
        if _infeasible(G[list(pair)], h[list(pair)], tol):
            return True

    def cr(i, j):
        return G[i, 0] * G[j, 1] - G[i, 1] * G[j, 0]

    y = np.array([cr(1, 2), cr(2, 0), cr(0, 1)])  # y @ G = 0 identically
    if np.all(y < 0):
        y = -y
    if np.all(y > tol * np.abs(y).max()):
        return bool(y @ h < -tol * np.abs(y).max())
    return False


def in_some_iis(j: int, G: np.ndarray, h: np.ndarray) -> bool:
    """Whether constraint j belongs to an irreducible infeasible subsystem (in the plane
    one has at most 3 members, Helly): some feasible T, |T| <= 2, with {j} + T infeasible."""
    others = [i for i in range(len(h)) if i != j]
    for size in (0, 1, 2):
        for T in itertools.combinations(others, size):
            T = list(T)
            if T and _infeasible(G[T], h[T]):
                continue
            idx = [j, *T]
            if _infeasible(G[idx], h[idx]):
                return True
    return False


def relax_problems(n: int, seed: int):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        m = int(rng.integers(2, 7))
        A = rng.normal(size=(m, 2)) * rng.uniform(0.2, 2.0, size=(m, 1))
        A[rng.uniform(size=m) < 0.2] = 0.0  # far agents: zero gradient
        b = rng.uniform(-3.0, 2.0, size=m)
        nominal = rng.uniform(-2.5, 2.5, size=2)
        yield nominal, A, b


def independent_min_relaxation(f, A: np.ndarray, rhs: np.ndarray, w: np.ndarray) -> float:
    m, ns = A.shape[0], f._S.shape[0]
    A_ub = np.zeros((m + ns, 2 + m))
    A_ub[:m, :2] = -A
    A_ub[:m, 2:] = -np.eye(m)
    A_ub[m:, :2] = f._S
    lp = linprog(
        np.concatenate([[0, 0], w]),
        A_ub=A_ub,
        b_ub=np.concatenate([rhs, f._s]),
        bounds=[(None, None)] * 2 + [(0, None)] * m,
        method="highs-ipm",
    )
    assert lp.status == 0
    return float(lp.fun)


def assert_kkt(f, nominal, A, rhs, v, tol=1e-6):
    G = np.vstack([-A, f._S])
    h = np.concatenate([rhs, f._s])
    slack = h - G @ v
    assert np.all(slack >= -tol), slack.min()
    active = slack <= 1e-6 * max(1.0, np.abs(h).max())
    grad = 2.0 * (v - nominal)
    if not active.any():
        np.testing.assert_allclose(grad, 0.0, atol=tol)
        return
    _, resid = nnls(G[active].T, -grad)
    assert resid <= 1e-5 * max(1.0, np.linalg.norm(grad)), resid


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("weights", ["uniform", "inverse_gradient"])
def test_relax_keeps_every_satisfiable_row_and_is_optimal(backend, weights) -> None:
    f = make(backend, Relax(weights=weights))
    n_relaxed = n_kept = n_fallback = 0
    lam = 0.0
    for nominal, A, b in relax_problems(60, seed=3):
        res = f.solve(nominal, A, b, lam)
        if res.status != "fallback":
            continue
        n_fallback += 1
        assert res.fallback == "relax"
        s = res.row_lambda - lam
        assert np.all(s >= 0.0)
        rhs = b + lam
        # the decision meets every row at its own lambda
        assert np.all(A @ res.decision + rhs + s >= -1e-9)
        # only rows of an infeasible subsystem are relaxed; all others keep s_j = 0 exactly
        G = np.vstack([-A, f._S])
        h = np.concatenate([rhs, f._s])
        for j in range(A.shape[0]):
            if s[j] > 0.0:
                n_relaxed += 1
                assert in_some_iis(j, G, h), (j, A, b, s)
            else:
                n_kept += 1
        # minimal weighted relaxation (independent interior-point LP) ...
        w = Relax(weights=weights).row_weights(A)
        opt = independent_min_relaxation(f, A, rhs, w)
        # (relaxed rows carry the filter's margin on top of the LP's slack)
        pad = f.search_margin(float(s.max()), A, rhs) * float(w[s > 0].sum())
        assert opt - 1e-6 * (1 + opt) <= w @ s <= opt + pad + 1e-6 * (1 + opt)
        # ... then the projection at that relaxation (KKT)
        assert_kkt(f, nominal, A, rhs + s, res.decision)
    assert n_fallback >= 20 and n_relaxed >= 20 and n_kept >= 20
    assert f.stats()["n_fallback_relax"] == n_fallback


@pytest.mark.parametrize("backend", BACKENDS)
def test_relax_relaxes_only_the_far_agents_below_the_floor(backend) -> None:
    # two near agents whose rows are satisfiable together, one far agent (zero gradient,
    # h = h_max) whose row a h_max + lambda >= 0 no velocity meets below the floor
    A = np.array([[-0.9, 0.2], [0.3, -0.7], [0.0, 0.0]])
    b = np.array([0.4, 0.6, 0.5])
    lam = -1.0
    nominal = np.array([1.8, -0.2])
    relax = make(backend, "relax").solve(nominal, A, b, lam)
    search = make(backend, "lambda_search").solve(nominal, A, b, lam)
    np.testing.assert_array_equal(relax.row_lambda[:2], [lam, lam])
    assert relax.row_lambda[2] == pytest.approx(-0.5, abs=1e-6)  # + the solver margin
    assert np.all(A[:2] @ relax.decision + b[:2] + lam >= -1e-12)
    # lambda_search loosens every row to the far agent's floor instead
    assert search.lambda_applied == pytest.approx(-0.5, abs=1e-6)
    assert np.any(A[:2] @ search.decision + b[:2] + lam < -1e-3)


def test_relax_parameters_are_validated() -> None:
    with pytest.raises(ValueError, match="weights"):
        Relax(weights="cubic").reset()
    with pytest.raises(ValueError, match="gradient_floor"):
        Relax(gradient_floor=0.0).reset()


@pytest.mark.parametrize("backend", BACKENDS)
def test_lambda_search_instance_equals_name(backend) -> None:
    A, b = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 0.0]]), np.array([-3.0, -3.0, 0.5])
    by_name = make(backend, "lambda_search").solve(np.array([1.0, 0.0]), A, b, 0.0)
    by_obj = make(backend, LambdaSearch()).solve(np.array([1.0, 0.0]), A, b, 0.0)
    np.testing.assert_array_equal(by_name.decision, by_obj.decision)
    assert by_name.lambda_applied == by_obj.lambda_applied


# ------------------------------------------------------------------ goal_aware
def _lp_feasible(A: np.ndarray, rhs: np.ndarray, S: np.ndarray, s: np.ndarray) -> bool:
    """Whether some v meets A v + rhs >= 0 and S v <= s (scipy's LP, a reference)."""
    res = linprog(
        [0.0, 0.0],
        A_ub=np.vstack([-A, S]) if A.size else S,
        b_ub=np.concatenate([rhs, s]) if A.size else s,
        bounds=[(None, None)] * 2,
    )
    return bool(res.status == 0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_goal_aware_meets_the_imminent_rows_and_heads_for_the_goal(backend) -> None:
    from conformal_control.families.cbf import ConformalConstraint
    from conformal_control.families.cbf.barriers import APFBarrier
    from conformal_control.families.cbf.speed import speed_polygon

    con = ConformalConstraint(APFBarrier(K_rep=1.0, rho0=10.0, d_c=1.0), a=10.0)
    S, s, _, _ = speed_polygon(16, 2.0)
    rng = np.random.default_rng(4)
    goal_dir = np.array([1.0, 0.0])
    seen = 0
    for _ in range(60):
        n = int(rng.integers(2, 6))
        ang = rng.uniform(-np.pi, np.pi, n)
        r = rng.uniform(1.1, 4.0, n)
        xp = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
        vp = -xp / r[:, None] * rng.uniform(0.0, 2.0, (n, 1)) + rng.normal(0, 0.3, (n, 2))
        A, b = con.rows(np.zeros(2), xp, vp)
        ttc = con.contact_times(np.zeros(2), xp, vp, 2.0 * goal_dir)
        lam = float(rng.choice([-1.0, -3.0, -6.0]))
        f = make(backend, GoalAware(rest="dropped"))
        res = f.solve_escaping(2.0 * goal_dir, A, b, lam, None, ttc)
        if res.status != "fallback":
            continue
        seen += 1
        assert res.fallback == "goal_aware" and f.stats()["n_fallback_goal_aware"] == 1
        v = res.decision
        order = np.lexsort((b, ttc))
        level = float(res.row_lambda[order[0]])
        assert level >= lam - 1e-12
        # the rows it meets at that level are a prefix of the time-to-contact order ...
        met = A @ v + b + level >= -1e-7
        k = int(np.argmin(met[order])) if not met[order].all() else n
        assert met[order[:k]].all() and k >= 1
        # ... the longest one that can be met (the next row would make it infeasible) ...
        if k < n:
            idx = order[: k + 1]
            assert not _lp_feasible(A[idx], b[idx] + level - 1e-6, S, s)
        # ... and no command meeting it makes more progress toward the goal
        idx = order[:k]
        best = linprog(
            -goal_dir, A_ub=np.vstack([-A[idx], S]), b_ub=np.concatenate([b[idx] + level, s]),
            bounds=[(None, None)] * 2,
        )  # fmt: skip
        assert best.status == 0 and v @ goal_dir >= -best.fun - 1e-6
        assert np.hypot(*v) <= 2.0 + 1e-9
        # rest="relaxed": the same prefix at the same level, the other rows at the
        # smallest common lambda that allows (an LP in (v, t) as the reference)
        g = make(backend, "goal_aware")
        res2 = g.solve_escaping(2.0 * goal_dir, A, b, lam, None, ttc)
        w = res2.decision
        assert (A[idx] @ w + b[idx] + level >= -1e-7).all()
        if k < n:
            rest = order[k:]
            top = float(res2.row_lambda[rest].max())
            lp = linprog(
                [0.0, 0.0, 1.0],
                A_ub=np.vstack(
                    [
                        np.column_stack([-A[idx], np.zeros(k)]),
                        np.column_stack([-A[rest], -np.ones(n - k)]),
                        np.column_stack([S, np.zeros(len(S))]),
                    ]
                ),
                b_ub=np.concatenate([b[idx] + level, b[rest], s]),
                bounds=[(None, None)] * 2 + [(level, None)],
            )
            assert lp.status == 0 and top <= lp.x[2] + 1e-5
    assert seen >= 10


def test_time_to_contact() -> None:
    from conformal_control.families.cbf.constraint import time_to_contact

    x = np.zeros(2)
    xp = np.array([[3.0, 0.0], [3.0, 0.0], [0.5, 0.0], [3.0, 2.0], [-3.0, 0.0]])
    vp = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, 0.0], [-1.0, 0.0], [0.0, 0.0]])
    t = time_to_contact(x, xp, vp, 1.0)
    assert t[0] == pytest.approx(2.0)  # 3 m away at 1 m/s: the 1 m disc in 2 s
    assert t[1] == math.inf and t[2] == 0.0 and t[3] == math.inf and t[4] == math.inf
