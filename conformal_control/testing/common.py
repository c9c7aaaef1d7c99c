"""Checks every plugin role shares: parameters stored unchanged, ``get_params`` round trip."""

from __future__ import annotations

import inspect
from typing import Any

from ._core import ContractError, _init_names, expect, plugin_label, unit_test_params

__all__ = ["check_get_params_round_trip", "check_repr"]


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
    missing = [n for n in _init_names(type(plugin)) if n not in params]
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
