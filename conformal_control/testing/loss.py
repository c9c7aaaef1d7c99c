"""Contract checks for :class:`~conformal_control.core.base.Loss` plugins.

A loss's inputs (an interval record and the revealed truth) depend on the decision family
it goes with, so the kit cannot invent them: every loss class provides a
``_unit_test_inputs()`` classmethod returning a list of ``(record, truth)`` pairs, edge
cases included (e.g. an agent whose truth is missing, an interval with nothing sensed).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..core.base import Loss
from ._core import CheckList, ContractError, assert_unchanged, clone, expect, plugin_label, snapshot
from .common import (
    check_capabilities,
    check_docstring_parameters,
    check_get_params_round_trip,
    check_no_mutable_defaults,
    check_pickle_round_trip,
    check_repr,
    sample_behaviour,
)

__all__ = [
    "LAMBDAS",
    "check_loss",
    "check_loss_bounds_declared",
    "check_loss_components",
    "check_loss_deterministic",
    "check_loss_diagnostics",
    "check_loss_nan_lambda",
    "check_loss_no_mutation",
    "check_loss_unit_test_inputs",
    "check_loss_within_bounds",
    "loss_inputs",
]

#: The lambdas every loss is evaluated at (SI units, 1/s for the CBF loss).
LAMBDAS = (-1e3, -10.0, -1.0, -0.1, 0.0, 0.1, 1.0, 10.0, 1e3)


def loss_inputs(loss: Loss[Any, Any]) -> list[tuple[Any, Any]]:
    """The ``(record, truth)`` pairs from the loss's ``_unit_test_inputs()``."""
    fn = getattr(loss, "_unit_test_inputs", None)
    if fn is None:
        raise ContractError(
            f"{plugin_label(loss)}: expected the loss class to define a classmethod "
            "_unit_test_inputs() returning [(record, truth), ...] sample inputs, found none"
        )
    inputs = list(fn())
    expect(
        bool(inputs) and all(isinstance(x, tuple) and len(x) == 2 for x in inputs),
        loss,
        f"expected _unit_test_inputs() to return a non-empty list of (record, truth) pairs, "
        f"got {inputs!r:.200}",
    )
    return inputs


def _call(loss: Loss[Any, Any], record: Any, truth: Any, lam: float, i: int) -> float | None:
    try:
        return loss(record, truth, lam)
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(loss)}: expected the loss to evaluate sample input #{i} at "
            f"lambda={lam:g}, got {type(exc).__name__}: {exc}"
        ) from exc


# ---------------------------------------------------------------------------- checks
def check_loss_bounds_declared(loss: Loss[Any, Any]) -> None:
    """``bounds`` is a pair of finite numbers ``lo < hi`` (the guarantees need a bounded loss)."""
    bounds = getattr(loss, "bounds", None)
    ok = (
        isinstance(bounds, (tuple, list))
        and len(bounds) == 2
        and all(isinstance(v, (int, float)) and math.isfinite(v) for v in bounds)
        and bounds[0] < bounds[1]
    )
    expect(ok, loss, f"expected bounds = (lo, hi) with finite lo < hi, got {bounds!r}")


def check_loss_unit_test_inputs(loss: Loss[Any, Any]) -> None:
    """``_unit_test_inputs()`` provides sample ``(record, truth)`` pairs."""
    loss_inputs(loss)


def check_loss_within_bounds(loss: Loss[Any, Any]) -> None:
    """Every value is None (no loss) or a finite float within ``bounds``, for lambdas from
    -1000 to 1000."""
    lf = clone(loss)
    lo, hi = lf.bounds
    for i, (record, truth) in enumerate(loss_inputs(lf)):
        for lam in LAMBDAS:
            v = _call(lf, record, truth, lam, i)
            if v is None:
                continue
            expect(
                isinstance(v, (float, int, np.floating, np.integer)) and not isinstance(v, bool),
                lf,
                f"expected a float or None, got {type(v).__name__} (input #{i}, lambda={lam:g})",
            )
            expect(
                math.isfinite(v) and lo <= v <= hi,
                lf,
                f"expected the loss within its declared bounds [{lo:g}, {hi:g}], got {v!r} "
                f"(input #{i}, lambda={lam:g})",
            )


def check_loss_no_mutation(loss: Loss[Any, Any]) -> None:
    """Evaluating the loss (and its diagnostics) leaves record and truth untouched."""
    lf = clone(loss)
    for i, (record, truth) in enumerate(loss_inputs(lf)):
        before = snapshot((record, truth))
        _call(lf, record, truth, 0.5, i)
        lf.diagnostics(record, truth, 0.5)
        assert_unchanged(before[0], record, lf, f"record #{i}", "the loss")
        assert_unchanged(before[1], truth, lf, f"truth #{i}", "the loss")


def check_loss_deterministic(loss: Loss[Any, Any]) -> None:
    """Same inputs, same loss: across fresh copies, repeated calls and call order."""
    a, b = clone(loss), clone(loss)
    inputs = loss_inputs(a)
    first = [_call(a, r, t, lam, i) for i, (r, t) in enumerate(inputs) for lam in LAMBDAS]
    second = [
        _call(b, r, t, lam, i)
        for i, (r, t) in reversed(list(enumerate(inputs)))
        for lam in reversed(LAMBDAS)
    ][::-1]
    expect(
        [None if v is None else float(v) for v in first]
        == [None if v is None else float(v) for v in second],
        loss,
        "expected the same loss values from a fresh copy evaluating the inputs in another order",
    )


def check_loss_nan_lambda(loss: Loss[Any, Any]) -> None:
    """A NaN lambda gives a clear ValueError (or None), never a NaN loss."""
    lf = clone(loss)
    record, truth = loss_inputs(lf)[0]
    try:
        v = lf(record, truth, math.nan)
    except ValueError as exc:
        expect(str(exc).strip() != "", lf, "expected a ValueError with a message")
        return
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(lf)}: expected a ValueError for lambda=nan, got "
            f"{type(exc).__name__}: {exc}"
        ) from exc
    expect(v is None, lf, f"expected a ValueError (or None) for lambda=nan, got {v!r}")


def check_loss_diagnostics(loss: Loss[Any, Any]) -> None:
    """``diagnostics()`` returns a dict of str -> numbers (logged beside the loss)."""
    lf = clone(loss)
    for record, truth in loss_inputs(lf):
        d = lf.diagnostics(record, truth, 0.0)
        expect(isinstance(d, dict), lf, f"expected diagnostics() to return a dict, got {d!r}")
        bad = {
            k: v
            for k, v in d.items()
            if not isinstance(k, str) or not isinstance(v, (int, float, np.integer, np.floating))
        }
        expect(not bad, lf, f"expected diagnostics of str -> number, got {bad!r}")


def check_loss_components(loss: Loss[Any, Any]) -> None:
    """A loss that splits by agent (``components``): at one lambda for every agent, the
    largest agent term is the loss itself (None when no agent has one); an array of equal
    entries gives the same terms as the number; and agent i's term depends on its own
    entry only. A loss without ``components`` is not checked."""
    lf = clone(loss)
    if type(lf).components is Loss.components:
        return
    for i, (record, truth) in enumerate(loss_inputs(lf)):
        keys = getattr(record, "ids", None)
        if keys is None:
            return
        n = len(keys)
        for lam in (-1.0, 0.0, 0.5):
            comp = lf.components(record, truth, lam)
            expect(comp is not None, lf, f"expected components() on input #{i}, got None")
            assert comp is not None
            vals = np.asarray(comp.values, dtype=float)
            ok = np.isfinite(vals)
            whole = _call(lf, record, truth, lam, i)
            expect(
                (whole is None and not ok.any()) or (ok.any() and whole == vals[ok].max()),
                lf,
                f"expected the largest agent term {vals[ok].max() if ok.any() else None!r} to "
                f"be the loss {whole!r} (input #{i}, lambda={lam:g})",
            )
            same = np.asarray(lf.components(record, truth, np.full(n, lam)).values)
            expect(
                np.array_equal(same, vals, equal_nan=True),
                lf,
                f"expected an array of equal lambdas to give the terms of the number "
                f"(input #{i}, lambda={lam:g})",
            )
            if n >= 2:
                moved = np.full(n, lam)
                moved[0] = lam - 1.0
                other = np.asarray(lf.components(record, truth, moved).values)
                rest = np.asarray(comp.keys) != keys[0]
                expect(
                    np.array_equal(other[rest], vals[rest], equal_nan=True),
                    lf,
                    f"expected moving agent {keys[0]}'s lambda to change its own term only "
                    f"(input #{i})",
                )


@sample_behaviour.register(Loss)
def _behaviour(loss: Loss[Any, Any]) -> list[float | None]:
    """Values on ``_unit_test_inputs()`` at every lambda of :data:`LAMBDAS` (pickling check)."""
    return [loss(r, t, lam) for r, t in loss_inputs(loss) for lam in LAMBDAS]


#: Every loss check, in order.
check_loss = CheckList(
    "loss",
    [
        check_get_params_round_trip,
        check_repr,
        check_capabilities,
        check_loss_bounds_declared,
        check_loss_unit_test_inputs,
        check_loss_within_bounds,
        check_loss_no_mutation,
        check_loss_deterministic,
        check_loss_nan_lambda,
        check_loss_diagnostics,
        check_loss_components,
        check_pickle_round_trip,
        check_docstring_parameters,
        check_no_mutable_defaults,
    ],
)
