"""GuaranteeMonitor: the river-style loop, the identity, and every Theorem-2 verdict.

Each verdict is produced by a loss sequence built for it (fixed step, eta = 1, so the
lambdas can be followed by hand: lambda_{k+1} = lambda_k + epsilon - l_k).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.core.monitor import GuaranteeMonitor
from conformal_control.core.update_rules import DecayingEtaRule, FixedEtaRule


def monitored(losses, *, epsilon=0.0, eta=1.0, lambda_init=0.0, rule_kw=None, **monitor_kw):
    rule = FixedEtaRule(epsilon=epsilon, eta=eta, lambda_init=lambda_init, **(rule_kw or {}))
    monitor = GuaranteeMonitor.for_rule(rule, **monitor_kw)
    for loss in losses:
        monitor.update(loss)
    return monitor


def test_river_style_loop():
    rule = FixedEtaRule(epsilon=0.1, eta=0.5, lambda_init=0.3)
    rule.reset()
    rule.update(0.4)  # a used rule: for_rule resets it
    stream = np.random.default_rng(0).uniform(-0.2, 0.8, size=50)

    monitor = GuaranteeMonitor.for_rule(rule)
    used = []
    for x in stream:  # the five lines: decide with monitor.lam, feed the loss
        used.append(monitor.lam)
        loss = 0.5 if x > monitor.lam else -0.5  # a miss costs, a hit pays
        monitor.update(loss)

    assert used[0] == 0.3 == monitor.lambda_1
    assert monitor.lambdas == used and monitor.n == 50
    assert monitor.lam == rule.value == monitor.lambda_next
    lam = 0.3
    for x, lam_k in zip(stream, used, strict=True):  # the rule's updates, by hand
        assert lam_k == pytest.approx(lam)
        lam += 0.5 * (0.1 - (0.5 if x > lam else -0.5))
    assert monitor.lam == pytest.approx(lam)
    assert monitor.average == pytest.approx(np.mean(monitor.losses))
    assert monitor.etas == [0.5] * 50


def test_update_needs_a_rule():
    monitor = GuaranteeMonitor(epsilon=0.0, lambda_1=0.0, eta=1.0)
    assert monitor.lam == 0.0
    with pytest.raises(RuntimeError, match=r"GuaranteeMonitor\.for_rule"):
        monitor.update(0.1)
    with pytest.raises(RuntimeError, match=r"for_rule"):
        GuaranteeMonitor.for_rule(FixedEtaRule(), learn=False).update(0.1)


def test_identity_residual_is_zero_for_the_fixed_step():
    losses = np.random.default_rng(1).uniform(-0.5, 0.5, size=200)
    monitor = monitored(losses, epsilon=0.05, eta=0.3, lambda_init=1.0)
    assert monitor.kind == "identity"
    assert monitor.identity_residual < 1e-12
    # the identity itself: mean = eps + (lambda_1 - lambda_{K+1}) / (eta K)
    rhs = 0.05 + (1.0 - monitor.lambda_next) / (0.3 * 200)
    assert monitor.average == pytest.approx(rhs, abs=1e-12)
    # clipping breaks it, and the residual says so
    clipped = monitored(losses, epsilon=0.05, eta=0.3, lambda_init=1.0, rule_kw={"lambda_max": 1.2})
    assert clipped.rule.n_clipped_ > 0 and clipped.identity_residual > 1e-3


def test_step_identity_and_long_run_bound_for_a_decaying_step():
    rule = DecayingEtaRule(epsilon=0.1, eta=1.0, power=0.5)
    monitor = GuaranteeMonitor.for_rule(rule, lambda_safe=0.0)
    for loss in np.random.default_rng(2).uniform(-0.5, 0.5, size=300):
        monitor.update(loss)
    assert monitor.kind == "step_identity"
    assert monitor.identity_residual < 1e-12
    assert monitor.long_run_bound is not None and monitor.long_run_holds
    assert monitor.bound is None and monitor.verdict == "not_applicable"  # not a fixed step


def test_verdict_holds():
    # lambda 1 -> 0.6 -> 0.2 -> -0.2 (at or below lambda_safe = 0 from the 4th update on,
    # where every loss is <= epsilon)
    monitor = monitored([0.5, 0.5, 0.5, 0.0, 0.0], epsilon=0.1, lambda_init=1.0, lambda_safe=0.0)
    assert monitor.lambdas == pytest.approx([1.0, 0.6, 0.2, -0.2, -0.1])
    assert monitor.premise_tested == 2 and monitor.premise_violations == 0
    assert monitor.bound == pytest.approx(0.1 + 2.0 / 5)
    assert monitor.average <= monitor.bound
    assert monitor.verdict == "holds"
    assert monitor.summary()["theorem2_holds"] is True


def test_verdict_violated():
    # a loss above epsilon at every lambda: the average stays far above the bound
    monitor = monitored([0.5] * 10, lambda_safe=0.0)
    assert monitor.bound == pytest.approx(0.1)
    assert monitor.average == 0.5
    assert monitor.verdict == "violated"
    assert monitor.summary()["theorem2_bound_met"] is False


def test_verdict_premise_fails():
    # lambda_1 = lambda_safe = 0 and the loss there is 0.2 > epsilon: the given lambda_safe
    # is not safe, although the bound is met
    monitor = monitored([0.2, -0.2], lambda_safe=0.0)
    assert monitor.bound_holds
    assert monitor.premise_violations == 1
    assert monitor.verdict == "premise_fails"
    assert monitor.summary()["theorem2_holds"] is False


def test_verdict_premise_untested():
    # lambda never comes down to lambda_safe: the bound is met but says nothing
    monitor = monitored([0.0] * 6, lambda_init=5.0, lambda_safe=0.0)
    assert monitor.lambdas == [5.0] * 6 and monitor.premise_tested == 0
    assert monitor.bound_holds and monitor.bound_assumption
    assert monitor.verdict == "premise_untested"


def test_premise_proven_makes_the_untested_premise_hold():
    monitor = monitored([0.0] * 6, lambda_init=5.0, lambda_safe=0.0, premise_proven=True)
    assert monitor.premise_tested == 0
    assert monitor.verdict == "holds"
    summary = monitor.summary()
    assert summary["theorem2_holds"] is True and summary["theorem2_premise_tested"] == 0
    # a proof does not excuse a contradiction seen in the data
    contradicted = monitored([0.2, -0.2], lambda_safe=0.0, premise_proven=True)
    assert contradicted.verdict == "premise_fails"


def test_verdict_assumption_fails():
    # lambda_1 = -5 < lambda_safe - eta = -1; the losses (-0.5) never contradict the premise
    monitor = monitored([-0.5] * 10, lambda_init=-5.0, lambda_safe=0.0)
    assert monitor.premise_tested == 10 and monitor.premise_violations == 0
    assert monitor.bound == pytest.approx(-0.4) and monitor.bound_holds
    assert monitor.bound_assumption is False
    assert monitor.verdict == "assumption_fails"
    # a lower clip above lambda_safe - eta breaks it too
    clipped = monitored(
        [0.0, -0.5, 0.5], lambda_safe=0.0, rule_kw={"lambda_min": -0.5}, lambda_init=0.0
    )
    assert clipped.bound_holds and clipped.premise_violations == 0
    assert clipped.verdict == "assumption_fails"


@pytest.mark.parametrize(
    "make",
    [
        pytest.param(lambda: monitored([0.1, 0.2]), id="no lambda_safe"),
        pytest.param(lambda: monitored([], lambda_safe=0.0), id="no loss yet"),
        pytest.param(
            lambda: GuaranteeMonitor.for_rule(FixedEtaRule(), lambda_safe=0.0, learn=False),
            id="lambda not learned",
        ),
        pytest.param(
            lambda: GuaranteeMonitor.for_rule(DecayingEtaRule(), lambda_safe=0.0),
            id="not a fixed step",
        ),
    ],
)
def test_verdict_not_applicable(make):
    monitor = make()
    assert monitor.bound is None
    assert monitor.verdict == "not_applicable"
    assert monitor.summary()["theorem2_holds"] is None


def test_lambda_safe_must_be_finite():
    with pytest.raises(ValueError, match="lambda_safe must be a finite number"):
        GuaranteeMonitor.for_rule(FixedEtaRule(), lambda_safe=math.inf)
    monitor = GuaranteeMonitor.for_rule(FixedEtaRule(), lambda_safe=0.0)
    assert monitor.lambda_safe_source == "given"
