"""The contract kit over every registered plugin, and broken plugins it must reject."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control import registry
from conformal_control.base import Loss, UpdateRule
from conformal_control.cbf import APFBarrier, CBFGapLoss, ConformalConstraint, QPSafetyFilter
from conformal_control.cbf.roles import Barrier, SafetyFilter
from conformal_control.predictors import ConstantVelocityPredictor
from conformal_control.predictors.base import Forecast, Predictor
from conformal_control.testing import (
    ContractError,
    check_barrier,
    check_loss,
    check_plugin,
    check_predictor,
    check_safety_filter,
    check_update_rule,
    checks_for,
    parametrize_with_checks,
    registered_plugins,
    run_checks,
)
from conformal_control.testing.barrier import check_barrier_gradient, check_barrier_nan_propagates
from conformal_control.testing.loss import check_loss_within_bounds
from conformal_control.testing.predictor import (
    check_predictor_batch_consistent,
    check_predictor_deterministic,
    check_predictor_finite_on_clean_input,
    check_predictor_no_mutation,
    check_predictor_output_shape,
)
from conformal_control.testing.safety_filter import (
    check_safety_filter_feasible_satisfied,
    check_safety_filter_infeasible_reported,
)
from conformal_control.testing.update_rule import check_update_rule_monotone
from conformal_control.update_rules import FixedEtaRule


# ------------------------------------------------------------------ every registered plugin
# every plugin of every role: core, plugins/ distributions, installed third-party packages
@parametrize_with_checks([cls for _, _, cls, _ in registered_plugins() if cls is not None])
def test_registered_plugin_contract(plugin, check):
    check(plugin)


def test_every_registered_plugin_is_available():
    # an installed plugin that cannot be imported fails here with its reason (never skipped)
    unavailable = [(r, n, why) for r, n, cls, why in registered_plugins() if cls is None]
    assert not unavailable, unavailable
    roles = {role for role, *_ in registered_plugins()}
    assert {"predictor", "barrier", "safety_filter", "loss", "update_rule", "dynamics"} <= roles


def test_runtime_registered_plugin_is_discovered():
    @registry.register("predictor", "_kit_runtime_cv")
    class RuntimeCV(ConstantVelocityPredictor):
        """Constant velocity registered at runtime."""

    try:
        found = {name: cls for _, name, cls, _ in registered_plugins("predictor")}
        assert found["_kit_runtime_cv"] is RuntimeCV
        assert all(r.passed for r in run_checks(RuntimeCV))
    finally:
        registry.unregister("predictor", "_kit_runtime_cv")


# ------------------------------------------------------------------ broken plugins
class WrongShapePredictor(ConstantVelocityPredictor):
    """Drops the last agent."""

    def predict(self, query):
        fc = super().predict(query)
        return Forecast(fc.positions[:-1], info=fc.info)


class NaNPredictor(ConstantVelocityPredictor):
    """Returns NaN for every agent."""

    def predict(self, query):
        fc = super().predict(query)
        return Forecast(np.full_like(fc.positions, np.nan), info=fc.info)


class MutatingPredictor(ConstantVelocityPredictor):
    """Fills NaN in the caller's history in place."""

    def predict(self, query):
        np.nan_to_num(query.history, copy=False)
        return super().predict(query)


class RandomPredictor(ConstantVelocityPredictor):
    """Adds unseeded noise."""

    def predict(self, query):
        fc = super().predict(query)
        return Forecast(fc.positions + np.random.default_rng().normal(size=fc.positions.shape))


class CrossTalkPredictor(ConstantVelocityPredictor):
    """Uses the batch mean velocity for everyone."""

    def predict(self, query):
        fc = super().predict(query)
        pos = fc.positions - query.current[:, None, :]
        return Forecast(query.current[:, None, :] + pos.mean(axis=0, keepdims=True))


class ConvertingPredictor(ConstantVelocityPredictor):
    """Converts its parameter in __init__ (not stored unchanged)."""

    def __init__(self, window=5):
        self.window = float(window)


class WrongGradientBarrier(APFBarrier):
    """Gradient with a factor 2 error."""

    def evaluate(self, x_ego, x_agent):
        h, ge, ga = super().evaluate(x_ego, x_agent)
        return h, 2.0 * ge, ga


class NaNSwallowingBarrier(APFBarrier):
    """Turns missing positions into a finite barrier value."""

    def evaluate(self, x_ego, x_agent):
        return super().evaluate(x_ego, np.nan_to_num(np.asarray(x_agent, float), nan=100.0))


class OutOfRangeLoss(CBFGapLoss):
    """Forgets to squash: returns the raw gap (unbounded)."""

    def __call__(self, record, truth, lam):
        gap = self.gaps(record, truth)
        if gap.size == 0 or not np.isfinite(gap).any():
            return None
        return float(np.nanmax(gap) + lam)


class NonMonotoneRule(FixedEtaRule):
    """Wrong sign: a higher loss raises lambda (less conservative)."""

    def update(self, loss):
        self.lambda_ = self.lambda_ - self.eta * (self.epsilon - float(loss))
        return self.lambda_


class LyingFilter(QPSafetyFilter):
    """Returns the nominal decision and claims it is optimal."""

    def solve(self, nominal, A, b, lam):
        from conformal_control.cbf.roles import FilterResult

        return FilterResult(np.asarray(nominal, float), "optimal", lam)


def _case_id(x: object) -> str:
    if isinstance(x, str):
        return x[:20].replace(" ", "_")
    return getattr(x, "__name__", type(x).__name__)


@pytest.mark.parametrize(
    ("plugin", "check", "message"),
    [
        (
            WrongShapePredictor(),
            check_predictor_output_shape,
            "expected Forecast.positions of shape (4, 6, 2)",
        ),
        (NaNPredictor(), check_predictor_finite_on_clean_input, "expected finite positions"),
        (MutatingPredictor(), check_predictor_no_mutation, "to leave its input query unchanged"),
        (RandomPredictor(), check_predictor_deterministic, "expected identical predictions"),
        (
            CrossTalkPredictor(),
            check_predictor_batch_consistent,
            "not to depend on the other agents",
        ),
        (ConvertingPredictor(window=3), check_predictor, "to store parameter 'window' unchanged"),
        (
            WrongGradientBarrier(),
            check_barrier_gradient,
            "expected dh_dego to match central finite",
        ),
        (NaNSwallowingBarrier(), check_barrier_nan_propagates, "expected h = NaN where"),
        (
            OutOfRangeLoss(ConformalConstraint(APFBarrier())),
            check_loss_within_bounds,
            "within its declared bounds",
        ),
        (
            NonMonotoneRule(eta=0.5),
            check_update_rule_monotone,
            "expected a higher loss to give a lambda no larger",
        ),
        (LyingFilter(), check_safety_filter_feasible_satisfied, "to mean A u + b + lambda >= 0"),
        (LyingFilter(), check_safety_filter_infeasible_reported, "expected status 'fallback'"),
    ],
    ids=_case_id,
)
def test_broken_plugin_rejected(plugin, check, message):
    with pytest.raises(ContractError) as info:
        check(plugin)
    text = str(info.value)
    assert message in text
    assert type(plugin).__name__ in text  # says which plugin
    assert "expected" in text


def test_mutating_predictor_message_says_where():
    with pytest.raises(ContractError, match=r"query\.history\[1, 0, 0\]: nan became 0\.0"):
        check_predictor_no_mutation(MutatingPredictor())


def test_wrong_shape_message_says_what_came_out():
    with pytest.raises(ContractError, match=r"got \(3, 6, 2\)"):
        check_predictor_output_shape(WrongShapePredictor())


def test_check_plugin_dispatches_by_role():
    check_plugin(ConstantVelocityPredictor)
    check_plugin(APFBarrier())
    with pytest.raises(ContractError, match="NaNPredictor"):
        check_plugin(NaNPredictor)
    with pytest.raises(TypeError, match="derives from none of the role base classes"):
        check_plugin(object())
    assert checks_for("predictor") is check_predictor
    assert {c.__name__ for c in check_barrier} >= {"check_barrier_gradient"}
    for lst in (check_predictor, check_barrier, check_loss, check_update_rule, check_safety_filter):
        assert isinstance(lst, list) and len(lst) >= 5


def test_run_checks_collects_every_failure():
    results = run_checks(NaNPredictor)
    failed = {r.check for r in results if not r.passed}
    assert "check_predictor_finite_on_clean_input" in failed
    assert all(r.message for r in results if not r.passed)
    assert {r.check for r in results if r.passed} >= {"check_get_params_round_trip"}


def test_bad_unit_test_params_fail_clearly():
    class BadParams(ConstantVelocityPredictor):
        @classmethod
        def _unit_test_params(cls):
            return [{"no_such_arg": 1}]

    with pytest.raises(ContractError, match=r"_unit_test_params\(\) must return kwargs"):
        check_plugin(BadParams)


def test_loss_without_sample_inputs_is_told_what_to_add():
    class NoInputs(Loss):
        def __call__(self, record, truth, lam):
            return 0.0

    with pytest.raises(ContractError, match="_unit_test_inputs"):
        check_loss(NoInputs())


def test_role_bases_cover_registry_roles():
    from conformal_control.testing import ROLE_BASES

    assert set(ROLE_BASES) <= set(registry.ROLES)
    assert ROLE_BASES["barrier"] is Barrier and ROLE_BASES["safety_filter"] is SafetyFilter
    assert ROLE_BASES["predictor"] is Predictor and ROLE_BASES["update_rule"] is UpdateRule
    assert math.isfinite(CBFGapLoss.bounds[1])


def test_parametrize_with_checks_ids_and_instances():
    mark = parametrize_with_checks([ConstantVelocityPredictor, APFBarrier(d_c=0.5)])
    assert mark.args[0] == "plugin, check"
    params = mark.args[1]
    ids = [p.id for p in params]
    n_cv = len(ConstantVelocityPredictor._unit_test_params()) * len(check_predictor)
    assert len(ids) == n_cv + len(check_barrier)
    assert "ConstantVelocityPredictor(window=1)-check_predictor_no_mutation" in ids
    assert any(i.startswith("APFBarrier(K_rep=1.0, rho0=10.0, d_c=0.5,") for i in ids)
    assert ids[-1].endswith("-check_barrier_safe_far_unsafe_at_contact")


def test_parametrize_with_checks_turns_a_broken_class_into_one_failing_test():
    class NeedsArg(ConstantVelocityPredictor):
        def __init__(self, required):
            self.required = required

    (param,) = parametrize_with_checks([NeedsArg]).args[1]
    plugin, check = param.values
    with pytest.raises(ContractError, match=r"NeedsArg\(\*\*\{\}\) failed .*missing 1 required"):
        check(plugin)
