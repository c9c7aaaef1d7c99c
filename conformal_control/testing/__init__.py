"""Contract kit: the checks every plugin of a role must pass, and a pytest helper.

Each role has a plain list of small named check functions ``check(plugin) -> None`` that
raise :class:`ContractError` (an ``AssertionError``) saying what was expected and what
came out (gymnasium's env checker and scikit-learn's ``check_estimator`` style)::

    from conformal_control.testing import check_predictor, parametrize_with_checks

    check_predictor(MyPredictor(window=3))        # run every check, raise the first failure
    [c.__name__ for c in check_predictor]          # the checks, one by one

    @parametrize_with_checks([MyPredictor, MyBarrier(d_c=0.5)])
    def test_contract(plugin, check):             # one test per (instance, check)
        check(plugin)

A class is checked once per entry of its ``_unit_test_params()`` classmethod (cheap
constructor kwargs; default ``[{}]``). Losses also provide ``_unit_test_inputs()``
(sample ``(record, truth)`` pairs), since only the loss knows what its inputs look like.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from ..base import Loss, UpdateRule
from ..cbf.roles import Barrier, Dynamics, Fallback, ReferenceController, SafetyFilter
from ..predictors.base import Predictor
from ._core import (
    CheckList,
    CheckResult,
    ContractError,
    clone,
    instances,
    plugin_label,
    unit_test_params,
)
from .barrier import check_barrier
from .common import check_get_params_round_trip, check_repr
from .dynamics import check_dynamics
from .loss import check_loss
from .predictor import check_predictor, make_query
from .reference import check_reference_controller
from .safety_filter import check_fallback, check_safety_filter
from .update_rule import check_update_rule

__all__ = [
    "ROLE_BASES",
    "CheckList",
    "CheckResult",
    "ContractError",
    "check_barrier",
    "check_dynamics",
    "check_fallback",
    "check_loss",
    "check_plugin",
    "check_predictor",
    "check_reference_controller",
    "check_safety_filter",
    "check_update_rule",
    "checks_for",
    "clone",
    "instances",
    "make_query",
    "parametrize_with_checks",
    "plugin_label",
    "registered_plugins",
    "role_of",
    "run_checks",
    "unit_test_params",
]

#: Base class of each role with a check list.
ROLE_BASES: dict[str, type] = {
    "predictor": Predictor,
    "barrier": Barrier,
    "safety_filter": SafetyFilter,
    "fallback": Fallback,
    "loss": Loss,
    "update_rule": UpdateRule,
    "dynamics": Dynamics,
    "reference": ReferenceController,
}

_CHECKS: dict[str, CheckList] = {
    "predictor": check_predictor,
    "barrier": check_barrier,
    "safety_filter": check_safety_filter,
    "fallback": check_fallback,
    "loss": check_loss,
    "update_rule": check_update_rule,
    "dynamics": check_dynamics,
    "reference": check_reference_controller,
}


def role_of(plugin: Any) -> str:
    """The role of a plugin instance or class, from the base class it derives from."""
    cls = plugin if isinstance(plugin, type) else type(plugin)
    for role, base in ROLE_BASES.items():
        if issubclass(cls, base):
            return role
    raise TypeError(
        f"{cls.__name__} derives from none of the role base classes "
        f"({', '.join(b.__name__ for b in ROLE_BASES.values())}); cannot pick its checks"
    )


def checks_for(role: str) -> CheckList:
    """The check list of ``role`` (roles without their own list get the common checks)."""
    if role in _CHECKS:
        return _CHECKS[role]
    return CheckList(role, [check_get_params_round_trip, check_repr])


def check_plugin(plugin: Any) -> None:
    """Run every check of the plugin's role (picked by its base class); raise the first failure.

    ``plugin`` is an instance, or a class checked once per ``_unit_test_params()`` entry.
    """
    checks_for(role_of(plugin))(plugin)


def run_checks(plugin: Any, role: str | None = None) -> list[CheckResult]:
    """Run every check of the plugin's role and return one result per (instance, check)."""
    return checks_for(role or role_of(plugin)).run(plugin)


def _failing(message: str) -> Callable[[Any], None]:
    def check_instantiation(plugin: Any) -> None:
        raise ContractError(message)

    return check_instantiation


def _cases(plugins: Iterable[Any]) -> list[tuple[str, Any, Callable[[Any], None]]]:
    cases: list[tuple[str, Any, Callable[[Any], None]]] = []
    for plugin in plugins:
        try:
            role = role_of(plugin)
            objs = instances(plugin) if isinstance(plugin, type) else [plugin]
        except Exception as exc:
            msg = str(exc) if isinstance(exc, ContractError) else f"{type(exc).__name__}: {exc}"
            cases.append((plugin_label(plugin), plugin, _failing(msg)))
            continue
        for obj in objs:
            label = plugin_label(obj)
            cases.extend((label, obj, check) for check in checks_for(role))
    return cases


def parametrize_with_checks(plugins: Iterable[Any]) -> Any:
    """pytest decorator: one test per (plugin instance, check), with readable ids.

    Parameters
    ----------
    plugins : iterable of plugin classes or instances
        Classes are instantiated from their ``_unit_test_params()``.

    Returns
    -------
    A ``pytest.mark.parametrize("plugin, check", ...)`` decorator; the test body is
    ``check(plugin)``. A class that cannot be instantiated gives one failing test.
    """
    import pytest

    params = [
        pytest.param(obj, check, id=f"{label}-{check.__name__}")
        for label, obj, check in _cases(plugins)
    ]
    return pytest.mark.parametrize("plugin, check", params)


def registered_plugins(role: str | None = None) -> list[tuple[str, str, type | None, str | None]]:
    """Every registered plugin as ``(role, name, class or None, unavailability reason)``."""
    from .. import registry

    out = []
    for entry in registry.entries(role):
        try:
            cls = entry.load()
        except registry.PluginUnavailableError as exc:
            out.append((entry.role, entry.name, None, str(exc)))
        else:
            out.append((entry.role, entry.name, cls, None))
    return out
