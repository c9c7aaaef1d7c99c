"""Update rules, generic losses and the rule-aware guarantee monitor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.core import registry
from conformal_control.core.losses import FunctionLoss, LossRangeError, MiscoverageLoss, wrap_loss
from conformal_control.core.monitor import GuaranteeMonitor
from conformal_control.core.update_rules import (
    ACIRule,
    DecayingEtaRule,
    DtACIRule,
    FixedEtaRule,
    PIDRule,
)
from conformal_control.families.cbf.controller import CBFIntervalRecord
from conformal_control.families.cbf.loss import CBFTruth
from conformal_control.families.cbf.safety_losses import CollisionLoss, DistanceShortfallLoss
from conformal_control.families.domains.factory import run_factory

RULES = ["fixed_eta", "decaying_eta", "aci", "dtaci", "pid"]
LOSSES = [
    "cbf_gap",
    "collision",
    "distance_shortfall",
    "miscoverage",
    "function",
    "defect_fraction",
]


def test_all_rules_and_losses_are_registered() -> None:
    assert set(RULES) <= set(registry.names("rule"))
    assert set(LOSSES) <= set(registry.names("loss"))
    for name in RULES:
        rule = registry.create("rule", name)
        assert math.isfinite(rule.reset())
        assert rule.capabilities.guarantee in ("identity", "step_identity", "long_run", "none")


@pytest.mark.parametrize("name", RULES)
def test_sign_convention_higher_loss_lower_lambda(name: str) -> None:
    """Same history, then one more loss: the larger loss never gives a larger lambda."""
    rng = np.random.default_rng(1)
    history = rng.uniform(0, 1, size=20)
    outs = []
    for last in (0.0, 0.3, 1.0):
        rule = registry.create("rule", name)
        rule.reset()
        for x in history:
            rule.update(x)
        outs.append(rule.update(last))
    assert outs[0] >= outs[1] >= outs[2]
    assert outs[0] > outs[2]


@pytest.mark.parametrize("name", RULES)
def test_every_rule_clips(name: str) -> None:
    rule = registry.create("rule", name, lambda_min=-0.2, lambda_max=0.3)
    rule.reset()
    lams = [rule.update(1.0) for _ in range(300)] + [rule.update(-1.0) for _ in range(300)]
    assert min(lams) >= -0.2 and max(lams) <= 0.3
    assert rule.n_clipped_ > 0


@pytest.mark.parametrize("name", RULES)
def test_rules_reject_non_finite_loss(name: str) -> None:
    rule = registry.create("rule", name)
    rule.reset()
    with pytest.raises(ValueError, match="non-finite loss"):
        rule.update(math.inf)


@pytest.mark.parametrize(
    ("cls", "kwargs"),
    [
        (DecayingEtaRule, {"power": 2.0}),
        (DecayingEtaRule, {"eta": 0.0}),
        (ACIRule, {"alpha": 1.5}),
        (DtACIRule, {"gammas": ()}),
        (DtACIRule, {"sigma": 1.0}),
        (PIDRule, {"C_sat": 0.0}),
        (PIDRule, {"max_arg": 2.0}),
    ],
)
def test_rules_reject_nonsense(cls: type, kwargs: dict) -> None:
    with pytest.raises(ValueError):
        cls(**kwargs).reset()


def test_decaying_step_identity_and_bound() -> None:
    rng = np.random.default_rng(0)
    rule = DecayingEtaRule(epsilon=0.1, eta=2.0, power=0.5, lambda_init=0.3)
    lam1 = rule.reset()
    losses = rng.uniform(-0.5, 0.5, 500)
    lams, etas = [lam1], []
    for x in losses:
        lams.append(rule.update(x))
        etas.append(rule.last_step_)
    assert etas[0] == 2.0 and etas[-1] < etas[0]
    lhs = math.fsum(e * (0.1 - x) for e, x in zip(etas, losses, strict=True))
    assert abs(lhs - (lams[-1] - lam1)) < 1e-9
    bound = rule.long_run_bound(len(losses), lams)
    assert abs(losses.mean() - 0.1) <= bound


def test_pid_without_integrator_is_the_fixed_rule() -> None:
    rng = np.random.default_rng(2)
    a, b = PIDRule(epsilon=0.1, eta=0.3, K_I=0.0), FixedEtaRule(epsilon=0.1, eta=0.3)
    a.reset(), b.reset()
    for x in rng.uniform(-0.5, 0.5, 100):
        assert a.update(x) == pytest.approx(b.update(x), abs=1e-12)


def test_pid_integrator_saturates_and_scorecaster_adds() -> None:
    rule = PIDRule(epsilon=0.0, eta=0.0, K_I=1.0, C_sat=0.1)
    rule.reset()
    for _ in range(20):
        lam = rule.update(0.5)
    assert rule.n_saturated_ > 0
    assert lam == pytest.approx(-math.tan(rule.max_arg))
    shifted = PIDRule(epsilon=0.0, eta=0.0, K_I=1.0, C_sat=0.1, scorecaster=lambda lo, la: 0.25)
    shifted.reset()
    for _ in range(20):
        lam2 = shifted.update(0.5)
    assert lam2 == pytest.approx(lam + 0.25)


def test_dtaci_uses_counterfactual_losses_in_the_loop() -> None:
    rule = DtACIRule(epsilon=0.05, gammas=(0.01, 0.05, 0.2), lambda_init=0.1)
    _, fig = run_factory(rule, T=200, seed=3)
    assert rule.n_counterfactual_ == 200
    assert abs(fig["l_avg"] - 0.05) < 0.03
    assert np.isclose(rule.weights_.sum(), 1.0) and np.all(rule.weights_ > 0)


def test_aci_epsilon_is_alpha_and_bound() -> None:
    rule = ACIRule(alpha=0.2, gamma=0.05)
    assert rule.epsilon == 0.2 and rule.reset() == 0.2
    rng = np.random.default_rng(0)
    errs = (rng.uniform(size=400) < 0.5).astype(float)
    lams = [rule.value] + [rule.update(e) for e in errs]
    assert abs(errs.mean() - 0.2) > rule.long_run_bound(400, lams) - 1  # defined & finite
    assert rule.long_run_bound(400, lams) == pytest.approx((0.8 + 0.05) / (0.05 * 400))


# -- monitor -----------------------------------------------------------------------------
def test_monitor_on_factory_theorem2_holds_and_reported() -> None:
    result, fig = run_factory(FixedEtaRule(epsilon=0.05, eta=0.1, lambda_init=0.1), seed=0)
    assert fig["guarantee"] == "identity"
    assert fig["identity_residual"] < 1e-12
    assert fig["theorem2_bound"] == pytest.approx(0.05 + (0.1 - 0.0 + 0.1) / (0.1 * 500))
    assert fig["theorem2_holds"] is True and fig["theorem2_assumption"] is True
    ra = result.monitor.running_average()
    assert ra.shape == (500,) and ra[-1] == pytest.approx(fig["l_avg"])
    assert all(iv.l_avg is not None for iv in result.intervals)


def test_monitor_flags_a_violated_bound_and_assumption() -> None:
    mon = GuaranteeMonitor(epsilon=0.0, lambda_1=-5.0, eta=1.0, lambda_safe=0.0)
    for _ in range(3):
        mon.observe(0.4, 0.0)
        mon.set_lambda_next(0.0)
    assert mon.bound_assumption is False  # lambda_1 < lambda_safe - eta
    assert mon.bound_holds is False  # 0.4 > 0 + (-5 + 1)/3


def test_monitor_residual_nonzero_when_clipped() -> None:
    _, fig = run_factory(
        FixedEtaRule(epsilon=0.05, eta=0.1, lambda_init=0.06, lambda_max=0.065), seed=0
    )
    assert fig["n_lambda_clipped"] > 0
    assert fig["identity_residual"] > 1e-6


# -- losses ------------------------------------------------------------------------------
def test_wrap_loss_checks_range() -> None:
    loss = wrap_loss(lambda rec, y, lam: rec - y + lam, bounds=(0, 1), name="diff")
    assert loss(0.5, 0.25, 0.0) == 0.25
    assert loss.get_params()["bounds"] == (0, 1)
    with pytest.raises(LossRangeError, match=r"'diff' returned 2.0 .*declared range \[0.0, 1.0\]"):
        loss(2.0, 0.0, 0.0)
    with pytest.raises(LossRangeError, match="not a number"):
        wrap_loss(lambda *a: "x", bounds=(0, 1))(0, 0, 0)
    with pytest.raises(LossRangeError):
        wrap_loss(lambda *a: math.nan, bounds=(0, 1))(0, 0, 0)
    with pytest.raises(ValueError, match="lo < hi"):
        wrap_loss(lambda *a: 0.0, bounds=(1, 0))
    assert wrap_loss(lambda *a: None, bounds=(0, 1))(0, 0, 0) is None
    assert FunctionLoss(lambda r, t, lam: 0.0)(0.0, 0.0, 0.0) == 0.0
    with pytest.raises(ValueError, match="needs fn="):
        FunctionLoss()(0.0, 0.0, 0.0)


def test_miscoverage_loss() -> None:
    class Rec:
        def covers(self, truth, lam):
            return abs(truth) <= 1 - lam

    loss = MiscoverageLoss()
    assert loss(Rec(), 0.5, 0.0) == 0.0 and loss(Rec(), 0.5, 0.9) == 1.0
    assert loss(Rec(), None, 0.0) is None
    with pytest.raises(TypeError, match="covers"):
        loss(object(), 0.5, 0.0)


def _record(ego_x: float) -> tuple[CBFIntervalRecord, CBFTruth]:
    s = 4
    x_ego = np.column_stack([np.full(s, ego_x), np.zeros(s)])
    rec = CBFIntervalRecord(
        ids=np.array([1]),
        x_ego=x_ego,
        v_ego=np.zeros((s, 2)),
        x_pred=np.zeros((s, 1, 2)),
        v_pred=np.zeros((s, 1, 2)),
        lam_applied=np.zeros(s),
    )
    samples = np.zeros((1, 3, 2))  # agent standing at the origin
    return rec, CBFTruth(samples=samples, dt=0.1, substeps=2)


def test_safety_losses() -> None:
    coll, short = CollisionLoss(d_c=1.0), DistanceShortfallLoss(d_safe=2.0, d_c=1.0)
    rec, truth = _record(0.5)
    assert coll(rec, truth, 0.0) == 1.0 and short(rec, truth, 0.0) == 1.0
    rec, truth = _record(1.5)
    assert coll(rec, truth, 0.0) == 0.0 and short(rec, truth, 0.0) == pytest.approx(0.5)
    assert coll.diagnostics(rec, truth, 0.0)["d_min"] == pytest.approx(1.5)
    rec, truth = _record(3.0)
    assert short(rec, truth, 0.0) == 0.0
    truth.samples[:] = np.nan
    assert coll(rec, truth, 0.0) is None and short(rec, truth, 0.0) is None
    with pytest.raises(ValueError, match="d_c < d_safe"):
        DistanceShortfallLoss(d_safe=1.0, d_c=1.0)(rec, truth, 0.0)


def test_an_initial_lambda_outside_the_bounds_is_an_error_not_a_silent_clip() -> None:
    # clipped silently, lambda_init = -1.5 with lambda_min = -1.333 ran at -1.333 and no
    # counter said so (a fixed lambda below the CBF's default floor ran at the floor)
    with pytest.raises(ValueError, match=r"initial lambda \(-1.5\) lies outside"):
        FixedEtaRule(epsilon=0.05, eta=0.0, lambda_init=-1.5, lambda_min=-1.3333).reset()
    with pytest.raises(ValueError, match=r"initial lambda \(0.1\) lies outside"):
        FixedEtaRule(epsilon=0.05, eta=0.1, lambda_init=0.1, lambda_max=0.065).reset()
    assert (
        FixedEtaRule(epsilon=0.05, eta=0.0, lambda_init=-1.3333, lambda_min=-1.3333).reset()
        == -1.3333
    )
