"""The generic core: one small abstract base class per role of the conformal loop.

Conformal decision theory runs a family of decision functions ``D^lambda``, ordered by
conservativeness, in an environment; after each interval the truth is revealed, a loss
scores the interval and an update rule moves lambda. Those four roles are all the loop
(:mod:`conformal_control.core.loop`) knows:

=======================  =============================================================
``Environment``          the world: observation at a sampling time, the decision input
                         at each control instant, the plant, the truth of an interval
``SingleStepEnvironment``  the same with one decision per interval (plain online problems)
``DecisionFamily``       the family ``D^lambda``; it owns whatever it needs to decide
                         (a trajectory predictor, a safety filter, ...)
``Loss``                 interval record + truth + lambda -> scalar loss (or ``None``)
``UpdateRule``           loss -> next lambda, with the guarantee it keeps
=======================  =============================================================

They are generic in the types they exchange (``Environment[ObsT, StateT, DecisionT,
TruthT]``, ``DecisionFamily[ObsT, StateT, DecisionT, RecordT]``, ``Loss[RecordT,
TruthT]``), as gymnasium's ``Env[ObsType, ActType]`` is, so a type checker can tell that
an environment, a family and a loss fit together.

The flagship's roles (predictor, barrier, safety filter, fallback, reference controller,
dynamics) live beside their users: :mod:`conformal_control.predictors.base` and
:mod:`conformal_control.families.cbf.roles`.

Every plugin follows the scikit-learn / river habits: constructor arguments are stored
unchanged as attributes of the same name (so :meth:`Plugin.get_params` can report them
and a run can write its full configuration), no work happens in ``__init__``, and state
learned or accumulated while running lives in attributes ending in ``_`` set by
``reset``.

Sign convention (all of the toolkit): a *smaller* lambda is *more conservative*.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import inspect
import math
import warnings
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar, Generic, TypeVar

from .capabilities import (
    CAPABILITY_FIELDS,
    FORMER_FLAGS,
    Capabilities,
    CompiledForm,
    GuaranteeKind,
)
from .exceptions import ConformalControlDeprecationWarning

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "Capabilities",
    "CompiledForm",
    "DecisionFamily",
    "Environment",
    "GuaranteeKind",
    "KeyedLosses",
    "Loss",
    "LossFunction",
    "Plugin",
    "Settings",
    "SingleStepEnvironment",
    "UpdateRule",
    "declared_test_params",
    "expand_settings",
    "first_test_instance",
    "flat_params",
    "param_names",
]

ObsT = TypeVar("ObsT")
StateT = TypeVar("StateT")
DecisionT = TypeVar("DecisionT")
TruthT = TypeVar("TruthT")
RecordT = TypeVar("RecordT")

#: An interval's loss as a function of lambda (``None``: no loss for that interval).
LossFunction = Callable[[float], "float | None"]

#: What a loop may run lambda as: ``"run"`` (one lambda for the whole run, the paper's) or
#: ``"agent"`` (one entry per agent, each learned from that agent's own loss; see
#: :class:`~conformal_control.core.monitor.AgentMonitor`).
LAMBDA_PER: tuple[str, ...] = ("run", "agent")


@dataclasses.dataclass(frozen=True)
class KeyedLosses:
    """An interval's loss split by key (by agent): what lambda's vector form learns from.

    Returned by :meth:`Loss.components`. Key ``i``'s loss is its own term of the
    interval's loss, evaluated with its own entry of lambda (for the CBF gap loss,
    ``s(max_t gap_i(t) + lambda_i)``); the interval's loss at that lambda is the
    largest of them.

    Attributes
    ----------
    keys : ndarray of shape (n,)
        The keys scored this interval (agent ids, int64).
    values : ndarray of shape (n,)
        Key ``i``'s loss; NaN where the key has no loss this interval (no truth).
    at : callable or None
        ``at(i, lam)``: key ``i``'s loss re-evaluated at another lambda (for rules with
        ``uses_loss_function``); None when the loss cannot re-evaluate it.
    """

    keys: np.ndarray
    values: np.ndarray
    at: Callable[[int, float], float | None] | None = None


#: Class-body values that are never a former flag (a method or property of that name).
_NOT_FLAGS = (property, classmethod, staticmethod, functools.cached_property)


@functools.lru_cache(maxsize=1024)
def _init_param_names(init: Callable[..., None]) -> tuple[str, ...]:
    """The named parameters of an ``__init__`` (cached: a signature costs tens of
    microseconds and ``get_params`` is called for every plugin of every episode)."""
    if init is object.__init__:
        return ()
    sig = inspect.signature(init)
    return tuple(
        p.name
        for p in sig.parameters.values()
        if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
    )


@dataclasses.dataclass(frozen=True)
class Settings:
    """Base of the small frozen groups of related parameters a plugin takes as one
    argument (the sampling MPC's ``Sampling``, ``Costs`` and ``Limits``, ...).

    A plugin stores the group as given; :meth:`Plugin.get_params` with ``deep=True``
    reports its fields as ``<group>__<field>`` and :meth:`Plugin.set_params` (and the
    plugin's constructor) take them in that form (``costs__w_goal=2.0``), so the
    registry's ``(name, params)`` form, a run's ``config.json`` and sweeps address a
    field of a group as plain data. Subclasses validate their fields in the plugin's
    ``reset``, as every parameter is.
    """

    def get_params(self) -> dict[str, Any]:
        """The fields of the group (name -> value)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def replace(self, **changes: Any) -> Settings:
        """A copy with ``changes`` applied (unknown names raise ``ValueError``)."""
        known = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise ValueError(
                f"{type(self).__name__} has no field(s) {', '.join(unknown)}; "
                f"its fields: {', '.join(sorted(known))}"
            )
        return dataclasses.replace(self, **changes)


def param_names(cls: type) -> list[str]:
    """The named parameters of a class's ``__init__`` (a plugin's: those
    :meth:`Plugin.get_params` reports).

    Parameters
    ----------
    cls : type
        The class.
    """
    return list(_init_param_names(cls.__init__))  # type: ignore[misc]  # the class's own


_T = TypeVar("_T")


def first_test_instance(cls: type[_T]) -> _T:
    """The first instance a class declares for the contract kit (``cls(**params)`` of the
    first entry of its ``_unit_test_params()`` classmethod, the kit's hook; ``cls()``
    without one): the partner a plugin's own checks are run with.

    Parameters
    ----------
    cls : type
        A plugin or environment class.
    """
    return cls(**declared_test_params(cls)[0])


def declared_test_params(cls: type) -> list[dict[str, Any]]:
    """The constructor kwargs a class declares for the contract kit: what its
    ``_unit_test_params()`` classmethod (the kit's hook) returns, ``[{}]`` without one.

    Parameters
    ----------
    cls : type
        A plugin or environment class.
    """
    hook = getattr(cls, "_unit_test_params", None)
    return [{}] if hook is None else list(hook())


def flat_params(plugin: Any) -> dict[str, Any]:
    """A plugin's parameters as plain data (for ``config.json``): each
    :class:`Settings` group given as its ``<group>__<field>`` entries (see
    :func:`expand_settings`), every other parameter as it is."""
    return expand_settings(plugin.get_params())


def expand_settings(params: dict[str, Any]) -> dict[str, Any]:
    """``params`` with each :class:`Settings` value replaced by its fields as
    ``<name>__<field>`` entries (plain data a constructor, ``set_params`` and the
    registry's ``(name, params)`` form take back)."""
    out: dict[str, Any] = {}
    for key, value in params.items():
        if isinstance(value, Settings):
            out.update({f"{key}__{k}": v for k, v in value.get_params().items()})
        else:
            out[key] = value
    return out


class Plugin:
    """Mixin giving every plugin ``get_params`` / ``set_params`` like scikit-learn estimators.

    Subclasses store each ``__init__`` argument under an attribute of the same name and do
    no work in ``__init__`` (validation happens in ``reset``).

    What a plugin class declares about itself -- the compiled form it has, the run values
    it takes, its role's flags -- is one
    :class:`~conformal_control.core.capabilities.Capabilities` object, :attr:`capabilities`,
    declared with keywords in the ``class`` statement
    (``class APFBarrier(Barrier, compiled="apf", run_values={...})``).
    """

    #: What this class declares about itself (see
    #: :class:`~conformal_control.core.capabilities.Capabilities`).
    capabilities: ClassVar[Capabilities] = Capabilities()

    def __init_subclass__(cls, **declared: Any) -> None:
        own = {k: declared.pop(k) for k in list(declared) if k in CAPABILITY_FIELDS}
        try:
            super().__init_subclass__(**declared)
        except TypeError:
            if not declared:
                raise
            close = difflib.get_close_matches(next(iter(declared)), CAPABILITY_FIELDS, n=1)
            raise TypeError(
                f"{cls.__name__}: no capability {', '.join(declared)}"
                f"{f' (did you mean {close[0]}?)' if close else ''}; the capabilities are "
                f"{', '.join(CAPABILITY_FIELDS)}"
            ) from None
        if "capabilities" in vars(cls):
            raise TypeError(
                f"{cls.__name__}: declare capabilities as keywords of the class statement "
                f"(class {cls.__name__}(Base, batchable=True)), not as an attribute"
            )
        for old, new in FORMER_FLAGS.items():
            value = vars(cls).get(old)
            if value is None or new in own or isinstance(value, _NOT_FLAGS) or callable(value):
                continue
            warnings.warn(
                f"{cls.__name__}.{old} = ... is deprecated: declare class "
                f"{cls.__name__}(..., {new}={value!r}) (removed in 0.4, not before 2027-06-30)",
                ConformalControlDeprecationWarning,
                stacklevel=3,
            )
            own[new] = value
        inherited: Capabilities = getattr(cls, "capabilities", Capabilities())
        cls.capabilities = inherited.replace(**{"compiled": None, **own})

    def compiled_state(self) -> CompiledForm | None:
        """What the compiled engine needs to run this plugin as the kernel its capabilities'
        :attr:`~conformal_control.core.capabilities.Capabilities.compiled` names: that
        kernel's form holding the plugin's constants, validated (raises ``ValueError`` as
        the plugin's own checks do). None (the default): the kernel takes no constants, or
        the class declares none."""
        return None

    #: Former flat constructor keywords now held by a :class:`Settings` group: old name
    #: -> ``<group>__<field>``. Still accepted (by the constructor, :meth:`set_params`
    #: and attribute reads) with a ``DeprecationWarning`` naming the new form.
    renamed_params: ClassVar[dict[str, str]] = {}

    @classmethod
    def _param_names(cls) -> list[str]:
        return param_names(cls)

    def get_params(self, deep: bool = False) -> dict[str, Any]:
        """Return the constructor parameters of this plugin (name -> value).

        Parameters
        ----------
        deep : bool
            Also report the fields of every :class:`Settings` group as
            ``<group>__<field>`` (the form :meth:`set_params` takes).
        """
        out = {name: getattr(self, name) for name in self._param_names() if hasattr(self, name)}
        if deep:
            for name, value in list(out.items()):
                if isinstance(value, Settings):
                    out.update({f"{name}__{k}": v for k, v in value.get_params().items()})
        return out

    def set_params(self, **params: Any) -> Plugin:
        """Set constructor parameters by name, a :class:`Settings` group's field as
        ``<group>__<field>`` (unknown names raise ``ValueError``; a name of
        :attr:`renamed_params` is mapped with a ``DeprecationWarning``)."""
        known = set(self._param_names())
        for key, value in params.items():
            key = self._renamed(key, stacklevel=3)
            group, sep, field = key.partition("__")
            if sep and group in known and isinstance(getattr(self, group, None), Settings):
                setattr(self, group, getattr(self, group).replace(**{field: value}))
            elif key in known:
                setattr(self, key, value)
            else:
                raise ValueError(
                    f"{type(self).__name__} has no parameter {key!r}; "
                    f"its parameters: {', '.join(sorted(known)) or 'none'}"
                )
        return self

    def _renamed(self, key: str, stacklevel: int) -> str:
        new = type(self).renamed_params.get(key)
        if new is None:
            return key
        group, _, field = new.partition("__")
        warnings.warn(
            f"{type(self).__name__}({key}=...) is deprecated: give {group}="
            f"{type(getattr(self, group, None)).__name__}({field}=...) or {new}=... "
            f"(removed in 0.4, not before 2027-06-30)",
            ConformalControlDeprecationWarning,
            stacklevel=stacklevel + 1,
        )
        return new

    def _set_grouped(self, extra: dict[str, Any]) -> None:
        """Apply the constructor's extra keywords (call at the end of ``__init__``):
        ``<group>__<field>`` entries, and former flat names (:attr:`renamed_params`)
        with a ``DeprecationWarning``; anything else is a ``TypeError``, as Python's."""
        for key in extra:
            if key not in type(self).renamed_params and "__" not in key:
                raise TypeError(
                    f"{type(self).__name__}.__init__() got an unexpected keyword argument {key!r}"
                )
        known = set(self._param_names())
        for key, value in extra.items():
            key = self._renamed(key, stacklevel=4)
            group, _, field = key.partition("__")
            current = getattr(self, group, None) if group in known else None
            if not isinstance(current, Settings):
                raise TypeError(
                    f"{type(self).__name__}.__init__() got an unexpected keyword argument {key!r}"
                )
            setattr(self, group, current.replace(**{field: value}))

    if not TYPE_CHECKING:  # hidden from type checkers: a typo stays an error for them

        def __getattr__(self, name: str) -> Any:
            # only reached for a missing attribute: a former flat parameter reads its field
            new = type(self).renamed_params.get(name)
            if new is None:
                raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
            group, _, field = self._renamed(name, stacklevel=2).partition("__")
            return getattr(getattr(self, group), field)

    @classmethod
    def summary(cls) -> str:
        """One-line description of the plugin: the first line of its docstring."""
        doc = inspect.getdoc(cls) or ""
        return doc.strip().splitlines()[0] if doc.strip() else cls.__name__

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"


# --------------------------------------------------------------------------------------
class Environment(ABC, Generic[ObsT, StateT, DecisionT, TruthT]):
    """The world the conformal loop acts on (episodic, gymnasium-like).

    One *interval* k spans the control instants between sampling times k and k+1. The
    loop calls, per interval: :meth:`sense` once, then :meth:`state` and :meth:`apply`
    at each of the :meth:`control_instants` (stopping early when :attr:`done`), then
    :meth:`reveal` once.
    """

    @abstractmethod
    def reset(self) -> None:
        """Start a new episode (validate parameters here, not in ``__init__``)."""

    @property
    @abstractmethod
    def done(self) -> bool:
        """Whether the episode is over (no further interval will be run)."""

    @abstractmethod
    def sense(self) -> ObsT:
        """Observation at the sampling time (what the decision family plans from)."""

    @abstractmethod
    def control_instants(self) -> int:
        """Number of control instants in the interval starting now."""

    @abstractmethod
    def state(self) -> StateT:
        """The decision input at the current control instant."""

    @abstractmethod
    def apply(self, decision: DecisionT) -> None:
        """Apply a decision for one control step and advance time."""

    @abstractmethod
    def reveal(self) -> TruthT:
        """Ground truth over the interval that just finished."""


class SingleStepEnvironment(Environment[ObsT, ObsT, DecisionT, TruthT]):
    """An environment with exactly one decision per interval.

    For plain online decision problems (a factory's speed, a prediction set per time
    step): subclasses implement :meth:`observe` instead of ``sense``/``state``/
    ``control_instants``; the decision input is the interval's observation.
    """

    @abstractmethod
    def observe(self) -> ObsT:
        """Observation of the step about to be decided."""

    def sense(self) -> ObsT:
        self._observation_ = self.observe()
        return self._observation_

    def control_instants(self) -> int:
        return 1

    def state(self) -> ObsT:
        return self._observation_


class DecisionFamily(Plugin, ABC, Generic[ObsT, StateT, DecisionT, RecordT]):
    """The family {D^lambda} of decision functions, ordered by conservativeness.

    A family owns what it needs to decide: the flagship family owns a trajectory
    predictor, a barrier and a safety filter; the loop only hands it the observation at
    each sampling time and asks for decisions.
    """

    def reset(self) -> None:
        """Reset between episodes (validate parameters here)."""

    @abstractmethod
    def begin_interval(self, observation: ObsT) -> None:
        """Receive the sensor's observation at a sampling time (and plan from it)."""

    @abstractmethod
    def decide(self, state: StateT, lam: float) -> DecisionT:
        """Decision D^lam(state) at the current control instant.

        With lambda run per agent (a loop with ``lambda_per="agent"``, for a family whose
        :meth:`lambda_keys` gives keys) ``lam`` is an array instead: one entry per key of
        :meth:`lambda_keys`, in that order.
        """

    def lambda_keys(self) -> np.ndarray | None:
        """The keys of lambda's entries for the current interval (valid after
        :meth:`begin_interval`), in the order :meth:`decide` takes them: agent ids
        (int64). None (the default): the family takes one lambda only."""
        return None

    def lambda_floors(self) -> np.ndarray | None:
        """Per key of :meth:`lambda_keys`, the lowest lambda at which that key's part of
        the decision stayed satisfiable over the interval just decided (valid between the
        interval's last :meth:`decide` and the next :meth:`begin_interval`): what a
        per-agent floor that binds only where it must reads (the loop's
        ``lambda_floor_row``). None (the default): the family does not say."""
        return None

    @abstractmethod
    def interval_record(self) -> RecordT:
        """Everything the loss needs about the decisions of the current interval."""

    def stats(self) -> dict[str, float]:
        """Counters accumulated since :meth:`reset` (merged into run metrics)."""
        return {}


class Loss(Plugin, ABC, Generic[RecordT, TruthT]):
    """Loss of the decisions taken over one interval, once the truth is revealed.

    ``bounds`` declares the range the loss takes values in (needed by the guarantees).
    Returning ``None`` means "no loss for this interval" (e.g. nothing was sensed); the
    loop then does not update lambda.
    """

    bounds: ClassVar[tuple[float, float]] = (-0.5, 0.5)

    @abstractmethod
    def __call__(self, record: RecordT, truth: TruthT, lam: float) -> float | None:
        """Loss l_k of interval k evaluated with the conformal variable ``lam``."""

    def diagnostics(self, record: RecordT, truth: TruthT, lam: Any) -> dict[str, float]:
        """Extra per-interval figures to log beside the loss (optional); ``lam`` as for
        :meth:`components` (an array when lambda is run per agent)."""
        return {}

    def components(self, record: RecordT, truth: TruthT, lam: Any) -> KeyedLosses | None:
        """The interval's loss split by key (agent), each key's term with its own lambda.

        ``lam`` is a float, or an array with one entry per key of the record (the family's
        :meth:`DecisionFamily.lambda_keys`, in that order). None (the default): the loss
        is not a function of per-key terms, and lambda cannot be run per agent with it.
        """
        return None


class UpdateRule(Plugin, ABC):
    """Online update of the conformal variable lambda.

    Convention: :meth:`update` receives the loss l_k of the interval that just ended and
    returns lambda_{k+1}; a loss above target must not increase lambda (smaller lambda
    is more conservative).

    The protocol the loop and the monitor rely on is declared here, not discovered:

    ``epsilon``            target average loss
    ``last_step_``         the step eta_k of the last update (NaN if the rule has none)
    ``n_clipped_``         updates whose lambda was clipped into [lambda_min, lambda_max]
    ``lambda_min/max``     clipping bounds (-inf, inf: none)

    and, in its :class:`~conformal_control.core.capabilities.Capabilities`: ``guarantee`` (the
    :data:`~conformal_control.core.capabilities.GuaranteeKind` the rule
    keeps), ``fixed_step`` (lambda_{k+1} = lambda_k + eta (eps - l_k) with a constant
    ``eta``, then :attr:`step` is that eta), ``uses_loss_function`` (the rule wants l_k(.)
    before each update: counterfactuals), ``lambda_params``.
    """

    #: Target average loss of the rule (epsilon).
    epsilon: float
    lambda_min: float = -math.inf
    lambda_max: float = math.inf

    #: Updates whose output was clipped (set by ``reset``).
    n_clipped_: int = 0
    #: Step eta_k of the last update (NaN when the rule has no such step).
    last_step_: float = math.nan

    @property
    def step(self) -> float | None:
        """The constant step eta of a fixed-step rule, else ``None``."""
        return None

    def set_loss_function(self, fn: LossFunction | None) -> None:
        """Receive ``fn(lam) -> loss`` for the next update (ignored by default)."""

    def long_run_bound(self, n: int, lambdas: Any) -> float | None:
        """Bound on |mean loss - epsilon| after ``n`` updates (lambda_1..lambda_{n+1})."""
        return None

    @abstractmethod
    def reset(self) -> float:
        """Reset the rule and return lambda_1."""

    @abstractmethod
    def update(self, loss: float) -> float:
        """Consume l_k and return lambda_{k+1}."""

    @property
    @abstractmethod
    def value(self) -> float:
        """Current lambda."""
