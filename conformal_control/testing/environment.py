"""Contract checks for :class:`~conformal_control.core.base.Environment` (gymnasium's
``check_env``).

An environment's observations, decision inputs and truths have problem-specific types, and
so do the decisions it applies: the kit cannot invent them. Each check therefore drives
the environment through a short stub of the conformal loop with a *partner* decision
family that the environment class provides through hooks (classmethods):

``_unit_test_family()``   a fresh :class:`~conformal_control.core.base.DecisionFamily` whose
                          decisions the environment accepts (required)
``_unit_test_params()``   constructor kwargs of the instances to check, each giving a
                          short, finite episode (default ``[{}]``)

Decision families name their partner the other way round, ``_unit_test_environment()``
(see :mod:`.decision_family`). The stub loop is the loop's body without loss and rule::

    env.reset(); family.reset()
    while not env.done:                                   # at most MAX_INTERVALS
        family.begin_interval(env.sense())
        for _ in range(env.control_instants()):           # an int >= 0
            env.apply(family.decide(env.state(), lam))
            if env.done: break
        env.reveal(); family.interval_record()

with lambda cycling through :data:`DRIVE_LAMBDAS`, one value per interval. Environments
are not plugins (no ``get_params``): the checks work on deep copies, and the checks they
share with the plugin roles are pickling, docstring and mutable defaults.
"""

from __future__ import annotations

import copy
import dataclasses
import numbers
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeAlias

import numpy as np

from ..core.base import DecisionFamily, Environment
from ._core import CheckList, ContractError, differ, expect, plugin_label, snapshot
from .common import (
    check_docstring_parameters,
    check_no_mutable_defaults,
    check_pickle_round_trip,
    sample_behaviour,
)

__all__ = [
    "DRIVE_LAMBDAS",
    "MAX_INSTANTS",
    "MAX_INTERVALS",
    "EpisodeTrace",
    "IntervalTrace",
    "check_environment",
    "check_environment_apply_after_done",
    "check_environment_deterministic",
    "check_environment_interval_protocol",
    "check_environment_outputs_not_aliased",
    "check_environment_reset",
    "drive",
    "env_copy",
    "partner",
    "partner_family",
    "scribble",
]

#: Lambdas the stub loop decides with, one per interval, cycling.
DRIVE_LAMBDAS = (0.0, 0.1, -0.1, 0.5)
#: An episode must end within this many intervals ...
MAX_INTERVALS = 1_000
#: ... and this many control instants.
MAX_INSTANTS = 20_000


@dataclass
class IntervalTrace:
    """Copies of everything exchanged during one interval of the stub loop."""

    observation: Any
    instants: int
    states: list[Any] = field(default_factory=list)
    decisions: list[Any] = field(default_factory=list)
    truth: Any = None
    record: Any = None


@dataclass
class EpisodeTrace:
    """One episode of the stub loop: its intervals and the family's final ``stats()``."""

    intervals: list[IntervalTrace] = field(default_factory=list)
    stats: Any = None

    @property
    def n_decisions(self) -> int:
        return sum(len(iv.decisions) for iv in self.intervals)


#: Any environment / decision family (the kit checks them whatever they exchange).
AnyEnvironment: TypeAlias = Environment[Any, Any, Any, Any]
AnyFamily: TypeAlias = DecisionFamily[Any, Any, Any, Any]

Probe = Callable[[AnyFamily, Any, int, int], None]


#: Pristine partner of each class, built once by its hook (partners may be costly to build:
#: a scene to generate, a model to load); every caller gets a deep copy.
_PARTNERS: weakref.WeakKeyDictionary[type, Any] = weakref.WeakKeyDictionary()


def _a(name: str) -> str:
    return f"an {name}" if name[0] in "AEIOU" else f"a {name}"


def partner(obj: Any, hook: str, kind: type, what: str) -> Any:
    """A fresh copy of the partner ``type(obj).<hook>()`` returns (checked to be a ``kind``).

    Parameters
    ----------
    obj : object
        The plugin whose class names its partner.
    hook : str
        The classmethod that returns the partner (``_unit_test_family`` or
        ``_unit_test_environment``).
    kind : type
        The base class the partner must derive from.
    what : str
        What ``obj`` is, for the message.
    """
    cls = type(obj)
    fn = getattr(cls, hook, None)
    if fn is None:
        raise ContractError(
            f"{plugin_label(obj)}: expected the {what} class to define a classmethod {hook}() "
            f"returning {_a(kind.__name__)} to drive it with (what they exchange is "
            "problem-specific), found none"
        )
    if cls not in _PARTNERS:
        made = fn()
        expect(
            isinstance(made, kind),
            obj,
            f"expected {hook}() to return {_a(kind.__name__)}, got {type(made).__name__}",
        )
        _PARTNERS[cls] = made
    try:
        return copy.deepcopy(_PARTNERS[cls])
    except Exception:  # a partner that cannot be deep-copied: build a new one each time
        return fn()


def partner_family(env: AnyEnvironment) -> AnyFamily:
    """A fresh family to drive ``env`` with, from its class's ``_unit_test_family()``."""
    family: AnyFamily = partner(env, "_unit_test_family", DecisionFamily, "environment")
    return family


def env_copy(env: AnyEnvironment) -> AnyEnvironment:
    """A deep copy of ``env`` (the checks never touch the instance they are given)."""
    try:
        return copy.deepcopy(env)
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(env)}: expected the environment to be deep-copyable (the checks "
            f"run on copies), got {type(exc).__name__}: {exc}"
        ) from exc


def _call(subject: Any, what: str, fn: Callable[..., Any], *args: Any) -> Any:
    try:
        return fn(*args)
    except ContractError:
        raise
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(subject)}: expected {what} to work, got {type(exc).__name__}: {exc}"
        ) from exc


def _done(env: AnyEnvironment, subject: Any, when: str) -> bool:
    value = _call(subject, f"env.done ({when})", lambda: env.done)
    expect(
        isinstance(value, (bool, np.bool_)),
        subject,
        f"expected env.done to be a bool ({when}), got {type(value).__name__} {value!r}",
    )
    return bool(value)


def drive(
    env: AnyEnvironment,
    family: AnyFamily,
    *,
    subject: Any = None,
    lambdas: tuple[float, ...] = DRIVE_LAMBDAS,
    stop_after: int | None = None,
    isolate: bool = False,
    scribble_outputs: bool = False,
    watch_family: bool = False,
    probe: Probe | None = None,
    keep: bool = True,
) -> EpisodeTrace:
    """Run the stub loop (see the module docstring) and return copies of what was exchanged.

    Parameters
    ----------
    env, family : Environment, DecisionFamily
        Both are reset first.
    subject : object, optional
        The object whose contract is checked, named in failures (default ``env``).
    lambdas : tuple of float
        Lambda of each interval, cycling.
    stop_after : int, optional
        Stop after this many intervals (the episode is left unfinished).
    isolate : bool
        Hand the family deep copies of the observations and states, so that what is done
        to the environment's own outputs cannot reach it.
    scribble_outputs : bool
        After use, overwrite in place what ``sense``/``state``/``reveal`` returned (see
        :func:`scribble`), as a careless caller might.
    watch_family : bool
        Fail if the family modifies the observation or a state it is handed.
    probe : callable, optional
        ``probe(family, state, k, i)`` before each decision (k: interval, i: instant).
    keep : bool
        Keep copies of everything exchanged (False: only the number of decisions per
        interval and whether a truth and a record came, much cheaper).
    """
    subject = env if subject is None else subject
    _call(subject, "env.reset()", env.reset)
    _call(subject, "family.reset()", family.reset)
    trace = EpisodeTrace()
    keep_copy = snapshot if keep else _presence
    k = 0
    while not _done(env, subject, f"after {k} intervals"):
        if stop_after is not None and k >= stop_after:
            return trace
        expect(
            k < MAX_INTERVALS and trace.n_decisions < MAX_INSTANTS,
            subject,
            f"expected the episode to end (done True) within {MAX_INTERVALS} intervals and "
            f"{MAX_INSTANTS} control instants, got {k} intervals and {trace.n_decisions} "
            "instants without done (give _unit_test_params() a short, finite episode)",
        )
        lam = lambdas[k % len(lambdas)]
        obs = _call(subject, f"env.sense() (interval {k})", env.sense)
        before = snapshot(obs) if keep or watch_family else None
        handed = copy.deepcopy(obs) if isolate else obs
        _call(subject, f"family.begin_interval() (interval {k})", family.begin_interval, handed)
        if watch_family:
            _unchanged(family, before, obs, f"observation of interval {k}", "begin_interval()")
        n = _call(subject, f"env.control_instants() (interval {k})", env.control_instants)
        expect(
            isinstance(n, (int, np.integer)) and not isinstance(n, (bool, np.bool_)) and n >= 0,
            subject,
            f"expected control_instants() to return an int >= 0 (interval {k}), got "
            f"{type(n).__name__} {n!r}",
        )
        iv = IntervalTrace(observation=before if keep else None, instants=int(n))
        trace.intervals.append(iv)
        for i in range(int(n)):
            where = f"interval {k}, instant {i}"
            state = _call(subject, f"env.state() ({where})", env.state)
            state_before = snapshot(state) if keep or watch_family or probe else None
            if probe is not None:
                probe(family, state_before, k, i)
            handed_state = copy.deepcopy(state) if isolate else state
            decision = _call(
                subject,
                f"family.decide(state, {lam:g}) ({where})",
                family.decide,
                handed_state,
                lam,
            )
            expect(
                decision is not None,
                subject,
                f"expected decide() to return a decision ({where}), got None",
            )
            if watch_family:
                _unchanged(family, state_before, state, f"state of {where}", "decide()")
                _unchanged(family, before, obs, f"observation of interval {k}", "decide()")
            iv.states.append(state_before if keep else None)
            iv.decisions.append(keep_copy(decision))
            _call(subject, f"env.apply(decision) ({where})", env.apply, decision)
            if scribble_outputs:
                scribble(state)
            if _done(env, subject, f"after apply() at {where}"):
                break
        truth = _call(subject, f"env.reveal() (interval {k})", env.reveal)
        iv.truth = keep_copy(truth)
        record = _call(subject, f"family.interval_record() (interval {k})", family.interval_record)
        expect(
            record is not None,
            subject,
            f"expected interval_record() to return the interval's record (interval {k}), got None",
        )
        iv.record = keep_copy(record)
        if scribble_outputs:
            scribble(obs)
            scribble(truth)
        k += 1
    trace.stats = snapshot(_call(subject, "family.stats()", family.stats))
    return trace


def _presence(obj: Any) -> Any:
    """What a trace keeps without copies: whether something came (None or True)."""
    return None if obj is None else True


def _unchanged(family: Any, before: Any, after: Any, name: str, during: str) -> None:
    d = differ(before, after, name)
    expect(d is None, family, f"expected {during} to leave its input {name} unchanged, but {d}")


#: What :func:`scribble` writes over numbers it can reach.
SCRIBBLE = 1234.5


def scribble(obj: Any, _depth: int = 0, _seen: set[int] | None = None) -> None:
    """Overwrite, in place, every writable array and every number held in a list or dict
    reachable from ``obj`` (through lists, tuples, dicts and dataclass fields)."""
    seen = set() if _seen is None else _seen
    if _depth > 8 or id(obj) in seen:
        return
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        if obj.flags.writeable and obj.size:
            if obj.dtype.kind in "fc":
                obj[...] = SCRIBBLE
            elif obj.dtype.kind in "iu":
                obj[...] = 77
            elif obj.dtype.kind == "b":
                np.logical_not(obj, out=obj)
        return
    if isinstance(obj, (list, dict)):
        keys = range(len(obj)) if isinstance(obj, list) else list(obj)
        for key in keys:
            value = obj[key]
            if isinstance(value, numbers.Number) and not isinstance(value, bool):
                # numbers.Integral declares no constructor in the stubs; every concrete
                # integral type (int, np.int64, ...) takes an int
                obj[key] = (
                    type(value)(77)  # type: ignore[call-arg]
                    if isinstance(value, numbers.Integral)
                    else SCRIBBLE
                )
            else:
                scribble(value, _depth + 1, seen)
        return
    if isinstance(obj, tuple):
        for value in obj:
            scribble(value, _depth + 1, seen)
        return
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        for f in dataclasses.fields(obj):
            scribble(getattr(obj, f.name), _depth + 1, seen)


def differ_or_fail(env: Any, a: EpisodeTrace, b: EpisodeTrace, message: str) -> None:
    """Fail the check (naming ``env``) when two episode traces differ.

    Parameters
    ----------
    env : object
        The plugin under test.
    a, b : EpisodeTrace
        The traces compared.
    message : str
        What was expected; the first difference is appended.
    """
    d = differ(a, b, "episode")
    expect(d is None, env, f"{message}, but {d}")


# ---------------------------------------------------------------------------- checks
def check_environment_reset(env: AnyEnvironment) -> None:
    """``reset()`` works, twice in a row too; ``done`` is a bool, False right after it; a
    reset in the middle of an episode restarts it exactly."""
    e = env_copy(env)
    for _ in range(2):
        _call(e, "reset()", e.reset)
        expect(
            not _done(e, e, "right after reset()"),
            e,
            "expected done False right after reset(), got True (an episode without an "
            "interval cannot be checked: give _unit_test_params() a non-empty one)",
        )
    first = drive(e, partner_family(e))
    drive(e, partner_family(e), stop_after=2)
    again = drive(e, partner_family(e))
    differ_or_fail(
        e, first, again, "expected reset() in the middle of an episode to restart it exactly"
    )


def check_environment_interval_protocol(env: AnyEnvironment) -> None:
    """Driven by its partner family: ``done`` is a bool at every step, ``control_instants``
    an int >= 0, ``sense`` -> ``state``/``apply`` -> ``reveal`` work in that order over
    every interval, ``reveal`` returns a truth, the episode ends within
    :data:`MAX_INTERVALS` intervals and applies at least one decision."""
    e = env_copy(env)
    trace = drive(e, partner_family(e), keep=False)
    expect(
        trace.n_decisions > 0,
        e,
        f"expected at least one control instant over the episode, got {len(trace.intervals)} "
        "intervals and no decision",
    )
    missing = [k for k, iv in enumerate(trace.intervals) if iv.truth is None]
    expect(
        not missing,
        e,
        f"expected reveal() to return the truth of every interval, got None for intervals "
        f"{missing[:5]}",
    )


def check_environment_deterministic(env: AnyEnvironment) -> None:
    """Two copies driven by fresh partner families give identical episodes."""
    a = drive(env_copy(env), partner_family(env))
    b = drive(env_copy(env), partner_family(env))
    differ_or_fail(env, a, b, "expected two copies driven the same way to give the same episode")


def check_environment_outputs_not_aliased(env: AnyEnvironment) -> None:
    """A caller that overwrites what ``sense()``, ``state()`` and ``reveal()`` returned
    changes nothing the environment does next, in this episode or after ``reset()``
    (hand out copies, not views of internal state)."""
    reference = drive(env_copy(env), partner_family(env), isolate=True)
    e = env_copy(env)
    scribbled = drive(e, partner_family(e), isolate=True, scribble_outputs=True)
    hint = (
        "expected the environment's outputs to be copies: after the caller overwrote what "
        "sense()/state()/reveal() returned"
    )
    differ_or_fail(e, reference, scribbled, f"{hint}, later outputs changed")
    after = drive(e, partner_family(e), isolate=True)
    differ_or_fail(e, reference, after, f"{hint}, the next episode after reset() changed")


def check_environment_apply_after_done(env: AnyEnvironment) -> None:
    """``apply()`` once the episode is over raises a ``RuntimeError`` (or ``ValueError``)
    saying so, instead of silently moving a finished world (or declare the behaviour in
    ``_xfail_checks``)."""
    e = env_copy(env)
    trace = drive(e, partner_family(e))
    decisions = [d for iv in trace.intervals for d in iv.decisions]
    expect(bool(decisions), e, "expected at least one decision over the episode, got none")
    try:
        e.apply(copy.deepcopy(decisions[-1]))
    except (RuntimeError, ValueError) as exc:
        expect(
            bool(str(exc).strip()),
            e,
            f"expected the {type(exc).__name__} of apply() after done to say why, got no message",
        )
        return
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(e)}: expected apply() after the episode ended to raise a "
            f"RuntimeError saying so, got {type(exc).__name__}: {exc}"
        ) from exc
    raise ContractError(
        f"{plugin_label(e)}: expected apply() after the episode ended (done True) to raise a "
        "RuntimeError saying so, got no error"
    )


@sample_behaviour.register(Environment)
def _behaviour(env: AnyEnvironment) -> EpisodeTrace:
    """One episode driven by a fresh partner family (for the pickling check)."""
    return drive(env, partner_family(env))


#: Every environment check, in order.
check_environment = CheckList(
    "environment",
    [
        check_environment_reset,
        check_environment_interval_protocol,
        check_environment_deterministic,
        check_environment_outputs_not_aliased,
        check_environment_apply_after_done,
        check_pickle_round_trip,
        check_docstring_parameters,
        check_no_mutable_defaults,
    ],
)
