"""What a plugin class declares about itself, in one object: :class:`Capabilities` (like
scikit-learn's tags), and what it hands the compiled engine, :class:`CompiledForm`.

A plugin declares its capabilities with keywords in its ``class`` statement
(:class:`~conformal_control.core.base.Plugin` folds them into ``Cls.capabilities``); the
toolkit reads them there (the compiled engine, the run's builder, the guarantee monitor,
benchmarks and sweeps), and ``conformal_control.testing.check_capabilities`` checks them.
This module imports nothing of the package, so every layer may read a capability.
"""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Mapping
from typing import Any, ClassVar, Literal

__all__ = [
    "CAPABILITY_FIELDS",
    "FORMER_FLAGS",
    "Capabilities",
    "CompiledForm",
    "GuaranteeKind",
]

#: What an update rule guarantees, read by
#: :class:`~conformal_control.core.monitor.GuaranteeMonitor`:
#: ``"identity"`` (fixed step: exact identity + Theorem-2 bound), ``"step_identity"``
#: (variable step: weighted identity + long-run bound), ``"long_run"`` (a bound on
#: |mean loss - epsilon|) or ``"none"``.
GuaranteeKind = Literal["identity", "step_identity", "long_run", "none"]


@dataclasses.dataclass(frozen=True)
class Capabilities:
    """What a plugin class declares about itself, in one object (like scikit-learn's tags).

    Read it as ``Cls.capabilities`` (or on an instance). A class declares its own values
    with keywords in its ``class`` statement; every other field is its parent's::

        class MyPredictor(Predictor, batchable=True, run_values={"random_state": "seed"}):
            ...

    except :attr:`compiled`, which is never inherited (a subclass may compute something
    else than its parent's compiled code does; it declares the name again if it does not).
    Fields of another role than the plugin's keep their defaults and mean nothing.
    ``conformal_control.testing.check_capabilities`` checks a plugin's declaration.

    Attributes
    ----------
    compiled : str or None
        Every role: the compiled form the class declares (the compiled engine runs it as
        that kernel, reading the constants
        :meth:`~conformal_control.core.base.Plugin.compiled_state` hands it).
    run_values : Mapping[str, str]
        Every role: constructor argument -> the documented run value
        (:data:`~conformal_control.core.spec.RUN_VALUES`) the run's builder passes for it when
        the caller did not give it.
    batchable : bool
        Predictor: its forecasts cost a few milliseconds at most per sampling time
        (nothing fitted by an iterative optimiser): benchmarks and sweeps run many episodes
        of it in one process instead of one worker per episode (was ``fast``).
    trainable : bool
        Predictor: it takes ``weights=FOLDER`` and is trained by ``train-predictor`` (a
        run without weights trains and caches them).
    requires_ground_truth : bool
        Predictor: it reads the true future (the oracle baseline); reports mark its runs
        and the contract kit feeds it a truth.
    guarantee : {"identity", "step_identity", "long_run", "none"}
        Update rule: what it guarantees (read by the guarantee monitor).
    fixed_step : bool
        Update rule: lambda_{k+1} = lambda_k + eta (eps - l_k) with a constant eta.
    exact_step : bool
        Update rule: lambda_{k+1} = lambda_k + eta_k (eps - l_k) exactly (before clipping),
        eta_k in ``last_step_``.
    uses_loss_function : bool
        Update rule: it wants the interval's loss as a function of lambda before each
        update (``set_loss_function``; counterfactual rules such as dtaci).
    lambda_params : tuple of str
        Update rule: constructor arguments in the units of lambda (converted from the
        scene's units).
    default_loss : str or None
        Decision family: the loss a run uses when it gives none (None: the gap loss).
    default_rule_params : Mapping[str, float]
        Decision family: the rule's ``epsilon``, ``eta``, ... when the run gives none
        (a family whose lambda is not the CBF's slack).
    lambda_unit : str or None
        Decision family: what its lambda is measured in, when not the CBF's rate (``"m"``,
        ``"level"``).
    vector_lambda : bool
        Decision family: it takes one lambda per agent (``lambda_keys()``); a loss: it
        scores each agent (``components()``).
    probe_floor_first : bool
        Safety filter: compute lambda* first when the previous decision fell back (saves a
        slow infeasible solve; iterative solvers).
    """

    compiled: str | None = None
    run_values: Mapping[str, str] = dataclasses.field(
        default_factory=lambda: types.MappingProxyType({})
    )
    batchable: bool = False
    trainable: bool = False
    requires_ground_truth: bool = False
    guarantee: GuaranteeKind = "none"
    fixed_step: bool = False
    exact_step: bool = False
    uses_loss_function: bool = False
    lambda_params: tuple[str, ...] = ()
    default_loss: str | None = None
    default_rule_params: Mapping[str, float] = dataclasses.field(
        default_factory=lambda: types.MappingProxyType({})
    )
    lambda_unit: str | None = None
    vector_lambda: bool = False
    probe_floor_first: bool = False

    def replace(self, **changes: Any) -> Capabilities:
        """A copy with ``changes`` applied (an unknown field is a ``TypeError``)."""
        unknown = sorted(set(changes) - set(CAPABILITY_FIELDS))
        if unknown:
            raise TypeError(
                f"no capabilit{'y' if len(unknown) == 1 else 'ies'} {', '.join(unknown)}; "
                f"the capabilities are {', '.join(CAPABILITY_FIELDS)}"
            )
        for key in ("run_values", "default_rule_params"):
            if key in changes:
                changes[key] = types.MappingProxyType(dict(changes[key]))
        if "lambda_params" in changes:
            changes["lambda_params"] = tuple(changes["lambda_params"])
        return dataclasses.replace(self, **changes)


#: The fields of :class:`Capabilities`, in order.
CAPABILITY_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(Capabilities))

#: Class attributes of 0.3 now held by :class:`Capabilities`: old name -> field. A class
#: that still sets one in its body has it folded in, with a deprecation warning
#: (removed in 0.4, not before 2027-06-30).
FORMER_FLAGS: Mapping[str, str] = types.MappingProxyType(
    {
        "compiled_as": "compiled",
        "fast": "batchable",
        "trainable": "trainable",
        "requires_ground_truth": "requires_ground_truth",
        "guarantee": "guarantee",
        "fixed_step": "fixed_step",
        "exact_step": "exact_step",
        "uses_loss_function": "uses_loss_function",
        "lambda_params": "lambda_params",
        "default_loss": "default_loss",
        "default_rule_params": "default_rule_params",
        "lambda_unit": "lambda_unit",
        "probe_floor_first": "probe_floor_first",
    }
)


@dataclasses.dataclass(frozen=True)
class CompiledForm:
    """What a plugin hands the compiled engine
    (:meth:`~conformal_control.core.base.Plugin.compiled_state`): the name of the kernel
    (:attr:`kernel`, the plugin's :attr:`Capabilities.compiled`) and, in a subclass, that
    kernel's constants, validated. The engine reads plugins only through their forms, never
    their attributes."""

    #: The kernel this form feeds.
    kernel: ClassVar[str] = ""
