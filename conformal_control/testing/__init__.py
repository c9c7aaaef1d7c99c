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

The generic roles a user writes for a problem of their own are checked the same way,
each driven through a short stub of the conformal loop (gymnasium's ``check_env``):
``check_environment`` (an :class:`~conformal_control.core.base.Environment`, driven by the
family its class's ``_unit_test_family()`` returns) and ``check_decision_family`` (a
:class:`~conformal_control.core.base.DecisionFamily`, driven in the environment of
``_unit_test_environment()``); see :mod:`.environment` and :mod:`.decision_family`.
:func:`discover` finds every concrete subclass of a base class in a package, for a test
matrix that grows by itself.

Every role also gets river's checks: a pickling round trip behaving the same, a numpy
docstring whose ``Parameters`` name every ``__init__`` argument, no mutable defaults.

Expected failures: a class declares the checks it is known to fail, and why, in
``_xfail_checks: ClassVar[dict[str, str]] = {"check_name": "reason"}`` (scikit-learn's
tag); a test suite can add its own with ``expected_failed_checks=`` (a dict, or a callable
``plugin -> dict``). :func:`parametrize_with_checks` marks them ``xfail(strict=True)``;
:func:`run_checks` reports them with status ``"xfailed"`` and :func:`check_plugin` lets
them fail; in every case an expected failure that passes is an error.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from collections.abc import Callable, Iterable
from typing import Any

from ..core.base import DecisionFamily, Environment, Loss, UpdateRule
from ..families.cbf.roles import Barrier, Dynamics, Fallback, ReferenceController, SafetyFilter
from ..predictors.base import Predictor
from ..world.crowds.base import CrowdModel
from ._core import (
    CheckList,
    CheckResult,
    ContractError,
    ExpectedFailures,
    clone,
    deep_clone,
    expected_failures,
    instances,
    plugin_label,
    unit_test_params,
)
from .barrier import check_barrier
from .common import (
    check_capabilities,
    check_docstring_parameters,
    check_get_params_round_trip,
    check_no_mutable_defaults,
    check_pickle_round_trip,
    check_repr,
)
from .crowd_model import check_crowd_model
from .decision_family import check_decision_family
from .dynamics import check_dynamics
from .environment import check_environment
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
    "ExpectedFailures",
    "check_barrier",
    "check_capabilities",
    "check_crowd_model",
    "check_decision_family",
    "check_dynamics",
    "check_environment",
    "check_fallback",
    "check_loss",
    "check_plugin",
    "check_predictor",
    "check_reference_controller",
    "check_safety_filter",
    "check_update_rule",
    "checks_for",
    "clone",
    "deep_clone",
    "discover",
    "expected_failures",
    "instances",
    "make_query",
    "parametrize_with_checks",
    "plugin_label",
    "registered_plugins",
    "role_of",
    "run_checks",
    "unit_test_params",
]

#: Base class of each role with a check list: the registry's roles, then the generic
#: roles a user writes for a problem of their own (not registered by name).
ROLE_BASES: dict[str, type] = {
    "predictor": Predictor,
    "barrier": Barrier,
    "safety_filter": SafetyFilter,
    "fallback": Fallback,
    "loss": Loss,
    "rule": UpdateRule,
    "dynamics": Dynamics,
    "reference": ReferenceController,
    "environment": Environment,
    "family": DecisionFamily,
    "crowd": CrowdModel,
}

_CHECKS: dict[str, CheckList] = {
    "predictor": check_predictor,
    "barrier": check_barrier,
    "safety_filter": check_safety_filter,
    "fallback": check_fallback,
    "loss": check_loss,
    "rule": check_update_rule,
    "dynamics": check_dynamics,
    "reference": check_reference_controller,
    "environment": check_environment,
    "family": check_decision_family,
    "crowd": check_crowd_model,
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
    from ..core.registry import RENAMED_ROLES, role_name

    if role in RENAMED_ROLES:
        role = role_name(role)  # a role name of 0.2: its new name, with a warning
    if role in _CHECKS:
        return _CHECKS[role]
    return CheckList(
        role,
        [
            check_get_params_round_trip,
            check_repr,
            check_capabilities,
            check_pickle_round_trip,
            check_docstring_parameters,
            check_no_mutable_defaults,
        ],
    )


def check_plugin(plugin: Any, *, expected_failed_checks: ExpectedFailures = None) -> None:
    """Run every check of the plugin's role (picked by its base class); raise the first failure.

    ``plugin`` is an instance, or a class checked once per ``_unit_test_params()`` entry.
    Expected failures (``_xfail_checks`` and ``expected_failed_checks``) may fail; one
    that passes raises.
    """
    checks_for(role_of(plugin))(plugin, expected_failed_checks=expected_failed_checks)


def run_checks(
    plugin: Any, role: str | None = None, *, expected_failed_checks: ExpectedFailures = None
) -> list[CheckResult]:
    """Run every check of the plugin's role and return one result per (instance, check).

    A check the plugin is expected to fail has status ``"xfailed"`` (or ``"xpassed"``,
    a failure, if it passed).
    """
    return checks_for(role or role_of(plugin)).run(
        plugin, expected_failed_checks=expected_failed_checks
    )


def _failing(message: str) -> Callable[[Any], None]:
    def check_instantiation(plugin: Any) -> None:
        raise ContractError(message)

    return check_instantiation


Case = tuple[str, Any, Callable[[Any], None], str | None]


def _cases(plugins: Iterable[Any], expected_failed_checks: ExpectedFailures = None) -> list[Case]:
    """(label, instance, check, reason it is expected to fail or None) per test."""
    cases: list[Case] = []
    for plugin in plugins:
        try:
            role = role_of(plugin)
            objs = instances(plugin) if isinstance(plugin, type) else [plugin]
        except Exception as exc:
            msg = str(exc) if isinstance(exc, ContractError) else f"{type(exc).__name__}: {exc}"
            cases.append((plugin_label(plugin), plugin, _failing(msg), None))
            continue
        checks = checks_for(role)
        for obj in objs:
            label = plugin_label(obj)
            try:
                xfail = expected_failures(obj, checks, expected_failed_checks)
            except ContractError as exc:
                cases.append((label, obj, _failing(str(exc)), None))
                continue
            cases.extend((label, obj, check, xfail.get(check.__name__)) for check in checks)
    return cases


def parametrize_with_checks(
    plugins: Iterable[Any], *, expected_failed_checks: ExpectedFailures = None
) -> Any:
    """pytest decorator: one test per (plugin instance, check), with readable ids.

    Parameters
    ----------
    plugins : iterable of plugin classes or instances
        Classes are instantiated from their ``_unit_test_params()``.
    expected_failed_checks : dict or callable, optional
        Checks expected to fail, ``{check name: reason}`` or ``plugin -> {...}``, on top
        of each class's ``_xfail_checks``.

    Returns
    -------
    A ``pytest.mark.parametrize("plugin, check", ...)`` decorator; the test body is
    ``check(plugin)``. A class that cannot be instantiated gives one failing test; an
    expected failure is marked ``xfail(strict=True, reason=...)``, so a check that
    unexpectedly passes fails the test suite.
    """
    import pytest

    params = [
        pytest.param(
            obj,
            check,
            id=f"{label}-{check.__name__}",
            marks=() if reason is None else pytest.mark.xfail(strict=True, reason=reason),
        )
        for label, obj, check, reason in _cases(plugins, expected_failed_checks)
    ]
    return pytest.mark.parametrize("plugin, check", params)


def discover(base: type, package: str = "conformal_control") -> list[type]:
    """Every concrete subclass of ``base`` defined in ``package`` (all its modules imported).

    For a test matrix that grows by itself, e.g. ``discover(Environment)`` gives every
    built-in environment. Abstract classes and names starting with ``_`` are left out; a
    module that fails to import raises, naming it.
    """
    root = importlib.import_module(package)
    for info in pkgutil.walk_packages(getattr(root, "__path__", []), prefix=f"{package}."):
        try:
            importlib.import_module(info.name)
        except Exception as exc:
            raise ImportError(
                f"discover() could not import {info.name}: {type(exc).__name__}: {exc}"
            ) from exc
    found: list[type] = []
    todo: list[type] = list(base.__subclasses__())
    while todo:
        cls = todo.pop(0)
        todo.extend(cls.__subclasses__())
        if (
            cls not in found
            and not inspect.isabstract(cls)
            and not cls.__name__.startswith("_")
            and (cls.__module__ == package or cls.__module__.startswith(f"{package}."))
        ):
            found.append(cls)
    return sorted(found, key=lambda c: (c.__module__, c.__qualname__))


def registered_plugins(role: str | None = None) -> list[tuple[str, str, type | None, str | None]]:
    """Every registered plugin as ``(role, name, class or None, unavailability reason)``."""
    from ..core import registry

    out: list[tuple[str, str, type | None, str | None]] = []
    for entry in registry.entries(role):
        try:
            cls = entry.load()
        except registry.PluginUnavailableError as exc:
            out.append((entry.role, entry.name, None, str(exc)))
        else:
            out.append((entry.role, entry.name, cls, None))
    return out
