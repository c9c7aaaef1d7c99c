"""Property-based tests (hypothesis) of the update rules' guarantees.

* fixed step: the identity mean(l) = eps + (lambda_1 - lambda_{K+1})/(eta K) holds for any
  loss sequence in the declared range (to floating-point accuracy), and the decaying
  step's weighted identity likewise;
* Theorem 2: against an adversary that respects the eventually-safe assumption, the
  average loss never exceeds eps + (lambda_1 - lambda_safe + eta)/(eta K), at every K;
* ACI-type rules (ACI, DtACI, PID) reach the target long-run miscoverage on i.i.d. and on
  shifting score sequences, within their documented tolerance (ACI and PID: their
  long-run bound; DtACI: ``DtACIRule.EMPIRICAL_TOLERANCE``).
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conformal_control.core.monitor import GuaranteeMonitor
from conformal_control.core.update_rules import (
    ACIRule,
    DecayingEtaRule,
    DtACIRule,
    FixedEtaRule,
    PIDRule,
)
from conformal_control.families.domains.intervals import _Step, run_intervals

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
losses_in_range = st.lists(
    st.floats(-0.5, 0.5, exclude_min=True, exclude_max=True), min_size=1, max_size=300
)


@SETTINGS
@given(
    losses=losses_in_range,
    epsilon=st.floats(-0.45, 0.45),
    eta=st.floats(1e-3, 100.0),
    lambda_1=st.floats(-100.0, 100.0),
)
def test_fixed_eta_identity_for_any_losses(losses, epsilon, eta, lambda_1) -> None:
    rule = FixedEtaRule(epsilon=epsilon, eta=eta, lambda_init=lambda_1)
    mon = GuaranteeMonitor(epsilon=epsilon, lambda_1=rule.reset(), eta=eta, rule=rule)
    lam_max = abs(lambda_1)
    for x in losses:
        mon.observe(x, rule.value)
        lam = rule.update(x)
        mon.set_lambda_next(lam, rule.last_step_)
        lam_max = max(lam_max, abs(lam))
    rhs = epsilon + (lambda_1 - lam) / (eta * len(losses))
    tol = 1e-12 * (1.0 + lam_max / eta)
    assert abs(math.fsum(losses) / len(losses) - rhs) <= tol
    assert mon.identity_residual <= tol


@SETTINGS
@given(
    losses=losses_in_range,
    eta=st.floats(1e-2, 10.0),
    power=st.floats(0.0, 1.0),
    offset=st.floats(0.5, 50.0),
)
def test_decaying_step_identity_and_long_run_bound(losses, eta, power, offset) -> None:
    rule = DecayingEtaRule(epsilon=0.0, eta=eta, power=power, offset=offset)
    lams = [rule.reset()]
    acc = []
    for x in losses:
        acc.append(rule.step_size(rule.n_updates_ + 1) * (0.0 - x))
        lams.append(rule.update(x))
    scale = 1.0 + max(abs(v) for v in lams)
    assert abs(math.fsum(acc) - (lams[-1] - lams[0])) <= 1e-12 * scale * len(losses)
    bound = rule.long_run_bound(len(losses), lams)
    assert abs(np.mean(losses)) <= bound + 1e-12 * scale / rule.step_size(len(losses))


@SETTINGS
@given(
    raw=st.lists(st.floats(-0.499, 0.499), min_size=1, max_size=400),
    epsilon=st.floats(-0.4, 0.4),
    safety_gap=st.floats(0.0, 0.09),
    eta=st.floats(1e-2, 10.0),
    lambda_safe=st.floats(-5.0, 5.0),
    start=st.floats(-1.0, 10.0),
)
def test_theorem2_bound_against_eventually_safe_adversary(
    raw, epsilon, safety_gap, eta, lambda_safe, start
) -> None:
    """The adversary picks any loss, except that lambda_k <= lambda_safe forces
    l_k <= eps_safe = eps - gap (the eventually-safe assumption)."""
    eps_safe = epsilon - safety_gap
    lambda_1 = lambda_safe - eta + start * eta  # start >= -1 ... lambda_1 >= lambda_safe - 2 eta
    lambda_1 = max(lambda_1, lambda_safe - eta)  # the theorem's assumption
    rule = FixedEtaRule(epsilon=epsilon, eta=eta, lambda_init=lambda_1)
    mon = GuaranteeMonitor(
        epsilon=epsilon, lambda_1=rule.reset(), eta=eta, lambda_safe=lambda_safe, rule=rule
    )
    for x in raw:
        lam = rule.value
        loss = min(x, eps_safe) if lam <= lambda_safe else x
        mon.observe(loss, lam)
        mon.set_lambda_next(rule.update(loss), rule.last_step_)
        assert lam >= lambda_safe - eta - 1e-9  # the invariant behind the theorem
        assert mon.bound_assumption is True
        assert mon.average <= mon.bound + 1e-9 * (1 + abs(lambda_1) / eta)


# -- long-run miscoverage of ACI-type rules ----------------------------------------------
def _series(seed: int, kind: str, n: int) -> list[_Step]:
    """Scores |y - forecast| as 1-D steps through the real interval domain (the predictor
    sees one sample and predicts standing still, so the score is |target|)."""
    rng = np.random.default_rng(seed)
    scores = np.abs(rng.standard_normal(n))
    if kind == "shift":
        scores *= np.where(np.arange(n) < n // 2, 1.0, 4.0)
    elif kind == "drift":
        scores *= np.linspace(0.5, 3.0, n)
    elif kind == "heavy":
        scores = np.abs(rng.standard_cauchy(n))
    return [_Step(i, 0, np.zeros((1, 2)), np.array([s, 0.0])) for i, s in enumerate(scores)]


KINDS = st.sampled_from(["iid", "shift", "drift", "heavy"])
ALPHA = st.sampled_from([0.05, 0.1, 0.2])


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), kind=KINDS, alpha=ALPHA, gamma=st.floats(0.01, 0.1))
def test_aci_long_run_miscoverage(seed, kind, alpha, gamma) -> None:
    _, fig = run_intervals(ACIRule(alpha=alpha, gamma=gamma), _series(seed, kind, 800), window=100)
    assert fig["long_run_holds"] is True
    assert abs(fig["miscoverage"] - alpha) <= fig["long_run_bound"]


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), kind=KINDS, alpha=ALPHA)
def test_pid_long_run_miscoverage(seed, kind, alpha) -> None:
    rule = PIDRule(epsilon=alpha, eta=0.05, K_I=0.05, C_sat=1.0, lambda_init=-1.0)
    _, fig = run_intervals(rule, _series(seed, kind, 800), window=100, parametrisation="radius")
    assert abs(fig["miscoverage"] - alpha) <= fig["long_run_bound"]


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000), kind=KINDS, alpha=ALPHA)
def test_dtaci_long_run_miscoverage(seed, kind, alpha) -> None:
    rule = DtACIRule(epsilon=alpha, gammas=(0.005, 0.02, 0.08), n_grid=4)
    _, fig = run_intervals(rule, _series(seed, kind, 1000), window=100)
    assert abs(fig["miscoverage"] - alpha) <= DtACIRule.EMPIRICAL_TOLERANCE
