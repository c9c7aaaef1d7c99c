"""The contract kit over every registered plugin and every built-in environment and
decision family, and broken plugins it must reject."""

from __future__ import annotations

import math
import textwrap
from typing import ClassVar

import numpy as np
import pytest

from conformal_control.core import registry
from conformal_control.core.base import DecisionFamily, Environment, Loss, UpdateRule
from conformal_control.core.update_rules import FixedEtaRule
from conformal_control.families.cbf import (
    APFBarrier,
    CBFGapLoss,
    ConformalCBFController,
    ConformalConstraint,
    QPSafetyFilter,
)
from conformal_control.families.cbf.roles import Barrier, SafetyFilter
from conformal_control.families.domains.factory import FactoryEnvironment, MachineSpeed
from conformal_control.families.domains.intervals import ConformalDisc, PedestrianSeries
from conformal_control.predictors import ConstantVelocityPredictor
from conformal_control.predictors.base import Forecast, Predictor
from conformal_control.testing import (
    ContractError,
    check_barrier,
    check_decision_family,
    check_environment,
    check_loss,
    check_plugin,
    check_predictor,
    check_safety_filter,
    check_update_rule,
    checks_for,
    discover,
    parametrize_with_checks,
    registered_plugins,
    run_checks,
)
from conformal_control.testing.barrier import check_barrier_gradient, check_barrier_nan_propagates
from conformal_control.testing.common import (
    check_docstring_parameters,
    check_no_mutable_defaults,
    check_pickle_round_trip,
    docstring_parameters,
)
from conformal_control.testing.decision_family import (
    check_decision_family_decisions,
    check_decision_family_deterministic,
    check_decision_family_no_mutation,
    check_decision_family_ordering,
    check_decision_family_reset,
)
from conformal_control.testing.environment import (
    check_environment_apply_after_done,
    check_environment_deterministic,
    check_environment_interval_protocol,
    check_environment_outputs_not_aliased,
    check_environment_reset,
)
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
from conformal_control.world.replay import ReplayEnvironment

# ------------------------------------------------------------------ built-ins failing today
#: Built-in classes failing a check today, with the reason: reported for a fix. The tests
#: mark them xfail(strict=True), so the fix makes the test fail until its line goes.
#: Built-in classes known to fail a check, with the reason (strict: a fix makes the test
#: fail until the entry is removed). Empty: every built-in passes every check.
KNOWN_FAILURES: dict[type, dict[str, str]] = {}


def known_failures(plugin: object) -> dict[str, str]:
    return KNOWN_FAILURES.get(type(plugin), {})


# ------------------------------------------------------------------ every registered plugin
# every plugin of every role: core, plugins/ distributions, installed third-party packages
@parametrize_with_checks(
    [cls for _, _, cls, _ in registered_plugins() if cls is not None],
    expected_failed_checks=known_failures,
)
def test_registered_plugin_contract(plugin, check):
    check(plugin)


# every Environment and DecisionFamily defined in the package (they are not registered)
BUILTIN_GENERIC = discover(Environment) + discover(DecisionFamily)


@parametrize_with_checks(BUILTIN_GENERIC, expected_failed_checks=known_failures)
def test_builtin_environment_and_family_contract(plugin, check):
    check(plugin)


def test_discovery_finds_every_builtin_environment_and_family():
    assert {FactoryEnvironment, PedestrianSeries, ReplayEnvironment} <= set(BUILTIN_GENERIC)
    assert {MachineSpeed, ConformalDisc, ConformalCBFController} <= set(BUILTIN_GENERIC)
    # abstract bases and classes defined outside the package are left out
    from conformal_control.core.base import SingleStepEnvironment

    assert SingleStepEnvironment not in BUILTIN_GENERIC
    assert all(c.__module__.startswith("conformal_control.") for c in BUILTIN_GENERIC)
    assert not {BrokenDoneEnv, NoisyMachine} & set(BUILTIN_GENERIC)
    predictors = discover(Predictor)
    assert ConstantVelocityPredictor in predictors and RuntimeCV not in predictors


def test_every_registered_plugin_is_available():
    # an installed plugin that cannot be imported fails here with its reason (never skipped)
    unavailable = [(r, n, why) for r, n, cls, why in registered_plugins() if cls is None]
    assert not unavailable, unavailable
    roles = {role for role, *_ in registered_plugins()}
    assert {"predictor", "barrier", "safety_filter", "loss", "rule", "dynamics"} <= roles


class RuntimeCV(ConstantVelocityPredictor):
    """Constant velocity registered at runtime."""


def test_runtime_registered_plugin_is_discovered():
    registry.register("predictor", "_kit_runtime_cv", RuntimeCV)
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
        from conformal_control.families.cbf.roles import FilterResult

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

    # every registered role has its check list; environments are checked but not registered
    assert set(registry.ROLES) <= set(ROLE_BASES)
    assert set(ROLE_BASES) - set(registry.ROLES) == {"environment"}
    assert ROLE_BASES["environment"] is Environment
    assert ROLE_BASES["family"] is DecisionFamily
    assert checks_for("environment") is check_environment
    assert checks_for("family") is check_decision_family
    with pytest.warns(DeprecationWarning, match="'decision_family' is now called 'family'"):
        assert checks_for("decision_family") is check_decision_family
    assert ROLE_BASES["barrier"] is Barrier and ROLE_BASES["safety_filter"] is SafetyFilter
    assert ROLE_BASES["predictor"] is Predictor and ROLE_BASES["rule"] is UpdateRule
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
    assert ids[-1].endswith("-check_no_mutable_defaults")
    assert any(i.endswith("-check_barrier_safe_far_unsafe_at_contact") for i in ids)


def test_parametrize_with_checks_turns_a_broken_class_into_one_failing_test():
    class NeedsArg(ConstantVelocityPredictor):
        def __init__(self, required):
            self.required = required

    (param,) = parametrize_with_checks([NeedsArg]).args[1]
    plugin, check = param.values
    with pytest.raises(ContractError, match=r"NeedsArg\(\*\*\{\}\) failed .*missing 1 required"):
        check(plugin)


# ------------------------------------------------------------------ broken environments
class FloatInstantsEnv(FactoryEnvironment):
    """Factory whose control_instants returns a float."""

    def control_instants(self):
        return 1.0


class BrokenDoneEnv(FactoryEnvironment):
    """Factory whose done is a number, not a bool."""

    @property
    def done(self):
        return self.T - self.t


class EndlessEnv(FactoryEnvironment):
    """Factory that never ends."""

    @property
    def done(self):
        return False


class UnseededEnv(FactoryEnvironment):
    """Factory drawing from an unseeded generator."""

    def reset(self):
        super().reset()
        self._rng = np.random.default_rng()


class HalfResetEnv(FactoryEnvironment):
    """Factory whose reset forgets to rewind its random draws."""

    def reset(self):
        rng = getattr(self, "_rng", None)
        super().reset()
        if rng is not None:
            self._rng = rng


class AliasingEnv(FactoryEnvironment):
    """Factory revealing its internal buffer, then drawing the next step into it."""

    def reset(self):
        super().reset()
        self._buf = np.zeros(int(self.p))

    def apply(self, decision):
        self.speeds_.append(float(decision))
        self._buf += self._rng.uniform(size=int(self.p))  # reads what it handed out
        self._buf %= 1.0
        self._u = self._buf
        self.t += 1

    def reveal(self):
        return self._u


class LambdaEnv(FactoryEnvironment):
    """Factory keeping a lambda (cannot be pickled)."""

    def reset(self):
        super().reset()
        self.draw_ = lambda: self._rng.uniform()


class StrictFactory(FactoryEnvironment):
    """Factory refusing apply() after the end."""

    def apply(self, decision):
        if self.done:
            raise RuntimeError("apply() called after the last step")
        super().apply(decision)


class LaxFactory(FactoryEnvironment):
    """Factory accepting apply() after the end (keeps producing steps)."""

    def apply(self, decision):
        self.speeds_.append(float(decision))
        self._u = self._rng.uniform(size=int(self.p))
        self.t += 1


class NoPartnerEnv(FactoryEnvironment):
    """Factory without a family to drive it."""

    _unit_test_family = None


@pytest.mark.parametrize(
    ("env", "check", "message"),
    [
        (
            FloatInstantsEnv(T=3),
            check_environment_interval_protocol,
            "expected control_instants() to return an int >= 0 (interval 0), got float 1.0",
        ),
        (BrokenDoneEnv(T=3), check_environment_reset, "expected env.done to be a bool"),
        (
            EndlessEnv(T=3),
            check_environment_interval_protocol,
            "expected the episode to end (done True) within 1000 intervals",
        ),
        (
            UnseededEnv(T=5),
            check_environment_deterministic,
            "expected two copies driven the same way to give the same episode",
        ),
        (
            HalfResetEnv(T=5),
            check_environment_reset,
            "expected reset() in the middle of an episode to restart it exactly",
        ),
        (
            AliasingEnv(T=5),
            check_environment_outputs_not_aliased,
            "later outputs changed, but episode.intervals[1].truth[0]",
        ),
        (
            LaxFactory(T=3),
            check_environment_apply_after_done,
            "expected apply() after the episode ended (done True) to raise a RuntimeError",
        ),
        (
            LambdaEnv(T=3),
            check_pickle_round_trip,
            "expected the LambdaEnv to survive pickle.dumps/loads after use",
        ),
        (
            NoPartnerEnv(T=3),
            check_environment_interval_protocol,
            "to define a classmethod _unit_test_family()",
        ),
    ],
    ids=lambda x: type(x).__name__ if isinstance(x, Environment) else _case_id(x),
)
def test_broken_environment_rejected(env, check, message):
    with pytest.raises(ContractError) as info:
        check(env)
    text = str(info.value)
    assert message in text
    assert text.startswith(type(env).__name__ + "(T=")  # says which environment, with params


def test_a_correct_environment_passes_every_check():
    results = run_checks(StrictFactory(T=4, p=3))
    assert [r.check for r in results] == [c.__name__ for c in check_environment]
    assert all(r.status == "passed" for r in results), [r.message for r in results]


def test_environment_checks_do_not_touch_the_instance():
    env = StrictFactory(T=4)
    check_environment(env)
    assert not hasattr(env, "t")  # every check works on a copy; this one was never reset


def test_environments_are_not_asked_for_get_params():
    names = {c.__name__ for c in check_environment}
    assert "check_get_params_round_trip" not in names and "check_repr" not in names
    assert not hasattr(FactoryEnvironment(), "get_params")


# ------------------------------------------------------------------ broken decision families
class StateMutatingDisc(ConformalDisc):
    """Shifts the history of the query it decides from, in place."""

    def decide(self, state, lam):
        state["query"].history[..., 0] += 1.0
        return super().decide(state, lam)


class ObservationMutatingDisc(ConformalDisc):
    """Drops the previous truth from the observation it plans from."""

    def begin_interval(self, observation):
        super().begin_interval(observation)
        observation.pop("previous_truth")


class NoisyMachine(MachineSpeed):
    """Adds unseeded noise to the speed."""

    def decide(self, state, lam):
        return super().decide(state, lam) + np.random.default_rng().uniform()


class ForgetfulMachine(MachineSpeed):
    """Speeds up with every decision ever made (reset() does not restart the count)."""

    n = 0

    def decide(self, state, lam):
        type(self).n += 1
        return super().decide(state, lam) + 0.01 * self.n


class NoneMachine(MachineSpeed):
    """Decides nothing."""

    def decide(self, state, lam):
        super().decide(state, lam)


class OrderedMachine(MachineSpeed):
    """Declares its ordering: a faster machine is less conservative."""

    @classmethod
    def _unit_test_conservativeness(cls, decision):
        return -float(decision)


class ReversedMachine(OrderedMachine):
    """Runs faster at a smaller lambda (the wrong way round)."""

    def decide(self, state, lam):
        return super().decide(state, -lam)


class BadStatsMachine(MachineSpeed):
    """Reports a string among its counters."""

    def stats(self):
        return {"mode": "fast"}


@pytest.mark.parametrize(
    ("family", "check", "message"),
    [
        (
            StateMutatingDisc(ConstantVelocityPredictor()),
            check_decision_family_no_mutation,
            "expected decide() to leave its input state of interval 0, instant 0 unchanged, "
            "but state of interval 0, instant 0['query'].history[0, 0, 0]",
        ),
        (
            ObservationMutatingDisc(ConstantVelocityPredictor()),
            check_decision_family_no_mutation,
            "expected begin_interval() to leave its input observation of interval 0 "
            "unchanged, but observation of interval 0: keys",
        ),
        (
            NoisyMachine(),
            check_decision_family_deterministic,
            "expected two fresh copies driven the same way to decide the same",
        ),
        (ForgetfulMachine(), check_decision_family_reset, "expected reset() to restart the family"),
        (
            NoneMachine(),
            check_decision_family_decisions,
            "expected decide() to return a decision (interval 0, instant 0), got None",
        ),
        (
            ReversedMachine(),
            check_decision_family_ordering,
            "expected a smaller lambda never to give a less conservative decision",
        ),
        (
            BadStatsMachine(),
            check_decision_family_decisions,
            "expected stats() of str -> number, got {'mode': 'fast'}",
        ),
    ],
    ids=lambda x: type(x).__name__ if isinstance(x, DecisionFamily) else _case_id(x),
)
def test_broken_decision_family_rejected(family, check, message):
    with pytest.raises(ContractError) as info:
        check(family)
    text = str(info.value)
    assert message in text
    assert text.startswith(type(family).__name__)


def test_ordering_probe_passes_a_family_ordered_the_right_way():
    check_decision_family_ordering(OrderedMachine())  # speeds max(lam, 0): nondecreasing
    with pytest.raises(ContractError, match=r"instant 0: lambda -10 -> -10 but lambda -1 -> -1$"):
        check_decision_family_ordering(ReversedMachine())
    check_decision_family_ordering(NoisyMachine())  # nothing declared: nothing to check


def test_family_without_partner_is_told_what_to_add():
    class Lonely(MachineSpeed):
        """No partner environment."""

        _unit_test_environment = None

    with pytest.raises(ContractError, match=r"_unit_test_environment\(\) returning an Environment"):
        check_decision_family_decisions(Lonely())


# ------------------------------------------------------------------ river's checks, broken
class MutableDefaultCV(ConstantVelocityPredictor):
    """Constant velocity with per-agent weights.

    Parameters
    ----------
    window : int
        Samples used for the velocity.
    weights : list of float
        Weights of the samples.
    """

    def __init__(self, window=5, weights=[1.0]):  # noqa: B006 - the defect under test
        self.window = window
        self.weights = weights


class UndocumentedCV(ConstantVelocityPredictor):
    """Constant velocity with an extra parameter nobody documented."""

    def __init__(self, window=5, smoothing=0.0):
        self.window = window
        self.smoothing = smoothing


class PartlyDocumentedCV(ConstantVelocityPredictor):
    """Constant velocity with an extra parameter.

    Parameters
    ----------
    window : int
        Samples used for the velocity.
    """

    def __init__(self, window=5, smoothing=0.0):
        self.window = window
        self.smoothing = smoothing


class LambdaHoldingCV(ConstantVelocityPredictor):
    """Keeps a lambda once used (cannot be pickled after use)."""

    def reset(self):
        super().reset()
        self.transform_ = lambda x: x


class ForgetfulPickleCV(ConstantVelocityPredictor):
    """Pickles a different window than it uses."""

    def __getstate__(self):
        return {**self.__dict__, "window": 1}


@pytest.mark.parametrize(
    ("plugin", "check", "message"),
    [
        (
            MutableDefaultCV(),
            check_no_mutable_defaults,
            "expected immutable __init__ defaults (None, numbers, strings, tuples; build "
            "mutable ones when used), got weights=list [1.0]",
        ),
        (
            UndocumentedCV(),
            check_docstring_parameters,
            "expected a numpy-style 'Parameters' section naming the __init__ arguments "
            "['window', 'smoothing']",
        ),
        (PartlyDocumentedCV(), check_docstring_parameters, "got no entry for ['smoothing']"),
        (
            LambdaHoldingCV(),
            check_pickle_round_trip,
            "expected the LambdaHoldingCV to survive pickle.dumps/loads after use",
        ),
        (
            ForgetfulPickleCV(),
            check_pickle_round_trip,
            "expected the copy pickled before use to behave as the original on the sample "
            "inputs, but outputs[0][0]",
        ),
    ],
    ids=lambda x: type(x).__name__ if not callable(x) or isinstance(x, type) else _case_id(x),
)
def test_river_checks_reject(plugin, check, message):
    with pytest.raises(ContractError) as info:
        check(plugin)
    text = str(info.value)
    assert message in text
    assert text.startswith(type(plugin).__name__)


def test_river_checks_run_for_every_role():
    for role in (
        "predictor",
        "barrier",
        "safety_filter",
        "loss",
        "rule",
        "dynamics",
        "reference",
        "environment",
        "family",
        "no_such_role",
    ):
        names = {c.__name__ for c in checks_for(role)}
        assert {
            "check_pickle_round_trip",
            "check_docstring_parameters",
            "check_no_mutable_defaults",
        } <= names, role


def test_docstring_parameters_parser():
    doc = """Summary.

    Parameters
    ----------
    a : float
        First.
    b, c : int
        Second and third, with a colon: here.
    *args
        More.

    Returns
    -------
    x : float
    """
    assert docstring_parameters(doc) == ["a", "b", "c", "args"]
    assert docstring_parameters("Summary only.") is None
    # a subclass keeping its parent's __init__ is documented by its parent
    check_docstring_parameters(RuntimeCV())


def test_docstring_check_wants_a_docstring():
    class Bare(ConstantVelocityPredictor):
        pass

    Bare.__doc__ = None
    with pytest.raises(ContractError, match="expected Bare to have a docstring"):
        check_docstring_parameters(Bare())


def test_immutable_defaults_accepted():
    class Fine(ConstantVelocityPredictor):
        """Fine defaults.

        Parameters
        ----------
        window, shape, name, kind, fn, nothing : any
            Immutable defaults.
        """

        def __init__(
            self, window=5, shape=(1, (2.0, "x")), name="cv", kind=float, fn=len, nothing=None
        ):
            self.window, self.shape, self.name = window, shape, name
            self.kind, self.fn, self.nothing = kind, fn, nothing

    check_no_mutable_defaults(Fine())
    check_docstring_parameters(Fine())

    class TupleOfList(Fine):
        """Tuple holding a list."""

        def __init__(self, window=5, shape=([1],)):
            self.window, self.shape = window, shape

    with pytest.raises(ContractError, match=r"shape=tuple \(\[1\],\)"):
        check_no_mutable_defaults(TupleOfList())


# ------------------------------------------------------------------ expected failures
class LenientFactory(LaxFactory):
    """Factory that, by design, accepts apply() after the end (declared)."""

    _xfail_checks: ClassVar[dict[str, str]] = {
        "check_environment_apply_after_done": "apply() after done is ignored"
    }


class OverCautiousMachine(MachineSpeed):
    """Declares a check it does not fail (a stale declaration)."""

    _xfail_checks: ClassVar[dict[str, str]] = {"check_repr": "repr used to crash"}


class TypoMachine(MachineSpeed):
    """Declares a check that does not exist."""

    _xfail_checks: ClassVar[dict[str, str]] = {"check_reprr": "typo"}


def test_declared_failure_is_reported_as_expected():
    results = {r.check: r for r in run_checks(LenientFactory(T=4))}
    r = results["check_environment_apply_after_done"]
    assert r.status == "xfailed" and r.passed
    assert r.reason == "apply() after done is ignored"
    assert "to raise a RuntimeError" in r.message  # the real failure is kept
    assert all(x.status == "passed" for k, x in results.items() if k != r.check)
    check_plugin(LenientFactory(T=4))  # no error: the failure is expected
    with pytest.raises(ContractError, match="to raise a RuntimeError"):
        check_plugin(LaxFactory(T=4))  # the same failure, undeclared


def test_declared_failure_that_passes_is_an_error():
    results = {r.check: r for r in run_checks(OverCautiousMachine())}
    r = results["check_repr"]
    assert r.status == "xpassed" and not r.passed
    assert "expected check_repr to fail (declared: repr used to crash), but it passed" in r.message
    with pytest.raises(ContractError, match="expected check_repr to fail"):
        check_plugin(OverCautiousMachine())


def test_declared_failure_must_name_a_check():
    with pytest.raises(ContractError, match=r"unknown \['check_reprr'\]"):
        check_plugin(TypoMachine())
    (result,) = run_checks(TypoMachine())
    assert result.status == "failed" and "check_reprr" in result.message
    (param,) = parametrize_with_checks([TypoMachine()]).args[1]
    with pytest.raises(ContractError, match="unknown"):
        param.values[1](param.values[0])


def test_expected_failed_checks_from_the_test_suite():
    extra = {"check_environment_apply_after_done": "known, see issue"}
    results = run_checks(LaxFactory(T=4), expected_failed_checks=extra)
    assert {r.check: r.status for r in results}["check_environment_apply_after_done"] == "xfailed"
    check_plugin(LaxFactory(T=4), expected_failed_checks=lambda p: extra)
    with pytest.raises(ContractError, match="expected check_environment_apply_after_done to fail"):
        check_plugin(StrictFactory(T=4), expected_failed_checks=extra)


def test_parametrize_marks_expected_failures_strict():
    params = parametrize_with_checks([LenientFactory(T=4), OverCautiousMachine()]).args[1]
    marked = {p.id.rsplit("-", 1)[1]: p.marks for p in params if p.marks}
    assert set(marked) == {"check_environment_apply_after_done", "check_repr"}
    for (mark,) in marked.values():
        assert mark.name == "xfail" and mark.kwargs["strict"] is True and mark.kwargs["reason"]


def test_pytest_runs_expected_failures_both_ways(tmp_path, monkeypatch):
    # in a real pytest session: the declared failure xfails, the stale declaration fails
    (tmp_path / "test_inner.py").write_text(
        textwrap.dedent(
            """
            from conformal_control.families.domains.factory import FactoryEnvironment, MachineSpeed
            from conformal_control.testing import parametrize_with_checks

            class Lenient(FactoryEnvironment):
                \"\"\"Ignores apply() after the end.

                Parameters
                ----------
                T, p, seed : int
                    As the factory.
                \"\"\"

                _xfail_checks = {"check_environment_apply_after_done": "accepted by design"}

                def apply(self, decision):
                    self.speeds_.append(float(decision))
                    self._u = self._rng.uniform(size=int(self.p))
                    self.t += 1

            class Stale(MachineSpeed):
                \"\"\"Declares a check it passes.\"\"\"

                _xfail_checks = {"check_repr": "stale"}

            @parametrize_with_checks([Lenient(T=4), Stale()])
            def test_contract(plugin, check):
                check(plugin)
            """
        )
    )
    outcomes: dict[str, str] = {}

    class Collect:  # records each test's outcome, as pytest reports it
        def pytest_runtest_logreport(self, report):
            if report.when == "call" or report.outcome != "passed":
                outcomes[report.nodeid.split("[", 1)[1]] = (
                    "xfailed" if hasattr(report, "wasxfail") and report.skipped else report.outcome
                )

    monkeypatch.setenv("PYTEST_DISABLE_PLUGIN_AUTOLOAD", "1")  # a bare session, quick
    code = pytest.main(
        [str(tmp_path / "test_inner.py"), "-q", "-p", "no:cacheprovider"],
        plugins=[Collect()],
    )
    assert code == pytest.ExitCode.TESTS_FAILED
    assert (
        outcomes.pop("Lenient(T=4, p=10, seed=0)-check_environment_apply_after_done]") == "xfailed"
    )
    assert outcomes.pop("Stale()-check_repr]") == "failed"  # XPASS(strict) fails the run
    assert set(outcomes.values()) == {"passed"}
    assert len(outcomes) == len(check_environment) + len(check_decision_family) - 2
