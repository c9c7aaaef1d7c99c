"""Contract checks for :class:`~conformal_control.core.base.UpdateRule` plugins.

Sign convention (whole toolkit, see :class:`~conformal_control.core.update_rules.FixedEtaRule`):
a *smaller* lambda is *more conservative*, so a higher loss must never give a larger lambda.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.base import UpdateRule
from ..core.monitor import AgentMonitor
from ._core import CheckList, ContractError, clone, expect, plugin_label
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
    "check_update_rule",
    "check_update_rule_above_target_not_less_conservative",
    "check_update_rule_deterministic",
    "check_update_rule_monotone",
    "check_update_rule_nan_loss",
    "check_update_rule_params_unchanged",
    "check_update_rule_per_agent",
    "check_update_rule_reset",
    "check_update_rule_value",
    "loss_sequence",
]


def loss_sequence(
    n: int = 40, seed: int = 0, bounds: tuple[float, float] = (-0.5, 0.5)
) -> list[float]:
    """Losses drawn uniformly inside ``bounds`` (1 % margin)."""
    lo, hi = bounds
    pad = 0.01 * (hi - lo)
    losses: list[float] = np.random.default_rng(seed).uniform(lo + pad, hi - pad, size=n).tolist()
    return losses


def _float(rule: UpdateRule, value: object, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (float, int, np.floating, np.integer)):
        raise ContractError(
            f"{plugin_label(rule)}: expected {what} to return a float lambda, "
            f"got {type(value).__name__}"
        )
    expect(math.isfinite(value), rule, f"expected {what} to return a finite lambda, got {value!r}")
    return float(value)


def _run(rule: UpdateRule, losses: list[float]) -> list[float]:
    out = [_float(rule, rule.reset(), "reset()")]
    for i, loss in enumerate(losses):
        try:
            lam = rule.update(loss)
        except Exception as exc:
            raise ContractError(
                f"{plugin_label(rule)}: expected update({loss:.4g}) (step {i}) to work, got "
                f"{type(exc).__name__}: {exc}"
            ) from exc
        out.append(_float(rule, lam, f"update({loss:.4g})"))
    return out


# ---------------------------------------------------------------------------- checks
def check_update_rule_value(rule: UpdateRule) -> None:
    """``reset()`` and ``update()`` return finite floats equal to ``value`` afterwards."""
    r = clone(rule)
    lam = _float(r, r.reset(), "reset()")
    expect(r.value == lam, r, f"expected value == reset() = {lam!r}, got {r.value!r}")
    for loss in loss_sequence(10):
        lam = _float(r, r.update(loss), f"update({loss:.4g})")
        expect(r.value == lam, r, f"expected value == update() = {lam!r}, got {r.value!r}")


def check_update_rule_monotone(rule: UpdateRule) -> None:
    """From the same state, a higher loss never gives a larger (less conservative) lambda."""
    warm = loss_sequence(15, seed=2)
    grid = np.linspace(-0.49, 0.49, 9).tolist()
    for n_warm in (0, 5, 15):
        after = []
        for loss in grid:
            r = clone(rule)
            _run(r, warm[:n_warm])
            after.append(_float(r, r.update(loss), f"update({loss:.4g})"))
        for (l_lo, lam_lo), (l_hi, lam_hi) in zip(
            zip(grid, after, strict=True), zip(grid[1:], after[1:], strict=True), strict=False
        ):
            expect(
                lam_hi <= lam_lo + 1e-12 * max(1.0, abs(lam_lo)),
                r,
                f"expected a higher loss to give a lambda no larger (smaller lambda = more "
                f"conservative); after {n_warm} warm-up updates, loss {l_lo:.3g} -> lambda "
                f"{lam_lo:.6g} but loss {l_hi:.3g} -> lambda {lam_hi:.6g}",
            )


def check_update_rule_above_target_not_less_conservative(rule: UpdateRule) -> None:
    """A loss above the target ``epsilon`` never increases lambda; below never decreases it."""
    r = clone(rule)
    eps = getattr(r, "epsilon", None)
    if eps is None or not math.isfinite(eps):
        return
    lam = _float(r, r.reset(), "reset()")
    for loss in loss_sequence(30, seed=3):
        new = _float(r, r.update(loss), f"update({loss:.4g})")
        tol = 1e-12 * max(1.0, abs(lam))
        if loss > eps:
            expect(
                new <= lam + tol,
                r,
                f"expected a loss {loss:.4g} above epsilon={eps:g} not to increase lambda, got "
                f"{lam:.6g} -> {new:.6g}",
            )
        elif loss < eps:
            expect(
                new >= lam - tol,
                r,
                f"expected a loss {loss:.4g} below epsilon={eps:g} not to decrease lambda, got "
                f"{lam:.6g} -> {new:.6g}",
            )
        lam = new


def check_update_rule_deterministic(rule: UpdateRule) -> None:
    """The same losses give the same lambdas (fresh copies)."""
    losses = loss_sequence(30, seed=4)
    a, b = _run(clone(rule), losses), _run(clone(rule), losses)
    expect(a == b, rule, "expected two fresh copies fed the same losses to give the same lambdas")


def check_update_rule_reset(rule: UpdateRule) -> None:
    """``reset()`` forgets everything: a second run repeats the first exactly."""
    r = clone(rule)
    losses = loss_sequence(30, seed=5)
    a = _run(r, losses)
    b = _run(r, losses)
    expect(a == b, r, f"expected reset() to restart the rule; lambda_1 {a[0]!r} then {b[0]!r}")


def check_update_rule_params_unchanged(rule: UpdateRule) -> None:
    """Running the rule leaves its constructor parameters as given (state goes elsewhere)."""
    r = clone(rule)
    before = dict(r.get_params())
    _run(r, loss_sequence(20, seed=6))
    after = r.get_params()
    changed = {k: (before[k], after.get(k)) for k in before if after.get(k) is not before[k]}
    expect(
        not changed,
        r,
        f"expected reset()/update() not to modify constructor parameters, changed: {changed}",
    )


def check_update_rule_nan_loss(rule: UpdateRule) -> None:
    """A NaN loss gives a clear ValueError, or is skipped with lambda left finite."""
    r = clone(rule)
    r.reset()
    try:
        lam = r.update(math.nan)
    except ValueError as exc:
        expect(str(exc).strip() != "", r, "expected a ValueError with a message")
        return
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(r)}: expected a ValueError for a NaN loss, got "
            f"{type(exc).__name__}: {exc}"
        ) from exc
    expect(
        isinstance(lam, (float, int, np.floating)) and math.isfinite(lam),
        r,
        f"expected a ValueError or a finite lambda after a NaN loss, got {lam!r}",
    )


def check_update_rule_per_agent(rule: UpdateRule) -> None:
    """Run per agent (:class:`~conformal_control.core.monitor.AgentMonitor`: a copy of the rule
    per agent), one agent's lambdas are the rule's own bit for bit, and each of two agents
    fed in turn follows the rule on its own losses only (no agent moves another's
    lambda). A rule without ``lambda_init`` cannot run per agent and is not checked."""
    if "lambda_init" not in rule.get_params():
        return
    losses = loss_sequence(24, seed=8)
    scalar = _run(clone(rule), losses)
    mon = AgentMonitor.for_rule(clone(rule))
    one = [float(mon.values([7])[0])]
    for loss in losses:
        mon.update([7], [loss])
        one.append(float(mon.values([7])[0]))
    expect(
        one == scalar,
        rule,
        f"expected one agent run per agent to follow the rule bit for bit; lambdas {one[:4]} "
        f"... but the rule gives {scalar[:4]} ...",
    )
    mon = AgentMonitor.for_rule(clone(rule))
    mon.values([1, 2])  # both start at the rule's lambda_1
    seen: dict[int, list[float]] = {1: [], 2: []}
    for i, loss in enumerate(losses):
        key = 1 if i % 3 else 2
        mon.update([key], [loss])
        seen[key].append(loss)
    for key, own in seen.items():
        expect(
            float(mon.values([key])[0]) == _run(clone(rule), own)[-1],
            rule,
            f"expected agent {key}'s lambda to be the rule's on its own {len(own)} losses "
            "(two agents fed in turn)",
        )


@sample_behaviour.register(UpdateRule)
def _behaviour(rule: UpdateRule) -> list[float]:
    """lambda_1 and the lambdas after 20 sample losses (for the pickling check)."""
    return _run(rule, loss_sequence(20, seed=7))


#: Every update-rule check, in order.
check_update_rule = CheckList(
    "rule",
    [
        check_get_params_round_trip,
        check_repr,
        check_capabilities,
        check_update_rule_value,
        check_update_rule_monotone,
        check_update_rule_above_target_not_less_conservative,
        check_update_rule_deterministic,
        check_update_rule_reset,
        check_update_rule_params_unchanged,
        check_update_rule_nan_loss,
        check_update_rule_per_agent,
        check_pickle_round_trip,
        check_docstring_parameters,
        check_no_mutable_defaults,
    ],
)
