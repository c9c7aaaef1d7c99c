"""Machinery shared by the contract checks: failures, check lists, instances, snapshots.

Expected failures (scikit-learn's ``_xfail_checks`` tag): a class may declare the checks
it is known to fail, with the reason, as a class attribute::

    class MyEnvironment(Environment):
        _xfail_checks: ClassVar[dict[str, str]] = {
            "check_environment_apply_after_done": "apply() after the end is ignored, by design",
        }

:class:`CheckList` then reports those checks as ``"xfailed"`` when they fail and as
``"xpassed"`` (a failure: the declaration is stale) when they pass; a test suite can add
declarations of its own through ``expected_failed_checks`` (a dict ``{check name:
reason}`` or a callable ``plugin -> dict``).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import inspect
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ..core.base import declared_test_params, param_names

__all__ = [
    "CheckList",
    "CheckResult",
    "ContractError",
    "ExpectedFailures",
    "assert_unchanged",
    "clone",
    "deep_clone",
    "differ",
    "expect",
    "expected_failures",
    "instances",
    "plugin_label",
    "snapshot",
    "unit_test_params",
]

Check = Callable[[Any], None]
#: ``{check name: reason}``, or a callable giving it for a plugin instance.
ExpectedFailures = Mapping[str, str] | Callable[[Any], Mapping[str, str]] | None
CheckStatus = Literal["passed", "failed", "xfailed", "xpassed"]


class ContractError(AssertionError):
    """A plugin broke its role's contract. The message says what was expected and what came."""


def expect(condition: bool | np.bool_, plugin: Any, what: str) -> None:
    """Raise :class:`ContractError` with ``what`` (expected ..., got ...) unless ``condition``."""
    if not condition:
        raise ContractError(f"{plugin_label(plugin)}: {what}")


def plugin_label(plugin: Any) -> str:
    """Readable ``Class(param=value, ...)`` label of a plugin (never raises).

    Objects without ``get_params`` (environments) are labelled from the attributes named
    like their ``__init__`` arguments.
    """
    cls = plugin if isinstance(plugin, type) else type(plugin)
    if isinstance(plugin, type):
        return cls.__name__
    try:
        if hasattr(plugin, "get_params"):
            params = plugin.get_params()
        else:
            params = {n: getattr(plugin, n) for n in init_names(cls) if hasattr(plugin, n)}
    except Exception:  # a broken get_params must not hide the real failure
        return cls.__name__
    args = ", ".join(f"{k}={_short(v)}" for k, v in params.items())
    return f"{cls.__name__}({args})"


def _short(value: Any) -> str:
    if hasattr(value, "get_params") and not isinstance(value, type):
        return type(value).__name__
    if isinstance(value, (list, tuple)) and len(value) > 3:
        return f"<{type(value).__name__} of {len(value)}>"
    if isinstance(value, np.ndarray):
        return f"<array {value.shape}>"
    text = repr(value)
    if "\n" in text or (text.startswith("<") and " at 0x" in text):
        return f"<{type(value).__name__}>"
    return text if len(text) <= 30 else text[:27] + "..."


@dataclass
class CheckResult:
    """Outcome of one check on one plugin instance.

    ``status`` is ``"passed"``, ``"failed"``, ``"xfailed"`` (failed as the plugin declared
    it would, ``reason`` says why) or ``"xpassed"`` (declared to fail but passed: the
    declaration is stale). :attr:`passed` is True for ``"passed"`` and ``"xfailed"``
    (pytest's ``strict=True`` reading: only a real or an unexpected outcome fails).
    """

    plugin: str
    check: str
    status: CheckStatus
    message: str = ""
    reason: str = ""

    @property
    def passed(self) -> bool:
        return self.status in ("passed", "xfailed")


def expected_failures(
    obj: Any, checks: Iterable[Check] | None = None, extra: ExpectedFailures = None
) -> dict[str, str]:
    """The checks ``obj`` is expected to fail: its class's ``_xfail_checks`` plus ``extra``.

    With ``checks``, every declared name must be one of theirs (a typo would otherwise
    silently keep a check from ever failing).
    """
    cls = obj if isinstance(obj, type) else type(obj)
    declared = getattr(cls, "_xfail_checks", None) or {}
    if callable(extra):
        extra = extra(obj)
    out: dict[str, str] = {}
    for source, table in (("_xfail_checks", declared), ("expected_failed_checks", extra or {})):
        if not isinstance(table, Mapping) or not all(
            isinstance(k, str) and isinstance(v, str) and v.strip() for k, v in table.items()
        ):
            raise ContractError(
                f"{cls.__name__}: expected {source} to be a dict of check name -> reason "
                f"(non-empty), got {table!r}"
            )
        out.update(table)
    if checks is not None:
        names = {c.__name__ for c in checks}
        unknown = sorted(set(out) - names)
        if unknown:
            raise ContractError(
                f"{cls.__name__}: expected the expected failures to name checks of its role, got "
                f"unknown {unknown}; its checks: {', '.join(sorted(names))}"
            )
    return out


def run_one(check: Check, obj: Any, reason: str | None) -> CheckResult:
    """Run ``check`` on ``obj``; ``reason``: why it is expected to fail (None: it is not)."""
    label = plugin_label(obj)
    try:
        check(obj)
    except Exception as exc:
        if reason is not None:
            return CheckResult(label, check.__name__, "xfailed", _message(exc), reason)
        return CheckResult(label, check.__name__, "failed", _message(exc))
    if reason is not None:
        return CheckResult(
            label,
            check.__name__,
            "xpassed",
            f"{label}: expected {check.__name__} to fail (declared: {reason}), but it passed; "
            "remove it from the expected failures",
            reason,
        )
    return CheckResult(label, check.__name__, "passed")


class CheckList(list[Check]):
    """A plain list of check functions ``check(plugin) -> None`` that can also be called.

    ``check_predictor(p)`` runs every check on ``p`` (an instance, or a class whose
    ``_unit_test_params()`` instances are all checked) and raises the first
    :class:`ContractError`; :meth:`run` returns one :class:`CheckResult` per check instead.
    Checks the plugin declares in ``_xfail_checks`` (or listed in
    ``expected_failed_checks``) may fail; if one passes, that is an error.
    """

    def __init__(self, role: str, checks: Iterable[Check] = ()) -> None:
        super().__init__(checks)
        self.role = role

    def __call__(self, plugin: Any, *, expected_failed_checks: ExpectedFailures = None) -> None:
        for obj in _as_instances(plugin):
            xfail = expected_failures(obj, self, expected_failed_checks)
            for check in self:
                if check.__name__ not in xfail:
                    check(obj)
                    continue
                result = run_one(check, obj, xfail[check.__name__])
                if result.status == "xpassed":
                    raise ContractError(result.message)

    def run(
        self, plugin: Any, *, expected_failed_checks: ExpectedFailures = None
    ) -> list[CheckResult]:
        """Run every check; collect failures instead of raising."""
        out: list[CheckResult] = []
        try:
            objs = _as_instances(plugin)
        except Exception as exc:
            return [CheckResult(plugin_label(plugin), "instantiate", "failed", _message(exc))]
        for obj in objs:
            try:
                xfail = expected_failures(obj, self, expected_failed_checks)
            except ContractError as exc:
                out.append(CheckResult(plugin_label(obj), "_xfail_checks", "failed", str(exc)))
                continue
            out.extend(run_one(check, obj, xfail.get(check.__name__)) for check in self)
        return out

    def __repr__(self) -> str:
        return f"CheckList({self.role!r}, [{', '.join(c.__name__ for c in self)}])"


def _message(exc: BaseException) -> str:
    if isinstance(exc, ContractError):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


def unit_test_params(cls: type) -> list[dict[str, Any]]:
    """The cheap constructor kwargs a class declares for the contract tests (default ``[{}]``)."""
    params = declared_test_params(cls)
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
            shown = "{" + ", ".join(f"{k!r}: {_short(v)}" for k, v in params.items()) + "}"
            raise ContractError(
                f"{cls.__name__}(**{shown}) failed ({type(exc).__name__}: {exc}); "
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


def deep_clone(plugin: Any) -> Any:
    """:func:`clone`, recursively: plugin-valued parameters are fresh copies too.

    A family owning a predictor and a safety filter is then independent of the original
    (two shallow clones would share, and reset, the same filter).
    """
    if not hasattr(plugin, "get_params") or isinstance(plugin, type):
        return plugin
    try:
        params = {k: deep_clone(v) for k, v in plugin.get_params().items()}
        return type(plugin)(**params)
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(plugin)}: expected type(plugin)(**plugin.get_params()) to build a "
            f"fresh copy, got {type(exc).__name__}: {exc}"
        ) from exc


def with_seed(plugin: Any, seed: int) -> Any:
    """A fresh copy, with ``random_state=seed`` if the plugin takes a ``random_state``."""
    params = plugin.get_params()
    if "random_state" in init_names(type(plugin)):
        params["random_state"] = seed
    return type(plugin)(**params)


def init_names(cls: type[Any]) -> list[str]:
    return param_names(cls)


# ------------------------------------------------------------------ input snapshots
def snapshot(obj: Any) -> Any:
    """Deep copy of ``obj`` for :func:`assert_unchanged`."""
    return copy.deepcopy(obj)


def _diff(before: Any, after: Any, path: str, callables_equal: bool = False) -> str | None:
    """Where ``after`` differs from ``before`` (None if equal, NaN == NaN).

    With ``callables_equal``, any two functions compare equal (two runs build different
    closures, e.g. a query's ``truth_provider``).
    """
    if callables_equal and _is_function(before) and _is_function(after):
        return None
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
            d = _diff(
                getattr(before, f.name),
                getattr(after, f.name),
                f"{path}.{f.name}",
                callables_equal,
            )
            if d:
                return d
        return None
    if isinstance(before, dict):
        if set(before) != set(after):
            return f"{path}: keys {sorted(before)} became {sorted(after)}"
        for k in before:
            d = _diff(before[k], after[k], f"{path}[{k!r}]", callables_equal)
            if d:
                return d
        return None
    if isinstance(before, (list, tuple)):
        if len(before) != len(after):
            return f"{path}: length {len(before)} became {len(after)}"
        for i, (x, y) in enumerate(zip(before, after, strict=True)):
            d = _diff(x, y, f"{path}[{i}]", callables_equal)
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
            return _diff(vars(before), vars(after), path, callables_equal)
    return None


def _is_function(obj: Any) -> bool:
    return inspect.isfunction(obj) or inspect.ismethod(obj) or isinstance(obj, functools.partial)


def differ(a: Any, b: Any, name: str) -> str | None:
    """Where two outcomes of the same computation differ (None: identical; functions
    compare equal, NaN == NaN)."""
    return _diff(a, b, name, callables_equal=True)


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
