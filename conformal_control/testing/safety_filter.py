"""Contract checks for :class:`~conformal_control.families.cbf.roles.SafetyFilter` plugins.

Constraints are ``A @ u + b + lam >= 0`` row-wise. Every check recomputes the residuals of
the returned decision itself instead of trusting the filter's status.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..families.cbf.roles import Fallback, FilterResult, SafetyFilter
from ._core import CheckList, ContractError, assert_unchanged, clone, expect, plugin_label, snapshot
from .common import (
    check_capabilities,
    check_docstring_parameters,
    check_get_params_round_trip,
    check_no_mutable_defaults,
    check_pickle_round_trip,
    check_repr,
    sample_behaviour,
)

__all__ = [
    "STATUSES",
    "check_fallback",
    "check_fallback_decision",
    "check_safety_filter",
    "check_safety_filter_deterministic",
    "check_safety_filter_feasible_satisfied",
    "check_safety_filter_infeasible_reported",
    "check_safety_filter_keeps_safe_nominal",
    "check_safety_filter_minimal",
    "check_safety_filter_no_mutation",
    "check_safety_filter_nonfinite_input",
    "check_safety_filter_output",
    "check_safety_filter_stats",
    "feasible_problems",
]

STATUSES = ("optimal", "unconstrained", "fallback")
TOL = 1e-6


def feasible_problems(
    n: int = 20, seed: int = 0
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, float]]:
    """``(nominal, A, b, lam)`` problems where u = 0 meets every row with margin >= 0.05.

    Zero velocity is admissible for any speed-bounded filter, so each problem is feasible;
    nominal decisions (up to 1.5 m/s) violate some rows, so the filter has work to do.
    """
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        m = int(rng.integers(1, 6))
        A = rng.normal(0.0, 1.0, size=(m, 2)) * rng.uniform(0.1, 1.0, size=(m, 1))
        lam = float(rng.uniform(-0.5, 0.5))
        b = rng.uniform(0.05, 0.8, size=m) - lam
        ang = rng.uniform(0.0, 2 * np.pi)
        nominal = rng.uniform(0.2, 1.5) * np.array([np.cos(ang), np.sin(ang)])
        if k % 5 == 0:
            nominal = nominal * 0.01
        out.append((nominal, A, b, lam))
    return out


def _solve(f: SafetyFilter, nominal: Any, A: Any, b: Any, lam: float, what: str) -> FilterResult:
    try:
        res = f.solve(nominal, A, b, lam)
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(f)}: expected solve() to handle {what}, got {type(exc).__name__}: {exc}"
        ) from exc
    expect(
        isinstance(res, FilterResult),
        f,
        f"expected solve() to return a FilterResult, got {type(res).__name__}",
    )
    u = np.asarray(res.decision)
    expect(
        u.shape == np.shape(nominal) and np.issubdtype(u.dtype, np.floating),
        f,
        f"expected a float decision of the nominal's shape {np.shape(nominal)} ({what}), got "
        f"shape {u.shape} dtype {u.dtype}",
    )
    expect(np.isfinite(u).all(), f, f"expected a finite decision ({what}), got {u.tolist()}")
    expect(
        res.status in STATUSES,
        f,
        f"expected status in {STATUSES} ({what}), got {res.status!r}",
    )
    return res


def _fresh(f: SafetyFilter) -> SafetyFilter:
    g: SafetyFilter = clone(f)
    g.reset()
    return g


def _residual(u: np.ndarray, A: np.ndarray, b: np.ndarray, lam: float) -> np.ndarray:
    r: np.ndarray = np.asarray(A) @ np.asarray(u, dtype=float) + b + lam
    return r


def _check_satisfied(
    f: SafetyFilter, res: FilterResult, A: np.ndarray, b: np.ndarray, lam: float, what: str
) -> None:
    """The returned decision satisfies the constraints at the lambda the result claims."""
    if res.status in ("optimal", "unconstrained"):
        expect(
            res.lambda_applied == lam,
            f,
            f"expected lambda_applied == requested lambda {lam:g} with status {res.status!r} "
            f"({what}), got {res.lambda_applied!r}",
        )
        r = _residual(res.decision, A, b, lam)
        expect(
            r.size == 0 or r.min() >= -TOL,
            f,
            f"expected status {res.status!r} to mean A u + b + lambda >= 0 ({what}); "
            f"recomputed residuals {np.round(r, 9).tolist()} for u = "
            f"{np.asarray(res.decision).tolist()}",
        )
        return
    if res.row_lambda is not None:
        rl = np.asarray(res.row_lambda, dtype=float)
        expect(
            rl.shape == (np.shape(b)[0],) and bool(np.all(rl >= lam)),
            f,
            f"expected row_lambda of shape ({np.shape(b)[0]},), never below the requested "
            f"lambda {lam:g} ({what}), got {rl.tolist()}",
        )
        r = np.asarray(A) @ np.asarray(res.decision, dtype=float) + b + rl
        expect(
            r.size == 0 or r.min() >= -TOL * max(1.0, float(np.abs(rl).max())),
            f,
            f"expected the fallback decision to satisfy each row at its row_lambda ({what}); "
            f"recomputed residuals {np.round(r, 9).tolist()}",
        )
    lam_used = res.lambda_applied
    if lam_used is None or not math.isfinite(lam_used):
        expect(
            bool(res.fallback),
            f,
            f"expected a fallback without a valid lambda to name itself in FilterResult.fallback "
            f"({what}), got {res.fallback!r}",
        )
        return
    expect(
        lam_used >= lam,
        f,
        f"expected a fallback to loosen (raise) lambda, requested {lam:g}, got {lam_used:g}",
    )
    r = _residual(res.decision, A, b, lam_used)
    expect(
        r.size == 0 or r.min() >= -TOL * max(1.0, abs(lam_used)),
        f,
        f"expected the fallback decision to satisfy the constraints at lambda_applied="
        f"{lam_used:g} ({what}); recomputed residuals {np.round(r, 9).tolist()}",
    )


# ---------------------------------------------------------------------------- checks
def check_safety_filter_output(safety_filter: SafetyFilter) -> None:
    """Decision of the nominal's shape, finite floats; a known status; no constraint = no change
    for a slow nominal."""
    f = _fresh(safety_filter)
    nominal = np.array([0.01, -0.02])
    res = _solve(f, nominal, np.zeros((0, 2)), np.zeros(0), 0.0, "no constraint")
    expect(
        res.status in ("optimal", "unconstrained"),
        f,
        f"expected status 'optimal' or 'unconstrained' without constraints, got {res.status!r}",
    )
    expect(
        np.allclose(res.decision, nominal, atol=1e-6),
        f,
        f"expected a 0.02 m/s nominal decision without constraints to pass unchanged, got "
        f"{np.asarray(res.decision).tolist()}",
    )


def check_safety_filter_feasible_satisfied(safety_filter: SafetyFilter) -> None:
    """On feasible problems the filter solves without fallback and the decision meets every
    constraint (residuals recomputed here)."""
    f = _fresh(safety_filter)
    for i, (nominal, A, b, lam) in enumerate(feasible_problems()):
        what = f"feasible problem #{i} ({A.shape[0]} rows)"
        res = _solve(f, nominal, A, b, lam, what)
        expect(
            res.status != "fallback",
            f,
            f"expected a feasible problem (u = 0 meets every row with margin) to be solved "
            f"without fallback ({what}), got fallback {res.fallback!r}",
        )
        _check_satisfied(f, res, A, b, lam, what)


def check_safety_filter_keeps_safe_nominal(safety_filter: SafetyFilter) -> None:
    """A slow nominal decision that already meets the constraints is returned unchanged."""
    f = _fresh(safety_filter)
    nominal = np.array([0.1, 0.05])
    A = np.array([[1.0, 0.0], [0.3, -0.8]])
    b = np.array([0.5, 0.5])
    res = _solve(f, nominal, A, b, 0.0, "a nominal decision meeting the constraints")
    expect(
        np.allclose(res.decision, nominal, atol=1e-6),
        f,
        f"expected the safe nominal {nominal.tolist()} unchanged, got "
        f"{np.asarray(res.decision).tolist()}",
    )


def check_safety_filter_minimal(safety_filter: SafetyFilter) -> None:
    """With one violated constraint and slow speeds the decision is the Euclidean projection
    of the nominal onto the half-plane (minimal modification)."""
    f = _fresh(safety_filter)
    rng = np.random.default_rng(7)
    for i in range(5):
        a = rng.normal(size=2)
        a /= np.linalg.norm(a)
        nominal = 0.2 * rng.normal(size=2) / math.sqrt(2)
        viol = rng.uniform(0.01, 0.15)
        lam = 0.1
        b = np.array([-(a @ nominal) - lam - viol])  # residual at nominal = -viol
        A = a[None, :]
        res = _solve(f, nominal, A, b, lam, f"one violated constraint #{i}")
        expected = nominal + viol * a
        expect(
            np.allclose(res.decision, expected, atol=1e-5),
            f,
            f"expected the projection {expected.round(6).tolist()} of nominal "
            f"{nominal.round(6).tolist()} onto the constraint (case {i}), got "
            f"{np.asarray(res.decision).round(6).tolist()} (status {res.status!r})",
        )


def check_safety_filter_infeasible_reported(safety_filter: SafetyFilter) -> None:
    """Contradictory constraints (u_x >= 5 and u_x <= -5) give status 'fallback', and a
    fallback claiming a lambda really satisfies the constraints there."""
    f = _fresh(safety_filter)
    A = np.array([[1.0, 0.0], [-1.0, 0.0]])
    b = np.array([-5.0, -5.0])
    for _ in range(2):  # filters often switch strategy once infeasibility persists
        res = _solve(f, np.array([0.3, 0.1]), A, b, 0.0, "infeasible constraints")
        expect(
            res.status == "fallback",
            f,
            "expected status 'fallback' for constraints no decision meets at the requested "
            f"lambda, got {res.status!r} with u = {np.asarray(res.decision).tolist()}",
        )
        _check_satisfied(f, res, A, b, 0.0, "infeasible constraints")


def check_safety_filter_no_mutation(safety_filter: SafetyFilter) -> None:
    """solve() leaves nominal, A and b untouched."""
    f = _fresh(safety_filter)
    for nominal, A, b, lam in feasible_problems(5, seed=1):
        before = snapshot((nominal, A, b))
        _solve(f, nominal, A, b, lam, "a feasible problem")
        for name, x0, x in zip(("nominal", "A", "b"), before, (nominal, A, b), strict=True):
            assert_unchanged(x0, x, f, name, "solve()")


def check_safety_filter_deterministic(safety_filter: SafetyFilter) -> None:
    """Two fresh copies fed the same problems return the same decisions."""
    outs = []
    for _ in range(2):
        f = _fresh(safety_filter)
        outs.append([_solve(f, *p, "a feasible problem").decision for p in feasible_problems(8)])
    diff = max(float(np.max(np.abs(np.subtract(x, y)))) for x, y in zip(*outs, strict=True))
    expect(
        diff <= 1e-9,
        safety_filter,
        f"expected identical decisions from two fresh copies, got a difference of {diff:.3g}",
    )


def check_safety_filter_nonfinite_input(safety_filter: SafetyFilter) -> None:
    """NaN in the constraints, lambda or nominal gives a clear ValueError, or a fallback with a
    finite decision; never a NaN decision reported as fine."""
    A = np.array([[1.0, 0.0], [0.0, 1.0]])
    b = np.array([0.5, 0.5])
    nominal = np.array([0.3, 0.1])
    bad_A = A.copy()
    bad_A[1, 0] = np.nan
    cases = {
        "NaN in A": (nominal, bad_A, b, 0.0),
        "inf in b": (nominal, A, np.array([0.5, np.inf]), 0.0),
        "NaN lambda": (nominal, A, b, math.nan),
        "NaN nominal": (np.array([np.nan, 0.1]), A, b, 0.0),
    }
    for what, args in cases.items():
        f = _fresh(safety_filter)
        try:
            res = f.solve(*args)
        except ValueError as exc:
            expect(str(exc).strip() != "", f, f"expected a ValueError with a message ({what})")
            continue
        except Exception as exc:
            raise ContractError(
                f"{plugin_label(f)}: expected a ValueError for {what}, got "
                f"{type(exc).__name__}: {exc}"
            ) from exc
        u = np.asarray(getattr(res, "decision", np.nan), dtype=float)
        expect(
            getattr(res, "status", None) == "fallback" and np.isfinite(u).all(),
            f,
            f"expected a ValueError or a fallback with a finite decision for {what}, got "
            f"status {getattr(res, 'status', None)!r}, u = {u.tolist()}",
        )


@sample_behaviour.register(SafetyFilter)
def _behaviour(safety_filter: SafetyFilter) -> list[tuple[np.ndarray, str, float]]:
    """Decisions, statuses and lambdas on 5 feasible problems after ``reset()``."""
    safety_filter.reset()
    out: list[tuple[np.ndarray, str, float]] = []
    for nominal, A, b, lam in feasible_problems(5, seed=7):
        res = safety_filter.solve(nominal, A, b, lam)
        out.append((np.asarray(res.decision), res.status, res.lambda_applied))
    return out


def check_safety_filter_stats(safety_filter: SafetyFilter) -> None:
    """stats() reports n_solves, n_infeasible and n_fallback; an infeasible problem adds one
    to n_infeasible and to n_fallback (and to the fallback's own n_fallback_<name>)."""
    f = _fresh(safety_filter)
    before = f.stats()
    for key in ("n_solves", "n_infeasible", "n_fallback"):
        expect(key in before, f, f"expected stats() to report {key!r}, got {sorted(before)}")
    A = np.array([[1.0, 0.0], [-1.0, 0.0]])
    b = np.array([-5.0, -5.0])
    res = _solve(f, np.array([0.3, 0.1]), A, b, 0.0, "infeasible constraints")
    after = f.stats()
    for key in ("n_infeasible", "n_fallback"):
        expect(
            after[key] == before[key] + 1,
            f,
            f"expected one infeasible decision to add 1 to {key}, got {before[key]} -> "
            f"{after[key]}",
        )
    key = f"n_fallback_{res.fallback}"
    expect(
        after.get(key) == before.get(key, 0) + 1,
        f,
        f"expected the fallback {res.fallback!r} to be counted in {key}, got {after.get(key)!r}",
    )


#: Every safety-filter check, in order.
check_safety_filter = CheckList(
    "safety_filter",
    [
        check_get_params_round_trip,
        check_repr,
        check_capabilities,
        check_safety_filter_output,
        check_safety_filter_feasible_satisfied,
        check_safety_filter_keeps_safe_nominal,
        check_safety_filter_minimal,
        check_safety_filter_infeasible_reported,
        check_safety_filter_no_mutation,
        check_safety_filter_deterministic,
        check_safety_filter_nonfinite_input,
        check_safety_filter_stats,
        check_pickle_round_trip,
        check_docstring_parameters,
        check_no_mutable_defaults,
    ],
)


# ---------------------------------------------------------------------------- fallbacks
def check_fallback_decision(fallback: Fallback) -> None:
    """Run by a safety filter on infeasible problems, the fallback returns status
    'fallback' under its own name, a finite decision, and (when it claims a lambda or
    per-row lambdas) a decision that meets the rows there."""
    from ..families.cbf.filters import Exact2DSafetyFilter, QPSafetyFilter

    problems = [
        (np.array([0.3, 0.1]), np.array([[1.0, 0.0], [-1.0, 0.0]]), np.array([-5.0, -5.0])),
        (  # a far agent below the feasibility floor beside a near one
            np.array([1.5, 0.0]),
            np.array([[0.0, 0.0], [-0.8, 0.1]]),
            np.array([0.5, 0.2]),
        ),
    ]
    for backend in (QPSafetyFilter, Exact2DSafetyFilter):
        f = backend(fallback=clone(fallback))
        f.reset()
        for i, (nominal, A, b) in enumerate(problems):
            lam = -1.0
            what = f"infeasible problem #{i} through {backend.__name__}"
            res = _solve(f, nominal, A, b, lam, what)
            expect(
                res.status == "fallback" and res.fallback == fallback.name,
                fallback,
                f"expected status 'fallback' named {fallback.name!r} ({what}), got "
                f"{res.status!r} named {res.fallback!r}",
            )
            _check_satisfied(f, res, A, b, lam, what)


#: Every fallback check, in order.
check_fallback = CheckList(
    "fallback",
    [check_get_params_round_trip, check_repr, check_capabilities, check_fallback_decision],
)
