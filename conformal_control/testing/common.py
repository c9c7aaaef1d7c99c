"""Checks every role shares: parameters stored unchanged, pickling, docstring, defaults.

The pickling check (river's ``check_pickling``) compares what a plugin does on its
role's sample inputs before and after a pickle round trip. What "does" means is
role-specific, so each role's checker module registers a *sample behaviour* with
:func:`sample_behaviour` (a :func:`functools.singledispatch` function on the role's base
class): a deterministic function ``plugin -> outputs`` that starts from ``reset()``.

The docstring check reads the ``Parameters`` section of a numpy-style class docstring.
It needs only the parameter names under that one header, so it scans the section itself
(a dozen lines) instead of adding a docstring-parser dependency to the runtime package.
"""

from __future__ import annotations

import copy
import enum
import functools
import inspect
import numbers
import pickle
import re
from typing import Any

import numpy as np

from ..core.base import (
    Capabilities,
    CompiledForm,
    DecisionFamily,
    Loss,
    Settings,
    UpdateRule,
)
from ..core.spec import RUN_VALUES
from ._core import (
    ContractError,
    deep_clone,
    differ,
    expect,
    init_names,
    plugin_label,
    unit_test_params,
    with_seed,
)

__all__ = [
    "check_capabilities",
    "check_docstring_parameters",
    "check_get_params_round_trip",
    "check_no_mutable_defaults",
    "check_pickle_round_trip",
    "check_repr",
    "docstring_parameters",
    "sample_behaviour",
]


def check_get_params_round_trip(plugin: Any) -> None:
    """``get_params()`` reports every ``__init__`` argument, stored unchanged (scikit-learn style).

    Rebuilding the plugin from ``get_params()`` must give a plugin whose ``get_params()``
    holds the very same objects: the constructor stores its arguments as they are and does
    no validation or conversion (that belongs in ``reset``/``predict``/...).
    """
    params = plugin.get_params()
    expect(
        isinstance(params, dict), plugin, f"expected get_params() to return a dict, got {params!r}"
    )
    missing = [n for n in init_names(type(plugin)) if n not in params]
    expect(
        not missing,
        plugin,
        f"expected get_params() to report every __init__ argument; missing {missing} "
        "(store each argument unchanged as self.<name>)",
    )
    try:
        copy = type(plugin)(**params)
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(plugin)}: expected type(plugin)(**plugin.get_params()) to work, got "
            f"{type(exc).__name__}: {exc}"
        ) from exc
    _stored_unchanged(plugin, copy, params)
    cls = type(plugin)
    # the declared test kwargs and the signature's defaults must be stored as given, too
    for kwargs in unit_test_params(cls):
        _stored_unchanged(plugin, cls(**kwargs), kwargs)
    sig = inspect.signature(cls.__init__)
    defaults = {
        n: p.default
        for n, p in sig.parameters.items()
        if n != "self" and p.default is not inspect.Parameter.empty
    }
    required = [
        n
        for n, p in sig.parameters.items()
        if n != "self"
        and p.default is inspect.Parameter.empty
        and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
    ]
    if not required:
        _stored_unchanged(plugin, cls(), defaults)


def _stored_unchanged(plugin: Any, built: Any, given: dict[str, Any]) -> None:
    stored = built.get_params()
    for name, value in given.items():
        expect(
            name in stored and stored[name] is value,
            plugin,
            f"expected __init__ to store parameter {name!r} unchanged (the same object), "
            f"passed {value!r}, stored {stored.get(name, '<missing>')!r}",
        )


def check_repr(plugin: Any) -> None:
    """``repr(plugin)`` works and names the class (run configs and logs print it)."""
    text = repr(plugin)
    expect(
        type(plugin).__name__ in text,
        plugin,
        f"expected repr() to contain the class name {type(plugin).__name__!r}, got {text!r}",
    )


# ------------------------------------------------------------------ pickling
@functools.singledispatch
def sample_behaviour(plugin: Any) -> Any:
    """What ``plugin`` does on its role's sample inputs (compared across a pickle round trip).

    Registered per role base class by the checker modules; the fallback compares the
    instance's attributes.
    """
    return {k: v for k, v in vars(plugin).items() if not k.startswith("__")}


def _fresh(plugin: Any) -> Any:
    if not hasattr(plugin, "get_params"):  # environments: no constructor round trip
        try:
            return copy.deepcopy(plugin)
        except Exception as exc:
            raise ContractError(
                f"{plugin_label(plugin)}: expected a deep copy to work (the checks run on "
                f"copies), got {type(exc).__name__}: {exc}"
            ) from exc
    fresh = deep_clone(plugin)
    return with_seed(fresh, 0) if "random_state" in init_names(type(fresh)) else fresh


def _round_trip(plugin: Any, when: str) -> Any:
    try:
        return pickle.loads(pickle.dumps(plugin))
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(plugin)}: expected the {type(plugin).__name__} to survive "
            f"pickle.dumps/loads {when} "
            f"(multiprocessing sweeps and checkpoints pickle it), got {type(exc).__name__}: {exc}"
        ) from exc


def _behave(plugin: Any, who: str) -> Any:
    try:
        return sample_behaviour(plugin)
    except ContractError:
        raise
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(plugin)}: expected the {who} to work on the role's sample inputs, got "
            f"{type(exc).__name__}: {exc}"
        ) from exc


def check_pickle_round_trip(plugin: Any) -> None:
    """A pickled-and-unpickled plugin behaves the same on the role's sample inputs, both
    fresh and after it has been used (river's ``check_pickling``)."""
    original = _fresh(plugin)
    for when in ("before use", "after use"):
        copied = _round_trip(original, when)
        expect(
            type(copied) is type(original),
            plugin,
            f"expected pickle to give back a {type(original).__name__}, got "
            f"{type(copied).__name__}",
        )
        mine = _behave(original, "plugin")
        theirs = _behave(copied, "unpickled copy")
        d = differ(mine, theirs, "outputs")
        expect(
            d is None,
            plugin,
            f"expected the copy pickled {when} to behave as the original on the sample inputs, "
            f"but {d}",
        )


# ------------------------------------------------------------------ docstring
_SECTION = re.compile(r"^(\w[\w ]*)\n-{3,}\s*$", re.MULTILINE)
_PARAM_LINE = re.compile(r"^([*\w][\w, *]*?)\s*(?::.*)?$")


def docstring_parameters(doc: str) -> list[str] | None:
    """Names in the ``Parameters`` section of a numpy-style docstring (None: no section).

    A line ``name : type`` (or ``a, b : float``) at the section's indentation names
    parameters; the indented lines under it describe them.
    """
    doc = inspect.cleandoc(doc or "")
    headers = list(_SECTION.finditer(doc))
    for i, m in enumerate(headers):
        if m.group(1).strip() != "Parameters":
            continue
        end = headers[i + 1].start() if i + 1 < len(headers) else len(doc)
        names: list[str] = []
        for line in doc[m.end() : end].splitlines():
            if not line.strip() or line[0].isspace():
                continue
            pm = _PARAM_LINE.match(line.strip())
            if pm:
                names += [n.strip().lstrip("*") for n in pm.group(1).split(",") if n.strip()]
        return names
    return None


def check_docstring_parameters(plugin: Any) -> None:
    """The class has a numpy-style docstring whose ``Parameters`` section names every
    ``__init__`` argument (river's docstring check; runs record parameters by name)."""
    cls = type(plugin)
    names = init_names(cls)
    doc = cls.__doc__ or ""
    expect(
        bool(doc.strip()),
        plugin,
        f"expected {cls.__name__} to have a docstring (its first line is the plugin's "
        "description), got none",
    )
    if not names:
        return
    # a subclass that keeps its parent's __init__ may keep its parent's Parameters too
    owner = next(c for c in cls.__mro__ if "__init__" in vars(c))
    documented: list[str] | None = None
    for c in cls.__mro__[: cls.__mro__.index(owner) + 1]:
        found = docstring_parameters(c.__doc__ or "")
        if found is not None:
            documented = (documented or []) + found
    expect(
        documented is not None,
        plugin,
        f"expected a numpy-style 'Parameters' section naming the __init__ arguments "
        f"{names} in the docstring of {cls.__name__}, got none",
    )
    missing = [n for n in names if n not in (documented or [])]
    expect(
        not missing,
        plugin,
        f"expected the docstring's Parameters section to name every __init__ argument, "
        f"got no entry for {missing}",
    )


# ------------------------------------------------------------------ mutable defaults
def _immutable(value: Any) -> bool:
    if value is None or isinstance(
        value, (bool, numbers.Number, str, bytes, range, type, enum.Enum, np.generic)
    ):
        return True
    if isinstance(value, (tuple, frozenset)):
        return all(_immutable(v) for v in value)
    return inspect.isfunction(value) or inspect.isbuiltin(value)


def check_no_mutable_defaults(plugin: Any) -> None:
    """No ``__init__`` argument defaults to a mutable object (a list, dict, array or a
    plugin instance would be shared by every instance built without it)."""
    cls = type(plugin)
    if cls.__init__ is object.__init__:
        return
    sig = inspect.signature(cls.__init__)
    bad = {
        n: p.default
        for n, p in sig.parameters.items()
        if p.default is not inspect.Parameter.empty and not _immutable(p.default)
    }
    expect(
        not bad,
        plugin,
        "expected immutable __init__ defaults (None, numbers, strings, tuples; build "
        "mutable ones when used), got "
        + ", ".join(f"{n}={type(v).__name__} {v!r:.40}" for n, v in bad.items()),
    )


#: Fields of :class:`~conformal_control.core.capabilities.Capabilities` that mean something
#: for one role only (keyed by the role's base class, resolved lazily: predictors and filters are a
#: floor up); every other field applies to every role.
_ROLE_CAPABILITIES: dict[str, tuple[str, ...]] = {
    "predictor": ("batchable", "trainable", "requires_ground_truth"),
    "rule": ("guarantee", "fixed_step", "exact_step", "uses_loss_function", "lambda_params"),
    "family": ("default_loss", "default_rule_params", "lambda_unit", "vector_lambda"),
    "loss": ("vector_lambda",),
    "safety_filter": ("probe_floor_first",),
}
_RULE_VALUES = ("epsilon", "eta", "lambda_init", "lambda_min", "lambda_max")


def _roles_of(cls: type) -> set[str]:
    from ..families.cbf.roles import SafetyFilter
    from ..predictors.base import Predictor

    bases = {
        "predictor": Predictor,
        "rule": UpdateRule,
        "family": DecisionFamily,
        "loss": Loss,
        "safety_filter": SafetyFilter,
    }
    return {role for role, base in bases.items() if issubclass(cls, base)}


def check_capabilities(plugin: Any) -> None:
    """The plugin's class declares its capabilities as one
    :class:`~conformal_control.core.capabilities.Capabilities` object, consistently.

    Fields of another role keep their defaults; every ``run_values`` entry maps a
    constructor argument (or a settings group's ``<group>__<field>``) to a documented run
    value (:data:`~conformal_control.core.spec.RUN_VALUES`); a declared compiled form is the one
    :meth:`~conformal_control.core.base.Plugin.compiled_state` hands over; a rule's
    ``lambda_params`` are constructor arguments and its ``guarantee`` a known kind; a
    trainable predictor takes ``weights`` and has ``fit``; a family's default rule
    parameters are the rule's run values.
    """
    cls = type(plugin)
    caps = getattr(cls, "capabilities", None)
    expect(
        isinstance(caps, Capabilities),
        plugin,
        f"expected {cls.__name__}.capabilities to be a Capabilities, got {caps!r} (declare "
        "capabilities with keywords of the class statement)",
    )
    assert isinstance(caps, Capabilities)
    roles = _roles_of(cls)
    default = Capabilities()
    allowed = {f for role in roles for f in _ROLE_CAPABILITIES[role]}
    for role, fields in _ROLE_CAPABILITIES.items():
        for name in fields:
            expect(
                name in allowed or getattr(caps, name) == getattr(default, name),
                plugin,
                f"expected no {role} capability {name!r} on a "
                f"{'/'.join(sorted(roles)) or 'plugin of another role'}, got "
                f"{getattr(caps, name)!r}",
            )
    names = set(init_names(cls))
    for argument, value in caps.run_values.items():
        group, sep, _ = argument.partition("__")
        ok = argument in names or (
            bool(sep) and group in names and isinstance(getattr(plugin, group, None), Settings)
        )
        expect(ok, plugin, f"expected run_values key {argument!r} to be a constructor argument")
        expect(
            value in RUN_VALUES,
            plugin,
            f"expected run_values[{argument!r}] to be a documented run value, got {value!r} "
            f"(one of {', '.join(RUN_VALUES)})",
        )
    # a declared form is the one handed over (a subclass that does not declare its
    # parent's form inherits compiled_state, unused: it is not run compiled)
    form = plugin.compiled_state() if caps.compiled and hasattr(plugin, "compiled_state") else None
    if form is not None:
        expect(
            isinstance(form, CompiledForm),
            plugin,
            f"expected compiled_state() to return a CompiledForm, got {type(form).__name__}",
        )
        expect(
            caps.compiled is not None and form.kernel == caps.compiled,
            plugin,
            f"expected compiled_state() to return a form of the declared kernel "
            f"{caps.compiled!r}, got one of {form.kernel!r}",
        )
    if "rule" in roles:
        expect(
            caps.guarantee in ("identity", "step_identity", "long_run", "none"),
            plugin,
            f"expected guarantee to be a GuaranteeKind, got {caps.guarantee!r}",
        )
        stray = [n for n in caps.lambda_params if n not in names]
        expect(not stray, plugin, f"expected lambda_params {stray} to be constructor arguments")
    if caps.trainable:
        expect(
            "weights" in names and callable(getattr(plugin, "fit", None)),
            plugin,
            "expected a trainable predictor to take weights= and to have fit()",
        )
    stray = [k for k in caps.default_rule_params if k not in _RULE_VALUES]
    expect(not stray, plugin, f"expected default_rule_params to be rule run values, got {stray}")
