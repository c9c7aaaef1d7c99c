"""One capabilities object per plugin class: declared with class keywords, resolved once,
checked by the contract kit."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from conformal_control.core.capabilities import Capabilities
from conformal_control.core.update_rules import FixedEtaRule
from conformal_control.families.cbf.barriers import APFBarrier
from conformal_control.predictors.base import Forecast, PredictionQuery, Predictor
from conformal_control.predictors.constant_velocity import ConstantVelocityPredictor
from conformal_control.testing import ContractError, check_capabilities


class _Still(Predictor):
    """Predicts that every agent stands still.

    Parameters
    ----------
    horizon : int
        Unused.
    """

    def __init__(self, horizon: int = 1) -> None:
        self.horizon = horizon

    def predict(self, query: PredictionQuery) -> Forecast:
        last = query.history[:, -1]
        return Forecast(np.repeat(last[:, None], query.horizon, axis=1))


def test_declared_with_class_keywords_and_inherited() -> None:
    class Quick(_Still, batchable=True):
        """A quick one."""

    class Quicker(Quick):
        """Quicker."""

    assert isinstance(Quick.capabilities, Capabilities)
    assert Quick.capabilities.batchable and Quicker.capabilities.batchable
    assert not _Still.capabilities.batchable  # the parent is unchanged
    assert Quick().capabilities is Quick.capabilities  # readable on an instance


def test_compiled_form_is_not_inherited() -> None:
    class Tweaked(ConstantVelocityPredictor):
        """Constant velocity computing something else."""

    assert ConstantVelocityPredictor.capabilities.compiled == "constant_velocity"
    assert Tweaked.capabilities.compiled is None
    assert Tweaked.capabilities.batchable  # every other field is inherited


def test_unknown_keyword_and_attribute_declaration_are_refused() -> None:
    with pytest.raises(TypeError, match="no capability batchabel"):

        class Typo(_Still, batchabel=True):  # type: ignore[call-arg]
            """A typo."""

    with pytest.raises(TypeError, match="declare capabilities as keywords"):

        class AsAttribute(_Still):
            """An attribute."""

            capabilities = Capabilities(batchable=True)


def test_a_flag_of_before_is_folded_in_with_a_warning() -> None:
    with pytest.warns(DeprecationWarning, match=r"Old.fast = \.\.\. is deprecated.*batchable"):

        class Old(_Still):
            """Set a flag the way of 0.2."""

            fast = True

    assert Old.capabilities.batchable


@pytest.mark.parametrize(
    ("keywords", "message"),
    [
        ({"guarantee": "identity"}, "no rule capability 'guarantee'"),
        ({"run_values": {"speed": "v_max"}}, "run_values key 'speed'"),
        ({"run_values": {"horizon": "horizon"}}, "documented run value"),
        ({"trainable": True}, "trainable predictor to take weights"),
    ],
)
def test_the_contract_kit_checks_a_declaration(keywords: dict, message: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cls = type("Declared", (_Still,), {"__doc__": _Still.__doc__}, **keywords)
    with pytest.raises(ContractError, match=message):
        check_capabilities(cls())
    check_capabilities(_Still())  # the undeclared one passes


def test_the_core_plugins_declare_what_they_did_as_attributes() -> None:
    assert APFBarrier.capabilities.run_values["d_c"] == "barrier_distance"
    caps = FixedEtaRule.capabilities
    assert (caps.guarantee, caps.fixed_step, caps.exact_step) == ("identity", True, True)
    assert caps.lambda_params == ("eta", "lambda_init", "lambda_min", "lambda_max")
    assert not hasattr(FixedEtaRule, "lambda_params") and not hasattr(Predictor, "fast")


def test_the_capabilities_module_stands_alone_and_base_re_exports_it() -> None:
    """``core.capabilities`` holds the declarations and imports nothing of the package (its
    floor is -1); ``core.base`` hands the same objects on, so 0.3's imports keep working."""
    import ast
    import inspect

    from conformal_control.core import base, capabilities

    tree = ast.parse(inspect.getsource(capabilities))
    imported = [
        "." * n.level + (n.module or "") if isinstance(n, ast.ImportFrom) else a.name
        for n in ast.walk(tree)
        if isinstance(n, (ast.Import, ast.ImportFrom))
        for a in n.names
    ]
    assert not [m for m in imported if m.startswith(("conformal_control", "."))], imported
    for name in capabilities.__all__:
        assert getattr(base, name) is getattr(capabilities, name), name
    assert {"Capabilities", "CompiledForm", "GuaranteeKind"} <= set(base.__all__)
    assert base.Plugin.capabilities == capabilities.Capabilities()
