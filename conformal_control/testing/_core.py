"""Machinery shared by the contract checks: failures, check lists, instances, snapshots."""

from __future__ import annotations

import copy
import dataclasses
import inspect
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "CheckList",
    "CheckResult",
    "ContractError",
    "assert_unchanged",
    "clone",
    "expect",
    "instances",
    "plugin_label",
    "snapshot",
    "unit_test_params",
]

Check = Callable[[Any], None]


class ContractError(AssertionError):
    """A plugin broke its role's contract. The message says what was expected and what came."""


def expect(condition: bool, plugin: Any, what: str) -> None:
    """Raise :class:`ContractError` with ``what`` (expected ..., got ...) unless ``condition``."""
    if not condition:
        raise ContractError(f"{plugin_label(plugin)}: {what}")


def plugin_label(plugin: Any) -> str:
    """Readable ``Class(param=value, ...)`` label of a plugin (never raises)."""
    cls = plugin if isinstance(plugin, type) else type(plugin)
    if isinstance(plugin, type):
        return cls.__name__
    try:
        params = plugin.get_params()
    except Exception:  # a broken get_params must not hide the real failure
        return cls.__name__
    args = ", ".join(f"{k}={_short(v)}" for k, v in params.items())
    return f"{cls.__name__}({args})"


def _short(value: Any) -> str:
    if hasattr(value, "get_params") and not isinstance(value, type):
        return type(value).__name__
    text = repr(value)
    return text if len(text) <= 30 else text[:27] + "..."


@dataclass
class CheckResult:
    """Outcome of one check on one plugin instance."""

    plugin: str
    check: str
    passed: bool
    message: str = ""


class CheckList(list):
    """A plain list of check functions ``check(plugin) -> None`` that can also be called.

    ``check_predictor(p)`` runs every check on ``p`` (an instance, or a class whose
    ``_unit_test_params()`` instances are all checked) and raises the first
    :class:`ContractError`; :meth:`run` returns one :class:`CheckResult` per check instead.
    """

    def __init__(self, role: str, checks: Iterable[Check] = ()) -> None:
        super().__init__(checks)
        self.role = role

    def __call__(self, plugin: Any) -> None:
        for obj in _as_instances(plugin):
            for check in self:
                check(obj)

    def run(self, plugin: Any) -> list[CheckResult]:
        """Run every check; collect failures instead of raising."""
        out: list[CheckResult] = []
        try:
            objs = _as_instances(plugin)
        except Exception as exc:
            return [CheckResult(plugin_label(plugin), "instantiate", False, _message(exc))]
        for obj in objs:
            label = plugin_label(obj)
            for check in self:
                try:
                    check(obj)
                except Exception as exc:
                    out.append(CheckResult(label, check.__name__, False, _message(exc)))
                else:
                    out.append(CheckResult(label, check.__name__, True))
        return out

    def __repr__(self) -> str:
        return f"CheckList({self.role!r}, [{', '.join(c.__name__ for c in self)}])"


def _message(exc: BaseException) -> str:
    if isinstance(exc, ContractError):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


def unit_test_params(cls: type) -> list[dict[str, Any]]:
    """The cheap constructor kwargs a class declares for the contract tests (default ``[{}]``)."""
    fn = getattr(cls, "_unit_test_params", None)
    params = [{}] if fn is None else list(fn())
    if not params or not all(isinstance(p, dict) for p in params):
        raise ContractError(
            f"{cls.__name__}._unit_test_params() must return a non-empty list of dicts of "
            f"constructor kwargs, got {params!r}"
        )
    return params


def instances(cls: type) -> list[Any]:
    """One instance of ``cls`` per entry of its ``_unit_test_params()``."""
    out = []
    for params in unit_test_params(cls):
        try:
            out.append(cls(**params))
        except Exception as exc:
            raise ContractError(
                f"{cls.__name__}(**{params!r}) failed ({type(exc).__name__}: {exc}); "
                "_unit_test_params() must return kwargs the constructor accepts"
            ) from exc
    return out


def _as_instances(plugin: Any) -> list[Any]:
    return instances(plugin) if isinstance(plugin, type) else [plugin]


def clone(plugin: Any) -> Any:
    """A fresh, unfitted copy built from ``get_params()`` (like ``sklearn.base.clone``)."""
    try:
        return type(plugin)(**plugin.get_params())
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(plugin)}: expected type(plugin)(**plugin.get_params()) to build a "
            f"fresh copy, got {type(exc).__name__}: {exc}"
        ) from exc


def with_seed(plugin: Any, seed: int) -> Any:
    """A fresh copy, with ``random_state=seed`` if the plugin takes a ``random_state``."""
    params = plugin.get_params()
    if "random_state" in _init_names(type(plugin)):
        params["random_state"] = seed
    return type(plugin)(**params)


def _init_names(cls: type) -> list[str]:
    names = getattr(cls, "_param_names", None)
    if names is not None:
        return list(names())
    sig = inspect.signature(cls.__init__)
    return [p for p in sig.parameters if p != "self"]


# ------------------------------------------------------------------ input snapshots
def snapshot(obj: Any) -> Any:
    """Deep copy of ``obj`` for :func:`assert_unchanged`."""
    return copy.deepcopy(obj)


def _diff(before: Any, after: Any, path: str) -> str | None:
    """Where ``after`` differs from ``before`` (None if equal, NaN == NaN)."""
    if isinstance(before, np.ndarray) or isinstance(after, np.ndarray):
        a, b = np.asarray(before), np.asarray(after)
        if a.shape != b.shape or a.dtype != b.dtype:
            return f"{path}: shape/dtype {a.shape}/{a.dtype} became {b.shape}/{b.dtype}"
        if a.dtype.kind in "fc":
            same = np.array_equal(a, b, equal_nan=True)
        else:
            same = np.array_equal(a, b)
        if not same:
            idx = np.argwhere(
                ~((a == b) | (np.isnan(a) & np.isnan(b))) if a.dtype.kind in "fc" else a != b
            )
            first = tuple(int(i) for i in idx[0]) if idx.size else ()
            return f"{path}{list(first)}: {a[first].item()!r} became {b[first].item()!r}"
        return None
    if dataclasses.is_dataclass(before) and not isinstance(before, type):
        for f in dataclasses.fields(before):
            d = _diff(getattr(before, f.name), getattr(after, f.name), f"{path}.{f.name}")
            if d:
                return d
        return None
    if isinstance(before, dict):
        if set(before) != set(after):
            return f"{path}: keys {sorted(before)} became {sorted(after)}"
        for k in before:
            d = _diff(before[k], after[k], f"{path}[{k!r}]")
            if d:
                return d
        return None
    if isinstance(before, (list, tuple)):
        if len(before) != len(after):
            return f"{path}: length {len(before)} became {len(after)}"
        for i, (x, y) in enumerate(zip(before, after, strict=True)):
            d = _diff(x, y, f"{path}[{i}]")
            if d:
                return d
        return None
    if isinstance(before, float) and isinstance(after, float):
        if before != after and not (np.isnan(before) and np.isnan(after)):
            return f"{path}: {before!r} became {after!r}"
        return None
    try:
        if before != after:
            return f"{path}: {before!r} became {after!r}"
    except Exception:  # objects without a usable ==: compare their attributes
        if hasattr(before, "__dict__"):
            return _diff(vars(before), vars(after), path)
    return None


def assert_unchanged(before: Any, after: Any, plugin: Any, name: str, during: str) -> None:
    """Fail if ``after`` differs from the snapshot ``before`` of input ``name``."""
    d = _diff(before, after, name)
    expect(
        d is None,
        plugin,
        f"expected {during} to leave its input {name} unchanged, but {d}",
    )


def max_abs_diff(a: Any, b: Any) -> float:
    """Largest absolute difference (NaN against NaN counts as 0, NaN against a number as inf)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape:
        return float("inf")
    if a.size == 0:
        return 0.0
    with np.errstate(invalid="ignore"):
        d = np.abs(a - b)
    both = np.isnan(a) & np.isnan(b)
    d = np.where(both, 0.0, np.where(np.isnan(d), np.inf, d))
    return float(d.max())


def close(a: Any, b: Any, rtol: float = 1e-6, atol: float = 1e-9) -> bool:
    """Element-wise closeness with NaN == NaN and equal shapes."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=rtol, atol=atol, equal_nan=True))
