"""Contract checks for :class:`~conformal_control.core.base.DecisionFamily` plugins.

A family's observations and decision inputs come from the environment it is made for,
so every check drives the family through the stub loop of :mod:`.environment` in a
*partner* environment its class provides through hooks (classmethods):

``_unit_test_environment()``       a fresh :class:`~conformal_control.core.base.Environment`
                                   producing what the family reads, with a short episode
                                   (required)
``_unit_test_params()``            constructor kwargs of the instances to check
                                   (default ``[{}]``)
``_unit_test_conservativeness()``  optional, ``(decision) -> float``: how conservative a
                                   decision is (larger = more conservative). When given,
                                   :func:`check_decision_family_ordering` checks that a
                                   smaller lambda never gives a less conservative decision
                                   from the same state (the family's ordering).

Fresh copies are built with :func:`~conformal_control.testing.deep_clone` (the family's
own predictor, filter, ... are fresh copies too).
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np

from ..core.base import DecisionFamily, Environment
from ._core import CheckList, ContractError, deep_clone, expect, plugin_label
from .common import (
    check_capabilities,
    check_docstring_parameters,
    check_get_params_round_trip,
    check_no_mutable_defaults,
    check_pickle_round_trip,
    check_repr,
    sample_behaviour,
)
from .environment import AnyEnvironment, AnyFamily, EpisodeTrace, differ_or_fail, drive, partner

__all__ = [
    "ORDER_LAMBDAS",
    "PROBE_LAMBDAS",
    "check_decision_family",
    "check_decision_family_decisions",
    "check_decision_family_deterministic",
    "check_decision_family_no_mutation",
    "check_decision_family_ordering",
    "check_decision_family_reset",
    "partner_environment",
]

#: Each lambda drives one whole episode in :func:`check_decision_family_decisions`.
PROBE_LAMBDAS = (-1.0, 0.0, 0.1, 1.0)
#: Lambdas compared at the same state by :func:`check_decision_family_ordering`.
ORDER_LAMBDAS = (-10.0, -1.0, -0.1, 0.0, 0.1, 0.5, 1.0, 10.0)
#: Intervals probed by :func:`check_decision_family_ordering`.
ORDER_INTERVALS = 3


def partner_environment(family: AnyFamily) -> AnyEnvironment:
    """A fresh environment to drive ``family`` in, from ``_unit_test_environment()``."""
    env: AnyEnvironment = partner(family, "_unit_test_environment", Environment, "decision family")
    return env


def _episode(family: AnyFamily, **kw: Any) -> EpisodeTrace:
    """One episode of a fresh copy of ``family`` in a fresh partner environment."""
    return drive(partner_environment(family), deep_clone(family), subject=family, **kw)


# ---------------------------------------------------------------------------- checks
def check_decision_family_decisions(family: AnyFamily) -> None:
    """Over a whole episode at each of several lambdas: ``begin_interval``, ``decide`` and
    ``interval_record`` work, every decision and record is not None, and ``stats()`` is a
    dict of str -> numbers."""
    for lam in PROBE_LAMBDAS:
        trace = _episode(family, lambdas=(lam,))
        expect(
            trace.n_decisions > 0,
            family,
            f"expected decisions over an episode at lambda={lam:g}, got none "
            "(does the partner environment have control instants?)",
        )
        stats = trace.stats
        expect(isinstance(stats, dict), family, f"expected stats() to return a dict, got {stats!r}")
        bad = {
            k: v
            for k, v in stats.items()
            if not isinstance(k, str)
            or isinstance(v, bool)
            or not isinstance(v, (int, float, np.integer, np.floating))
        }
        expect(not bad, family, f"expected stats() of str -> number, got {bad!r:.200}")


def check_decision_family_no_mutation(family: AnyFamily) -> None:
    """``begin_interval`` and ``decide`` leave the observation and state they are handed
    unchanged (the environment may still use them)."""
    _episode(family, watch_family=True)


def check_decision_family_deterministic(family: AnyFamily) -> None:
    """Two fresh copies in two fresh environments decide and record identically."""
    a, b = _episode(family), _episode(family)
    differ_or_fail(family, a, b, "expected two fresh copies driven the same way to decide the same")


def check_decision_family_reset(family: AnyFamily) -> None:
    """``reset()`` restarts the family: a second episode of the same instance (reset in
    the middle of the first) repeats a fresh copy's."""
    fam = deep_clone(family)
    fresh = drive(partner_environment(family), fam, subject=family)
    drive(partner_environment(family), fam, subject=family, stop_after=2)
    again = drive(partner_environment(family), fam, subject=family)
    differ_or_fail(
        family, fresh, again, "expected reset() to restart the family: a second episode differs"
    )


def check_decision_family_ordering(family: AnyFamily) -> None:
    """Where the class declares ``_unit_test_conservativeness(decision) -> float``: from
    the same state, a smaller lambda never gives a less conservative decision (the
    toolkit's convention: smaller lambda = more conservative). Without it, nothing to
    check."""
    score = getattr(type(family), "_unit_test_conservativeness", None)
    if score is None:
        return

    def probe(fam: AnyFamily, state: Any, k: int, i: int) -> None:
        if k >= ORDER_INTERVALS:
            return
        values = []
        for lam in ORDER_LAMBDAS:
            twin = copy.deepcopy(fam)
            try:
                values.append(float(score(twin.decide(copy.deepcopy(state), lam))))
            except Exception as exc:
                raise ContractError(
                    f"{plugin_label(family)}: expected decide() at lambda={lam:g} and "
                    f"_unit_test_conservativeness() to work, got {type(exc).__name__}: {exc}"
                ) from exc
        for (lo, v_lo), (hi, v_hi) in zip(
            zip(ORDER_LAMBDAS, values, strict=True),
            zip(ORDER_LAMBDAS[1:], values[1:], strict=True),
            strict=False,
        ):
            ok = v_lo >= v_hi - 1e-9 * max(1.0, abs(v_hi)) or (
                math.isnan(v_lo) and math.isnan(v_hi)
            )
            expect(
                ok,
                family,
                f"expected a smaller lambda never to give a less conservative decision "
                f"(_unit_test_conservativeness, larger = more conservative); at interval {k}, "
                f"instant {i}: lambda {lo:g} -> {v_lo:g} but lambda {hi:g} -> {v_hi:g}",
            )

    _episode(family, probe=probe)


@sample_behaviour.register(DecisionFamily)
def _behaviour(family: AnyFamily) -> EpisodeTrace:
    """One episode in a fresh partner environment (for the pickling check)."""
    return drive(partner_environment(family), family, subject=family)


#: Every decision-family check, in order.
check_decision_family = CheckList(
    "family",
    [
        check_get_params_round_trip,
        check_repr,
        check_capabilities,
        check_decision_family_decisions,
        check_decision_family_no_mutation,
        check_decision_family_deterministic,
        check_decision_family_reset,
        check_decision_family_ordering,
        check_pickle_round_trip,
        check_docstring_parameters,
        check_no_mutable_defaults,
    ],
)
