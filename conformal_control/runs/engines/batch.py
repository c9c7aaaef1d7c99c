"""Lockstep batch engine: many episodes of the flagship at once, the same metrics.

:func:`run_episode`'s generic loop runs one episode as a chain of Python calls per control
instant (environment, controller, filter, plant). :func:`run_batch` runs many: every
episode of a batch advances by one interval per iteration, and the work of an iteration is
done for all of them together -- ONE compiled call for every control instant of the
interval (:func:`~conformal_control.runs.engines.interval.run_interval`: reference, the exact
2-D filter's fused APF step, plant, goal check, frame clock and log), compiled loops for
the replay bookkeeping (:mod:`~conformal_control.runs.engines.kernels`), and, at sampling
times, ONE call of the predictor, the interpolation, the constraint and the loss on the
agents of every episode at that sampling time laid side by side (these are computed agent
by agent, so one call on the concatenation is the same arithmetic as one call per
episode). :func:`run_episode` itself runs a single episode on this engine when it can
(:func:`run_single`, keeping the per-instant steps and the animation record too).

The metrics are those of :func:`run_episode`, exactly: every episode is built by
:func:`~conformal_control.runs.build.build_flagship` (same parameter resolution, same
validation, same errors), its lambda is updated by its own update rule through its own
:class:`~conformal_control.core.monitor.GuaranteeMonitor`, its counters are written into the
same learned attributes the per-episode loop fills, and it is measured by the same code.
The per-instant arithmetic is written to round the same way (``tests/runs/engines/test_batch.py``
checks every metric against :func:`run_episode`). The wall time of the control loop
(``wall_s``) is the episode's share of the batch's: each iteration's time divided among
the episodes it advanced.

Supported (:func:`supports` says why not otherwise, so a caller can fall back to
:func:`run_episode`): replayed crowds, and the reactive ``social_force``, ``orca`` and
``mixed`` crowds without noise (:mod:`~conformal_control.runs.engines.reactive`: each episode's
crowd walks through the interval's control instants after its robot, one compiled call
per instant for all of them); any registered predictor; the ``cbf`` family and the
``acp`` family (adaptive conformal prediction regions); the APF barrier; the exact 2-D
filter with any registered fallback (``lambda_search``, ``brake`` and ``hold`` are decided
by the compiled step; any other, e.g. ``relax``, by the episode's own fallback object on the
compiled step's rows: the engine pauses that episode at that instant, lets the fallback
decide in Python and runs on); the attractive-field reference; the velocity-tracking plant;
the ``cbf_gap``, ``collision``, ``distance_shortfall`` or ``acp_miscoverage`` loss; any
registered update rule, learning or not. Roles are given by name (an instance would be
shared by every episode).

The ``acp`` family runs its own per-interval code (scoring its past predictions, sorting
their errors, the regions' radii at the interval's lambda: its ``begin_interval`` and
``_inflation``) on the episode's own controller, and the engine runs the interval's control
instants compiled with the barrier's collision distance raised per horizon step, as
:meth:`ACPController.decide <conformal_control.families.cbf.acp.ACPController.decide>` sets up the
compiled step; its miscoverage loss scores the interval's record with its own code.

What runs compiled and what runs through the episode's own objects: the constant-velocity
and the oracle predictor are compiled (above), and so are the predictor shifts of either
(``delayed``, ``noisy``, ``scaled``, ``dropout``, :mod:`~conformal_control.predictors.shift`)
and the ``recorded`` predictor (the forecasts of a predictions file, the benchmark's
``learned`` shift: each episode's slice of the file is packed into the batch and replayed
by :mod:`~conformal_control.runs.engines.recorded_kernels`, its constant-velocity fallback
compiled with it; with another fallback, on a scene the file does not cover or with
agent ids that are not integers it is called as it is); any other predictor is called at each
sampling time on the query the episode's environment builds
(:meth:`~conformal_control.world.replay.ReplayEnvironment.sense`), through the
controller's own ``begin_interval`` (sanitising, counters, interpolation, the same
:class:`~conformal_control.families.cbf.controller.PredictorError`), and its interpolated
predictions are copied into the batch. The gap loss is compiled; the ``collision`` and
``distance_shortfall`` losses are the loss objects themselves, called on the interval's
record and on the truth the environment reveals. The rule is the episode's own; a rule that
evaluates the interval's loss at other lambdas (``uses_loss_function``, e.g. ``dtaci``)
receives the loss as a function of lambda, as
:class:`~conformal_control.core.loop.ConformalStepper` hands it (for the gap loss
``s(max_gap + lambda)``: the gaps do not depend on lambda, and
:class:`~conformal_control.families.cbf.loss.CBFGapLoss` adds lambda to their maximum).

Memory: at most ``batch_size`` episodes are alive at a time; a finished episode's slot is
refilled from ``scenes`` (consumed lazily: pass a generator to keep only the live scenes in
memory) at the next common sampling time. With ``output="metrics"`` (default) only the
:class:`~conformal_control.runs.results.metrics.EpisodeMetrics` are kept; ``output="results"``
keeps an :class:`~conformal_control.runs.results.episode.EpisodeResult` per episode (scene, config,
intervals, per-frame trajectory, the loop's result; no per-instant ``steps`` and no
animation record).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from itertools import repeat
from typing import Any, TypeVar, cast

import numpy as np

from ...core import registry
from ...core.base import Loss, Plugin
from ...core.jit import compile_now
from ...core.loop import (
    IntervalLog,
    IntervalScore,
    LoopResult,
    check_per_agent,
    close_agent_interval,
    close_interval,
)
from ...core.monitor import AgentMonitor, GuaranteeMonitor
from ...core.spec import RunSpec
from ...data.scene import Scene, SparseTracks
from ...families.cbf import kernels2d
from ...families.cbf.acp import ACPController, ACPIntervalRecord
from ...families.cbf.barriers import APFBarrier, APFForm
from ...families.cbf.constraint import ConformalConstraint, time_to_contact
from ...families.cbf.controller import CBFIntervalRecord, ConformalCBFController, PredictorError
from ...families.cbf.dynamics import VelocityTrackingDoubleIntegrator, VelocityTrackingForm
from ...families.cbf.filters.exact2d import Exact2DForm, Exact2DSafetyFilter
from ...families.cbf.loss import CBFGapLoss, CBFTruth, GapLossForm
from ...families.cbf.pyhypot import EXACT_FOR_THIS_PYTHON
from ...families.cbf.reference import AttractiveField, AttractiveFieldForm
from ...families.cbf.roles import InfeasibleStep
from ...families.cbf.speed import speed_polygon
from ...predictors.constant_velocity import ConstantVelocityForm
from ...predictors.recorded import RecordedForm
from ...predictors.shift import DelayedForm, ScaledForm, ShiftForm, noise_offsets, scene_key
from ...world.crowds.crowd import Crowd
from ...world.reactive import ReactiveEnvironment
from ...world.replay import FrameLog, ReplayCursor, ReplayEnvironment
from ..build import Flagship, build_flagship
from ..results.episode import EpisodeResult
from ..results.measure import (
    LAMBDA_LIMIT,
    check_lambda,
    episode_config,
    feasibility,
    jsonable,
    lambda_safe_values,
    measure,
    warn_after_run,
    warn_before_run,
)
from ..results.metrics import EpisodeMetrics
from ..results.record import AnimationRecorder
from . import kernels as bk
from . import recorded_kernels as rk
from .crowd_kernels import dense_layout
from .gap_kernels import BRAKE, HOLD, PYTHON, SEARCH, gap_maxima
from .interval import run_interval
from .reactive import MODELS, CrowdSlots, unsupported_crowd

__all__ = ["iter_batch", "run_batch", "run_single", "supports"]

_T = TypeVar("_T")

#: What the engine compiles, per role of a run: the compiled counterparts it has kernels
#: for. A plugin runs compiled when its class declares one of them (``capabilities.compiled``, see
#: :class:`~conformal_control.core.base.Capabilities`); the role's default (None) always does.
KERNELS: dict[str, frozenset[str]] = {
    "barrier": frozenset({"apf"}),
    "safety_filter": frozenset({"exact2d"}),
    "reference": frozenset({"attractive_field"}),
    "dynamics": frozenset({"velocity_tracking"}),
    "loss": frozenset({"cbf_gap", "collision", "distance_shortfall", "acp_miscoverage"}),
    "family": frozenset({"cbf", "acp"}),
}
#: Roles the engine runs under any registered name (each episode builds and runs its own;
#: a predictor declaring ``constant_velocity`` or ``oracle`` is compiled, a fallback
#: declaring one of :data:`COMPILED_FALLBACKS` too; any other fallback decides in Python,
#: the episode's own object on the compiled step's rows).
ANY_NAME_ROLES = ("predictor", "rule", "fallback")
#: The fallbacks the compiled step decides itself.
COMPILED_FALLBACKS = frozenset({"lambda_search", "brake", "hold"})
#: Losses the engine scores with their own code on the interval's record and truth (they
#: read the ego's positions and the truth, not the filter's status strings).
_RECORD_LOSSES = frozenset({"collision", "distance_shortfall", "acp_miscoverage"})
#: Predictor code of an episode whose predictor is called in Python (not compiled).
_OWN = -1
_FALLBACKS = {"lambda_search": SEARCH, "brake": BRAKE, "hold": HOLD}  # else PYTHON
_PREDICTORS = {
    "constant_velocity": bk.CONSTANT_VELOCITY,
    "oracle": bk.ORACLE,
    "recorded": bk.RECORDED,
}
#: The predictor shifts the compiled prediction applies (to a compiled predictor).
_SHIFTS = {"delayed": bk.DELAYED, "noisy": bk.NOISY, "scaled": bk.SCALED, "dropout": bk.DROPOUT}


def _compiled_name(cls: type) -> str | None:
    """The compiled form ``cls`` declares (its ``capabilities.compiled``; None for a class
    that is no plugin)."""
    return cls.capabilities.compiled if issubclass(cls, Plugin) else None


def _kernel_of(role: str, name: str) -> str | None:
    """The compiled counterpart the plugin registered as ``name`` declares (None: none,
    or no such plugin: the loop then says so)."""
    try:
        return _compiled_name(registry.get(role, name))
    except (ValueError, ImportError):
        return None


def as_run_spec(spec: Any = None, params: dict[str, Any] | None = None, **settings: Any) -> RunSpec:
    """The :class:`~conformal_control.core.spec.RunSpec` of the arguments the functions that
    run episodes take: a RunSpec (with ``settings`` applied), or the predictor (a name or
    an instance; the positional argument of before) and ``settings``."""
    if isinstance(spec, RunSpec):
        if params is None and not settings:
            return spec
        return RunSpec.from_settings(params, base=spec, **settings)
    if spec is not None:
        settings["predictor"] = spec
    return RunSpec.from_settings(params, **settings)


def supports(spec: RunSpec | None = None, /, **settings: Any) -> str | None:
    """Whether the compiled engine runs episodes of ``spec`` (or of the settings of a run,
    as :func:`~conformal_control.runs.episode.run_episode` takes them): None if it does, else the
    reason (one sentence).

    Examples
    --------
    >>> supports(predictor="constant_velocity", learn=False) is None
    True
    >>> supports(crowd="orca", learn=False) is None
    True
    >>> supports(crowd="social_force", crowd_params={"noise": 0.1})
    'crowd noise: the batch engine steps deterministic crowds only'
    """
    settings.pop("seeds", None)  # one per episode: not a setting of the run
    settings.pop("extra_config", None)
    settings.pop("on_interval", None)  # called as the loop calls it
    try:
        run = as_run_spec(spec, **settings)
    except TypeError as exc:
        return str(exc)
    roles = run.roles()
    for role in (*ANY_NAME_ROLES, *KERNELS):
        name, params = roles[role]
        if name is not None and not isinstance(name, str):
            return (
                f"{role} given as a {type(name).__name__} instance: the batch engine builds "
                "one per episode, give it by registered name"
            )
        kernels = KERNELS.get(role)
        if kernels is not None and name is not None and _kernel_of(role, name) not in kernels:
            return f"{role} {name!r}: the batch engine compiles {', '.join(sorted(kernels))}"
        if role == "fallback" and params and _kernel_of(role, str(name)) in COMPILED_FALLBACKS:
            return (
                f"fallback parameters for {name!r}: the batch engine runs the compiled "
                "fallbacks as registered"
            )
    filter_params = roles["safety_filter"][1]
    if filter_params.get("compiled_step", True) is not True:
        return "safety_filter_params compiled_step=False: the batch engine is the compiled step"
    if not isinstance(filter_params.get("fallback"), (str, type(None))):
        return "a fallback instance: the batch engine builds one per episode, give it by name"
    if run.robots is not None:
        return "robots: the batch engine runs one robot per episode"
    crowd, crowd_params = roles["crowd"]
    if not isinstance(crowd, str):
        return "a crowd instance: the batch engine builds one per episode, give it by name"
    if crowd != "replay":
        why = unsupported_crowd(crowd, dict(crowd_params or {}))
        if why is not None:
            return why
    if settings.get("record_animation"):
        return "record_animation: the batch engine keeps no animation record"
    return None


class _NotRun(ValueError):
    """An episode as built is not one the engine runs (a name resolved to a plugin of
    another class); the message says why."""

    def __init__(self, why: str) -> None:
        super().__init__(f"run_batch cannot run this episode: {why}; use run_episode")


def _exact(obj: object, cls: type[_T], role: str) -> _T:
    """``obj`` if its class is exactly ``cls`` (a subclass may compute something else
    than the compiled step does), else :class:`_NotRun`."""
    if type(obj) is not cls:
        raise _NotRun(f"the {role} is a {type(obj).__name__}, not a {cls.__name__}")
    return obj


def _compiled(obj: object, cls: type[_T], role: str) -> _T:
    """``obj`` if its class declares the compiled counterpart ``cls`` declares (its own
    ``capabilities.compiled``), else
    :class:`_NotRun`."""
    kernel = _compiled_name(cls)
    if kernel is None or _compiled_name(type(obj)) != kernel:
        raise _NotRun(
            f"the {role} is a {type(obj).__name__}, which does not declare the compiled "
            f"counterpart {kernel!r}"
        )
    return cast(_T, obj)


@dataclass(frozen=True)
class _Parts:
    """The roles of a built episode the engine reads, as the classes it runs."""

    env: ReplayEnvironment
    barrier: APFBarrier
    safety_filter: Exact2DSafetyFilter
    reference: AttractiveField
    dynamics: VelocityTrackingDoubleIntegrator
    loss: Loss[Any, Any]  # a CBFGapLoss (compiled) or one of _RECORD_LOSSES
    gap: CBFGapLoss | None  # the loss if it is the gap loss
    acp: ACPController | None  # the decision family if it is the acp family


def _parts(fl: Flagship) -> _Parts:
    """The roles of ``fl`` as the classes the engine runs; raises :class:`_NotRun` (a
    ValueError) if the episode as built is not one it runs."""
    policy = fl.family
    if _compiled_name(type(policy)) not in KERNELS["family"] or not isinstance(
        policy, ConformalCBFController
    ):
        raise _NotRun(
            f"the decision family is a {type(policy).__name__}, which declares none of "
            f"{', '.join(sorted(KERNELS['family']))}"
        )
    if policy.reciprocity is not None:
        raise _NotRun("the decision family has robots' reciprocity")
    env = fl.env
    if type(env) is ReactiveEnvironment:
        crowd = env.crowd
        if type(crowd) is not Crowd:
            raise _NotRun(f"the crowd is a {type(crowd).__name__}, not a Crowd")
    else:
        env = _exact(env, ReplayEnvironment, "environment")
    constraint = _exact(fl.constraint, ConformalConstraint, "constraint")
    barrier = _compiled(fl.barrier, APFBarrier, "barrier")
    filt = _compiled(fl.safety_filter, Exact2DSafetyFilter, "safety filter")
    reference = _compiled(fl.reference, AttractiveField, "reference")
    dynamics = _compiled(fl.dynamics, VelocityTrackingDoubleIntegrator, "dynamics")
    loss = fl.loss
    kernel = _compiled_name(type(loss))
    gap = cast(CBFGapLoss, loss) if kernel == "cbf_gap" else None
    if gap is None and kernel not in _RECORD_LOSSES:
        shown = ", ".join(sorted(KERNELS["loss"]))
        raise _NotRun(f"the loss is a {type(loss).__name__}, which declares none of {shown}")
    if (gap is not None and gap.constraint is not constraint) or (
        policy.constraint is not constraint
    ):
        raise _NotRun("the loss and the controller do not share the run's constraint")
    if filt.compiled_step is not True:
        raise _NotRun("the safety filter's compiled step is off")
    fallback = filt.fallback
    if not isinstance(fallback, str) and _compiled_name(type(fallback)) in COMPILED_FALLBACKS:
        # (a fallback decided in Python is the episode's own object, parameters and all)
        raise _NotRun("the compiled fallbacks run as registered, not as a configured instance")
    acp = policy if isinstance(policy, ACPController) else None
    if (acp is not None) != (_compiled_name(type(policy)) == "acp"):
        raise _NotRun(f"the decision family {type(policy).__name__} is not the class it declares")
    return _Parts(env, barrier, filt, reference, dynamics, loss, gap, acp)


def _form(forms: dict[str, Any], role: str, cls: type[_T]) -> _T:
    """The compiled form of ``role`` among ``forms`` (the flagship's
    :meth:`~conformal_control.runs.build.Flagship.compiled_forms`), as the kernel it
    declares reads it; :class:`_NotRun` if the part hands another."""
    form = forms.get(role)
    if not isinstance(form, cls):
        raise _NotRun(f"the {role} declares {cls.kernel!r} but hands no {cls.__name__}")  # type: ignore[attr-defined]
    return form


def _predictor_code(pred: object) -> int:
    """The compiled predictor of :func:`~conformal_control.runs.engines.kernels.predict_interpolate`
    that ``pred``'s class declares (``capabilities.compiled``), else ``_OWN``."""
    return _PREDICTORS.get(_compiled_name(type(pred)) or "", _OWN)


def _window_of(form: object) -> Any:
    """The constant-velocity predictor's window, read from its compiled form (as given:
    checked by the caller); :class:`_NotRun` if the predictor hands no such form."""
    if not isinstance(form, ConstantVelocityForm):
        raise _NotRun("the predictor declares 'constant_velocity' but hands no form of it")
    return form.window


def _valid_window(window: Any) -> bool:
    return bool(int(window) == window and window >= 1)


def _prediction(
    pred: Plugin, form: object, dt_frame: float, history: int, ids: np.ndarray
) -> tuple[int, int, ShiftForm | None, Any]:
    """How the compiled prediction runs ``pred`` (whose compiled form is ``form``): (the
    predictor code, the shift code, the shift's form, the constant-velocity window, 1 for
    another predictor). A predictor shift (:mod:`~conformal_control.predictors.shift`) of
    a compiled predictor runs compiled with it (the wrapped predictor read through its own
    compiled form); one that returns the wrapped forecast itself is that predictor; one
    the compiled form would not follow exactly where the wrapper raises or reads what the
    kernel does not hold (a delay beyond the history, a bad window, agent ids that are not
    integers) is called as it is (``_OWN``)."""
    kernel = _compiled_name(type(pred)) or ""
    own = (_OWN, bk.NO_SHIFT, None, 1)
    if kernel not in _SHIFTS:
        code = _predictor_code(pred)
        if code == bk.RECORDED:
            return _recorded_prediction(form, ids)
        return code, bk.NO_SHIFT, None, _window_of(form) if code == bk.CONSTANT_VELOCITY else 1
    if not isinstance(form, ShiftForm) or form.kernel != kernel:
        raise _NotRun(f"the predictor declares {kernel!r} but hands no form of that shift")
    base = form.base
    code = _predictor_code(base)
    window: Any = 1
    if code == bk.CONSTANT_VELOCITY:
        window = _window_of(base.compiled_state())
        if not _valid_window(window):
            return own
    if code in (_OWN, bk.RECORDED):  # (a shift of recorded forecasts: called as it is)
        return own
    if isinstance(form, DelayedForm):
        k = form.samples(dt_frame)
        if k == 0:  # the wrapped forecast itself
            return code, bk.NO_SHIFT, None, window
        if k >= history:  # the wrapper refuses it (its error, at its first prediction)
            return own
    elif form.neutral:
        return code, bk.NO_SHIFT, None, window
    if kernel in ("noisy", "dropout") and not np.issubdtype(ids.dtype, np.integer):
        return own
    return code, _SHIFTS[kernel], form, window


def _recorded_prediction(form: object, ids: np.ndarray) -> tuple[int, int, None, Any]:
    """How the compiled prediction runs a ``recorded`` predictor (whose compiled form is
    ``form``): compiled with its fallback's window when the fallback is the constant-velocity
    predictor with a valid window and the agents' ids are integers (the predictor's
    ``astype(int64)`` of other ids is not what the kernel reads), else called as it is."""
    if not isinstance(form, RecordedForm):
        raise _NotRun("the predictor declares 'recorded' but hands no RecordedForm")
    own = (_OWN, bk.NO_SHIFT, None, 1)
    fallback = form.fallback
    if _predictor_code(fallback) != bk.CONSTANT_VELOCITY:
        return own
    window = _window_of(fallback.compiled_state())
    if not _valid_window(window) or not np.issubdtype(ids.dtype, np.integer):
        return own
    return bk.RECORDED, bk.NO_SHIFT, None, window


def _recorded_block(
    form: RecordedForm, sc: Scene, dt_frame: float, last: int
) -> tuple[np.ndarray, float] | None:
    """The forecasts of ``sc``'s predictions file that an episode sampling at frames
    ``sc.start_index`` .. ``last`` can read, packed
    (:func:`~conformal_control.runs.engines.recorded_kernels.pack`: the latest issue at or before
    the first sampling time, and every later one up to the last), and the step length;
    None where the predictor raises on this scene (no file for it, a missing or malformed
    file): the episode's own predictor is then called, and raises as in the loop, at its
    first prediction."""
    try:
        rec, step_s, per_step = form.source(sc.name)
    except (ValueError, OSError):
        return None
    f_s = step_s / per_step
    times = rec.frames * f_s  # as the predictor computes them
    t_lo = int(sc.first_frame + sc.start_index) * dt_frame
    t_hi = int(sc.first_frame + last) * dt_frame
    k_lo = max(int(np.searchsorted(times, t_lo + rk.EPS, side="right")) - 1, 0)
    k_hi = int(np.searchsorted(times, t_hi + rk.EPS, side="right"))
    keep = range(k_lo, max(k_hi, k_lo))
    block = rk.pack(times[k_lo : max(k_hi, k_lo)], [rec.ids[k] for k in keep],
                    [rec.points[k] for k in keep])  # fmt: skip
    return block, step_s


def _info_keys(code: int, shift: int, form: ShiftForm | None) -> tuple[str, ...]:
    """The keys of the controller's ``forecast_info_`` a compiled prediction fills, in the
    order the predictor (and its shift) first report them."""
    if code == bk.RECORDED:  # (its fallback's counters are not reported)
        return ("n_missing", "n_missing_steps", "n_extrapolated", "n_nonfinite_current")
    base = ("n_short_history",) if code == bk.CONSTANT_VELOCITY else ()
    if shift == bk.DELAYED:
        return (*base, "n_stale", "n_unseen")
    if shift == bk.DROPOUT:
        return (*base, "n_dropped", "n_stale", "n_unseen")
    if shift == bk.SCALED and isinstance(form, ScaledForm) and form.scale == 0.0:
        return ()  # frozen: the wrapped predictor is not asked
    return base


class _GapLossAt:
    """The gap loss of an interval as a function of lambda: ``s(max_gap + lambda)``, as
    :meth:`CBFGapLoss.__call__ <conformal_control.families.cbf.loss.CBFGapLoss.__call__>` computes
    it
    (the gaps do not depend on lambda; lambda is added to their maximum), from the maximum
    the engine computed (what ``ConformalStepper.end_interval`` hands a rule with
    ``uses_loss_function``, without rebuilding the interval's record)."""

    def __init__(self, loss: CBFGapLoss, max_gap: np.float64) -> None:
        self.loss, self.max_gap = loss, max_gap

    def __call__(self, lam: float) -> float:
        if math.isnan(lam):
            raise ValueError("the loss needs a lambda that is a number, got nan")
        return float(self.loss.squash(self.max_gap + lam))


# ------------------------------------------------------------------------------ episodes
@dataclass
class _Episode:
    """One live episode: its built flagship and what the loop accumulates in Python."""

    index: int
    run: RunSpec  # the episode's own: its seed and time limit
    fl: Flagship
    parts: _Parts  # fl's roles as the classes the engine runs
    monitor: GuaranteeMonitor | AgentMonitor
    learn: bool
    seed: int
    max_frames: int | None
    lambda_safe: float | None  # in the scene's units, as run_episode reports it
    floor: Any
    goals: np.ndarray
    intervals: list[IntervalLog] = field(default_factory=list)
    n_sensed: list[int] = field(default_factory=list)
    # lambda run per agent: the interval's agents (keys) and their lambdas
    keys: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    lams: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # the keys of the forecast counters a compiled prediction fills (see _info_keys)
    info_keys: tuple[str, ...] = ()


class _Pool:
    """The state of ``size`` episode slots, one row per slot (grown on demand).

    Every array's first axis is the slot. The per-slot scalars are float64 (times, lambda,
    the plant's and the reference's constants, the loss scale, the wall time) or int64
    (step and frame counters, sizes, codes of the fallback and the predictor).
    """

    size: int
    t: np.ndarray  # float64 (size,)
    lam: np.ndarray  # float64 (size,)
    dt: np.ndarray  # float64 (size,)
    dt_frame: np.ndarray  # float64 (size,)
    decay: np.ndarray  # float64 (size,)
    gain: np.ndarray  # float64 (size,)
    k_acc: np.ndarray  # float64 (size,)
    neg_k_att: np.ndarray  # float64 (size,)
    v_ref_max: np.ndarray  # float64 (size,)
    goal_radius: np.ndarray  # float64 (size,)
    radius: np.ndarray  # float64 (size,)
    t_goal: np.ndarray  # float64 (size,)
    scale: np.ndarray  # float64 (size,)
    wall: np.ndarray  # float64 (size,)
    step: np.ndarray  # int64 (size,)
    n_ctrl: np.ndarray  # int64 (size,)
    n_agents: np.ndarray  # int64 (size,)
    fi: np.ndarray  # int64 (size,)
    last_frame: np.ndarray  # int64 (size,)
    k_start: np.ndarray  # int64 (size,)
    substeps: np.ndarray  # int64 (size,)
    tau: np.ndarray  # int64 (size,)
    history: np.ndarray  # int64 (size,)
    goal_idx: np.ndarray  # int64 (size,)
    n_log: np.ndarray  # int64 (size,)
    poly_len: np.ndarray  # int64 (size,)
    fallback: np.ndarray  # int64 (size,)
    predictor: np.ndarray  # int64 (size,)
    window: np.ndarray  # int64 (size,)
    n_short: np.ndarray  # int64 (size,)
    n_short_total: np.ndarray  # int64 (size,)
    n_predicted: np.ndarray  # int64 (size,)
    n_bad: np.ndarray  # int64 (size,)
    n_bad_total: np.ndarray  # int64 (size,)
    x: np.ndarray  # (size, 4): position, velocity
    goal: np.ndarray  # (size, 2)
    last: np.ndarray  # (size, 2): the previous decision (the filter's output)
    active: np.ndarray  # bool (size,)
    done: np.ndarray  # bool (size,)
    need_begin: np.ndarray  # bool (size,)
    prm: np.ndarray  # (size, len(kernels2d.PARAMS))
    poly: np.ndarray  # (size, 5 * sides): the speed polygon
    counts: np.ndarray  # int64 (size, 7): solves, infeasible, fallback, vertex, steps, escape,
    # escape_projected
    sensed: np.ndarray  # int64 (size, columns)
    xp: np.ndarray  # (size, steps, cap, 2): predicted positions
    vp: np.ndarray  # (size, steps, cap, 2): predicted velocities
    rec_x: np.ndarray  # (size, steps, 2)
    rec_v: np.ndarray  # (size, steps, 2)
    rec_lam: np.ndarray  # (size, steps)
    log: np.ndarray  # (size, frames, 6)
    samples: np.ndarray  # (>= tau + 1, 2): one agent's predicted samples, scratch
    cap: int  # agents per slot that xp / vp and the work buffer hold
    sides: int  # sides of the largest speed polygon
    work: np.ndarray  # the compiled filter's work buffer
    store: np.ndarray  # the live episodes' recordings, flat (see kernels)
    where: np.ndarray  # int64 (size, 5): slot -> (offset, frames, agents, samples, present)
    goals: np.ndarray  # (size, waypoints, 2): each slot's goals
    n_goals: np.ndarray  # int64 (size,)
    rec_code: np.ndarray  # int8 (size, steps): status of each control instant (FREE, ...)
    keep: bool  # whether st_* keep every control instant of the episodes
    st_t: np.ndarray  # (size, instants): time after each control instant
    st_x: np.ndarray  # (size, instants, 4): state after it
    st_cmd: np.ndarray  # (size, instants, 2): the command applied
    n_st: np.ndarray  # int64 (size,)
    used: int  # floats of store in use
    acp: np.ndarray  # bool (size,): the acp family (lambda is the regions' level)
    acp_dc: np.ndarray  # (size, horizon): the barrier's d_c at each horizon step
    acp_delta: np.ndarray  # (size, horizon): its delta
    acp_h: np.ndarray  # int64 (size,): horizon steps of the interval's regions
    forced: np.ndarray  # bool (size,): a decision given for the paused step
    forced_v: np.ndarray  # (size, 3): that decision (v_x, v_y, lambda applied)
    paused: np.ndarray  # (3,): the paused step's nominal decision and lambda
    reactive: np.ndarray  # bool (size,): a reactive crowd (engines.reactive)
    mirror: np.ndarray  # bool (size,): its environment's buffer is read during the run
    vec: np.ndarray  # bool (size,): lambda run per agent
    lam_off: np.ndarray  # (size, cap): per agent, its lambda minus the slot's lam (vec)
    shift: np.ndarray  # int64 (size,): the predictor shift (kernels' NO_SHIFT, DELAYED, ...)
    shift_k: np.ndarray  # int64 (size,): a delay in frames
    shift_x: np.ndarray  # (size, 2): the scale, or dropout's probability and block length
    noise_sigma: np.ndarray  # (size,): the noisy shift's standard deviation (m)
    seeds: np.ndarray  # int64 (size,): the shift's seed
    scene_keys: np.ndarray  # int64 (size,): its key of the scene's name
    first_frame: np.ndarray  # int64 (size,): the scene's first frame number
    agent_id: np.ndarray  # int64 (size, columns): the id of each agent of the recording
    noise: np.ndarray  # (size, cap, 2): each sensed agent's noisy displacement
    shift_counts: np.ndarray  # int64 (size, 3): stale, unseen, dropped (totals)
    rec: np.ndarray  # the recorded forecasts of the live episodes that replay them, flat
    rec_at: np.ndarray  # int64 (size,): where slot b's block starts in rec
    rec_len: np.ndarray  # int64 (size,): its length (0: none)
    rec_used: int  # floats of rec in use
    rec_step: np.ndarray  # (size,): the forecasts' step length (s)
    rec_counts: np.ndarray  # int64 (size, 4): missing, missing steps, extrapolated,
    # non-finite current (totals)

    def __init__(self, size: int) -> None:
        b = self.size = size
        self.t = np.zeros(b)
        self.lam = np.zeros(b)
        self.dt = np.zeros(b)
        self.dt_frame = np.zeros(b)
        self.decay = np.zeros(b)
        self.gain = np.zeros(b)
        self.k_acc = np.zeros(b)
        self.neg_k_att = np.zeros(b)
        self.v_ref_max = np.zeros(b)
        self.goal_radius = np.zeros(b)
        self.radius = np.zeros(b)
        self.t_goal = np.zeros(b)
        self.scale = np.zeros(b)
        self.wall = np.zeros(b)
        self.step = np.zeros(b, dtype=np.int64)
        self.n_ctrl = np.zeros(b, dtype=np.int64)
        self.n_agents = np.zeros(b, dtype=np.int64)
        self.fi = np.zeros(b, dtype=np.int64)
        self.last_frame = np.zeros(b, dtype=np.int64)
        self.k_start = np.zeros(b, dtype=np.int64)
        self.substeps = np.zeros(b, dtype=np.int64)
        self.tau = np.zeros(b, dtype=np.int64)
        self.history = np.zeros(b, dtype=np.int64)
        self.goal_idx = np.zeros(b, dtype=np.int64)
        self.n_log = np.zeros(b, dtype=np.int64)
        self.poly_len = np.zeros(b, dtype=np.int64)
        self.fallback = np.zeros(b, dtype=np.int64)
        self.predictor = np.zeros(b, dtype=np.int64)
        self.window = np.zeros(b, dtype=np.int64)
        self.n_short = np.zeros(b, dtype=np.int64)
        self.n_short_total = np.zeros(b, dtype=np.int64)
        self.n_predicted = np.zeros(b, dtype=np.int64)
        self.n_bad = np.zeros(b, dtype=np.int64)
        self.n_bad_total = np.zeros(b, dtype=np.int64)
        self.x = np.zeros((b, 4))
        self.goal = np.zeros((b, 2))
        self.last = np.zeros((b, 2))
        self.active = np.zeros(b, dtype=bool)
        self.done = np.zeros(b, dtype=bool)
        self.need_begin = np.zeros(b, dtype=bool)
        self.prm = np.zeros((b, len(kernels2d.PARAMS)))
        self.poly = np.zeros((b, 0))
        self.counts = np.zeros((b, 7), dtype=np.int64)
        self.sensed = np.zeros((b, 0), dtype=np.int64)
        self.xp = np.zeros((b, 0, 0, 2))
        self.vp = np.zeros((b, 0, 0, 2))
        self.rec_x = np.zeros((b, 0, 2))
        self.rec_v = np.zeros((b, 0, 2))
        self.rec_lam = np.zeros((b, 0))
        self.log = np.zeros((b, 0, 6))
        self.samples = np.zeros((1, 2))
        self.cap = 0  # agents per slot that xp / vp and the work buffer hold
        self.sides = 0
        self.work = np.zeros(0)
        self.store = np.zeros(0)  # the live episodes' recordings, flat (see kernels)
        # slot -> (offset, frames, agents, samples, present samples)
        self.where = np.zeros((b, 5), dtype=np.int64)
        self.used = 0
        self.goals = np.zeros((b, 1, 2))
        self.n_goals = np.zeros(b, dtype=np.int64)
        self.rec_code = np.zeros((b, 0), dtype=np.int8)
        self.keep = False
        self.st_t = np.zeros((b, 0))
        self.st_x = np.zeros((b, 0, 4))
        self.st_cmd = np.zeros((b, 0, 2))
        self.n_st = np.zeros(b, dtype=np.int64)
        self.acp = np.zeros(b, dtype=bool)
        self.acp_dc = np.zeros((b, 1))
        self.acp_delta = np.zeros((b, 1))
        self.acp_h = np.ones(b, dtype=np.int64)
        self.forced = np.zeros(b, dtype=bool)
        self.forced_v = np.zeros((b, 3))
        self.paused = np.zeros(3)
        self.reactive = np.zeros(b, dtype=bool)
        self.mirror = np.zeros(b, dtype=bool)
        self.vec = np.zeros(b, dtype=bool)
        self.lam_off = np.zeros((b, 0))
        self.shift = np.zeros(b, dtype=np.int64)
        self.shift_k = np.zeros(b, dtype=np.int64)
        self.shift_x = np.zeros((b, 2))
        self.noise_sigma = np.zeros(b)
        self.seeds = np.zeros(b, dtype=np.int64)
        self.scene_keys = np.zeros(b, dtype=np.int64)
        self.first_frame = np.zeros(b, dtype=np.int64)
        self.agent_id = np.zeros((b, 0), dtype=np.int64)
        self.noise = np.zeros((b, 0, 2))
        self.shift_counts = np.zeros((b, 3), dtype=np.int64)
        self.rec = np.zeros(0)
        self.rec_at = np.zeros(b, dtype=np.int64)
        self.rec_len = np.zeros(b, dtype=np.int64)
        self.rec_used = 0
        self.rec_step = np.zeros(b)
        self.rec_counts = np.zeros((b, 4), dtype=np.int64)

    @staticmethod
    def grown(arr: np.ndarray, axis: int, n: int) -> np.ndarray:
        if arr.shape[axis] >= n:
            return arr
        shape = list(arr.shape)
        shape[axis] = n
        out = np.zeros(shape, dtype=arr.dtype)
        out[tuple(slice(0, k) for k in arr.shape)] = arr
        return out

    def load(self, b: int, tracks: SparseTracks) -> None:
        """Copy slot ``b``'s recording (sparse,
        :func:`~conformal_control.runs.engines.kernels.pack`)
        into the store (compacting or growing it)."""
        counts = (tracks.n_frames, tracks.n_agents, tracks.xy.shape[0], tracks.frame_cols.size)
        self.put(b, bk.pack(tracks), counts)

    def put(self, b: int, data: np.ndarray, counts: tuple[int, int, int, int]) -> None:
        """Copy slot ``b``'s recording laid out as
        :func:`~conformal_control.runs.engines.kernels.pack`
        lays it out, with ``counts`` = (frames, agents, samples, present), into the store."""
        n = data.size
        if self.used + n > self.store.size:
            self._compact()
            if self.used + n > self.store.size:  # doubled: amortised, and no room reserved
                # for slots that may never fill (a long scene and batch_size 256 asked for
                # 256 copies of it)
                grown = np.empty(max(2 * self.store.size, self.used + n))
                grown[: self.used] = self.store[: self.used]
                self.store = grown
        self.store[self.used : self.used + n] = data
        self.where[b] = (self.used, *counts)
        self.used += n

    def _compact(self) -> None:
        """Move the live slots' recordings to the front of the store, in place."""
        live = np.flatnonzero(self.active)
        end = 0
        for b in live[np.argsort(self.where[live, 0])].tolist():
            o, f, m, ns, k = self.where[b].tolist()
            n = bk.slot_size(f, m, ns, k)
            if o != end:
                self.store[end : end + n] = self.store[o : o + n]  # numpy copies overlaps safely
                self.where[b, 0] = end
            end += n
        self.used = end

    def put_recorded(self, b: int, block: np.ndarray) -> None:
        """Copy slot ``b``'s recorded forecasts (a block of
        :func:`~conformal_control.runs.engines.recorded_kernels.pack`; empty: none) into ``rec``
        (the live slots' blocks moved to the front first when it is full, then grown)."""
        n = block.size
        self.rec_len[b] = 0
        if self.rec_used + n > self.rec.size:
            end = 0
            live = np.flatnonzero(self.active & (self.rec_len > 0))
            for s in live[np.argsort(self.rec_at[live])].tolist():
                o, k = int(self.rec_at[s]), int(self.rec_len[s])
                if o != end:
                    self.rec[end : end + k] = self.rec[o : o + k]
                    self.rec_at[s] = end
                end += k
            self.rec_used = end
            if self.rec_used + n > self.rec.size:
                grown = np.empty(max(2 * self.rec.size, self.rec_used + n))
                grown[: self.rec_used] = self.rec[: self.rec_used]
                self.rec = grown
        self.rec[self.rec_used : self.rec_used + n] = block
        self.rec_at[b] = self.rec_used
        self.rec_len[b] = n
        self.rec_used += n

    def prepare(self, b: int, goals: np.ndarray, instants: int) -> None:
        """Slot ``b``'s goals, and room for its ``instants`` control instants if kept."""
        if goals.shape[0] > self.goals.shape[1]:
            self.goals = self.grown(self.goals, 1, goals.shape[0])
        self.goals[b, : goals.shape[0]] = goals
        self.n_goals[b] = goals.shape[0]
        self.n_st[b] = 0
        if self.keep and instants > self.st_t.shape[1]:
            g = self.grown
            self.st_t = g(self.st_t, 1, instants)
            self.st_x, self.st_cmd = g(self.st_x, 1, instants), g(self.st_cmd, 1, instants)

    def ensure(
        self, *, steps: int = 0, agents: int = 0, columns: int = 0, frames: int = 0, sides: int = 0
    ) -> None:
        """Room for ``steps`` control instants per interval, ``agents`` sensed agents,
        ``columns`` agents in a recording, ``frames`` logged frames, ``sides`` polygon sides."""
        g = self.grown
        if steps > self.xp.shape[1]:
            self.xp, self.vp = g(self.xp, 1, steps), g(self.vp, 1, steps)
            self.rec_x, self.rec_v = g(self.rec_x, 1, steps), g(self.rec_v, 1, steps)
            self.rec_lam = g(self.rec_lam, 1, steps)
            self.rec_code = g(self.rec_code, 1, steps)
            self.samples = g(self.samples, 0, steps + 1)  # >= tau + 1 rows
        if agents > self.cap or sides > self.sides:
            if agents > self.cap:
                self.cap = max(agents, 2 * self.cap, 16)
                self.xp, self.vp = g(self.xp, 2, self.cap), g(self.vp, 2, self.cap)
                self.lam_off = g(self.lam_off, 1, self.cap)
                self.noise = g(self.noise, 1, self.cap)
                self.prm[:, 11] = self.cap
            if sides > self.sides:
                self.sides = sides
                self.poly = g(self.poly, 1, 5 * sides)
            self.work = np.zeros(kernels2d.work_size(self.cap, self.sides))
        if columns > self.sensed.shape[1]:
            self.sensed = g(self.sensed, 1, columns)
            self.agent_id = g(self.agent_id, 1, columns)
        if frames > self.log.shape[1]:
            self.log = g(self.log, 1, frames)


# ------------------------------------------------------------------------------ engine
class _Engine:
    """The lockstep loop over a :class:`_Pool` (see the module docstring)."""

    def __init__(
        self, size: int, output: str, run: RunSpec, extra_config: dict[str, Any] | None
    ) -> None:
        self.pool = _Pool(size)
        self.eps: list[_Episode | None] = [None] * size
        self.output = output
        self.run_spec = run
        self.extra_config = extra_config
        self._squash: dict[float, Any] = {}  # loss scale -> the squashing of a loss with it
        self._own = False  # whether an episode predicts with its own predictor object
        self._acp = False  # whether an episode is of the acp family
        self.crowds: CrowdSlots | None = None  # the reactive crowds, if any
        # the scores of an interval end, per slot (reset for the slots that end; reused
        # rather than allocated at every interval end)
        self._scores = (
            np.empty(size),  # top gap
            np.empty(size),  # top gap at the lambda applied
            np.empty(size, dtype=np.int64),  # pairs scored
            np.empty(size),  # loss
            np.empty(size),  # loss at the lambda applied
        )
        #: called with the slots after their interval's control instants, before it is
        #: scored (the single-episode run keeps its animation record with it)
        self.on_control: Any = None
        #: called with each scored interval's log, as the loop's ``on_interval``
        self.on_interval: Callable[[IntervalLog], None] | None = None
        #: stack level of the warnings of an episode's end (who they point at)
        self.warn_stacklevel = 4

    # ------------------------------------------------------------------ start
    def start(self, b: int, index: int, scene: Scene, seed: int, max_frames: int | None) -> None:
        """Build episode ``index`` as run_episode does and load it into slot ``b``."""
        run = dataclasses.replace(self.run_spec, seed=seed, max_frames=max_frames)
        learn = run.learn
        fl = build_flagship(scene, run)
        parts = _parts(fl)
        sc = fl.scene
        lambda_safe, lam_safe_si = lambda_safe_values(fl, run.lambda_safe, run.units)
        floor = feasibility(fl)
        warn_before_run(fl, floor, learn)
        # what ConformalLoop.run does first: reset the environment (validates the scene and
        # the timing), the family (validates; resets predictor, filter, reference), the rule
        env = parts.env
        env.reset()
        vec = fl.params.si["lambda_per"] == "agent"
        if vec:  # as ConformalStepper.start, and its begin_interval for the acp family
            check_per_agent(fl.family, fl.loss)
            if parts.acp is not None:
                raise ValueError(
                    f"{type(fl.family).__name__}.lambda_keys() gave None after "
                    "begin_interval: lambda cannot be run per agent with this family"
                )
        fl.family.reset()
        monitor: GuaranteeMonitor | AgentMonitor
        monitor = (AgentMonitor if vec else GuaranteeMonitor).for_rule(
            fl.rule,
            lambda_safe=lam_safe_si,
            lambda_safe_source=run.lambda_safe_source,
            premise_proven=False,
            bounds=parts.loss.bounds,
            learn=learn,
            **({"prior": fl.params.si["lambda_prior"]} if vec else {}),
        )
        # each compiled part as its compiled form (validated constants), never its attributes
        forms = fl.compiled_forms()
        apf = _form(forms, "barrier", APFForm)
        filt_form = _form(forms, "safety_filter", Exact2DForm)
        ref_form = _form(forms, "reference", AttractiveFieldForm)
        k = _form(forms, "dynamics", VelocityTrackingForm).K_acc
        pred = fl.predictor
        reactive = isinstance(env, ReactiveEnvironment)
        if isinstance(env, ReactiveEnvironment):
            model = env.crowd.model_  # (built by the reset)
            if type(model) not in MODELS.values():
                raise _NotRun(f"the crowd model is a {type(model).__name__}")
        # the acp family predicts, scores its past errors and sorts them in its own
        # begin_interval: its predictor is called through it; so is the oracle of a
        # reactive crowd (whose future is not known: its query says so)
        dt_frame = 1.0 / sc.fps
        ids = np.asarray(sc.agent_ids)
        code, shift, form, window = _prediction(
            pred, forms.get("predictor"), dt_frame, int(env.history_frames), ids
        )
        if parts.acp is not None or (reactive and code == bk.ORACLE):
            code, shift, form, window = _OWN, bk.NO_SHIFT, None, 1
        last = sc.n_frames - 1
        if max_frames is not None:
            last = min(last, sc.start_index + int(max_frames))
        recorded = None
        if code == bk.RECORDED:
            rform = cast(RecordedForm, forms.get("predictor"))
            recorded = _recorded_block(rform, sc, dt_frame, last)
            if recorded is None:  # the predictor raises on this scene: called as it is
                code, window = _OWN, 1
        if int(window) != window or window < 1:
            raise PredictorError(
                f"predictor {type(pred).__name__} failed on scene {sc.name}: ValueError: "
                f"window must be a positive integer, got {window!r}"
            )
        ep = _Episode(
            index=index,
            run=run,
            fl=fl,
            parts=parts,
            monitor=monitor,
            learn=learn,
            seed=seed,
            max_frames=max_frames,
            lambda_safe=lambda_safe,
            floor=floor,
            goals=np.asarray(sc.goals, dtype=float),
            info_keys=_info_keys(code, shift, form),
        )
        p = self.pool
        substeps, tau = int(env.substeps), int(env.tau_frames)
        S, s, verts, radius = speed_polygon(int(filt_form.speed_sides), float(filt_form.v_max))
        p.ensure(
            steps=tau * substeps,
            agents=1,
            columns=sc.n_agents,
            frames=last - sc.start_index + 1,
            sides=S.shape[0],
        )
        dt = dt_frame / substeps
        # the frames the episode reads: its history before the start, its frames, the last
        # interval's future (the oracle, the truth); the rest of a long scene stays out
        lo = sc.start_index - int(env.history_frames)
        if reactive:  # every column over the episode's frames, filled as the crowd walks
            assert isinstance(env, ReactiveEnvironment)
            lo, hi = max(lo, 0), min(last + tau + 2, sc.n_frames)
            m = sc.n_agents
            buffer = env.compiled_state().buffer
            assert buffer is not None  # a reactive environment holds its crowd's positions
            data = dense_layout(buffer[lo:hi], lo, sc.start_index, sc.n_frames)
            p.put(b, data, (sc.n_frames, m, m * (hi - lo), m * (hi - lo)))
            if self.crowds is None:
                self.crowds = CrowdSlots(p.size)
            self.crowds.load(b, env, last, lo)
        else:
            p.load(b, sc.tracks.clip(lo, last + tau + 2))
        p.reactive[b] = reactive
        # whether the episode's own objects read the environment's buffer during the run
        p.mirror[b] = reactive and (code == _OWN or parts.gap is None)
        p.x[b] = (*sc.start, 0.0, 0.0)
        p.t[b] = 0.0
        p.goal[b] = ep.goals[0]
        p.goal_idx[b] = 0
        p.goal_radius[b] = sc.goal_radius
        p.t_goal[b] = math.nan
        p.neg_k_att[b] = -ref_form.K_att
        p.v_ref_max[b] = ref_form.v_max
        p.dt[b] = dt
        p.dt_frame[b] = dt_frame
        p.decay[b] = math.exp(-k * dt)
        p.gain[b] = -math.expm1(-k * dt)
        p.k_acc[b] = k
        p.radius[b] = env.sensing_radius
        p.lam[b] = monitor.lambda_1
        p.vec[b] = vec
        if parts.gap is not None:
            gap = _form(forms, "loss", GapLossForm)
            p.scale[b] = gap.scale
            self._squash.setdefault(float(gap.scale), gap.squash)
        else:  # scored by the loss object (see end)
            p.scale[b] = math.nan
        p.last[b] = 0.0
        p.step[b] = 0
        p.fi[b] = sc.start_index
        p.last_frame[b] = last
        p.substeps[b] = substeps
        p.tau[b] = tau
        p.history[b] = int(env.history_frames)
        p.predictor[b] = code
        self._own = self._own or code == _OWN
        self._acp = self._acp or parts.acp is not None
        p.window[b] = int(window)
        p.shift[b] = shift
        p.shift_k[b] = form.samples(dt_frame) if isinstance(form, DelayedForm) else 0
        p.shift_x[b] = (
            (form.scale, 0.0)
            if isinstance(form, ScaledForm)
            else (getattr(form, "p", 0.0), getattr(form, "duration_s", 1.0))
        )
        p.noise_sigma[b] = getattr(form, "sigma_m", 0.0)
        p.seeds[b] = getattr(form, "seed", 0)
        p.scene_keys[b] = scene_key(sc.name)
        p.first_frame[b] = sc.first_frame
        if shift in (bk.NOISY, bk.DROPOUT) or code == bk.RECORDED:
            p.agent_id[b, : ids.size] = ids
        p.shift_counts[b] = 0
        p.rec_counts[b] = 0
        if recorded is not None:
            p.put_recorded(b, recorded[0])
            p.rec_step[b] = recorded[1]
        else:
            p.rec_len[b] = 0
        p.n_log[b] = 0
        p.wall[b] = 0.0
        p.n_predicted[b] = p.n_short_total[b] = p.n_bad_total[b] = 0
        p.counts[b] = 0
        p.done[b] = False
        p.need_begin[b] = True
        p.active[b] = True
        poly = np.concatenate([S.ravel(), s, verts.ravel()])
        p.poly[b, : poly.size] = poly
        p.poly_len[b] = poly.size
        fallback_kernel = filt_form.fallback
        p.fallback[b] = _FALLBACKS.get(fallback_kernel or "", PYTHON)
        p.forced[b] = False
        p.acp[b] = parts.acp is not None
        p.prm[b] = (
            apf.K_rep,
            apf.rho0,
            apf.d_c,
            apf.delta,
            apf.surface,
            float(fl.constraint.a),
            radius,
            not filt_form.speed_sides,
            filt_form.v_max,
            fallback_kernel == "lambda_search",
            filt_form.lambda_margin,
            p.cap,
            *fl.constraint.edge_settings(),
        )
        self.eps[b] = ep
        bk.log_frames(np.array([b]), p.store, p.where, p.fi, p.x, p.t, p.log, p.n_log)

    # ------------------------------------------------------------------ sampling time
    def begin(self, slots: np.ndarray) -> None:
        """Sampling time of ``slots``: sense, predict, interpolate."""
        p = self.pool
        bk.count_sensed(slots, p.store, p.where, p.fi, p.x, p.radius, p.sensed, p.n_agents)
        n = p.n_agents[slots]
        most = int(n.max(initial=0))
        if most > p.cap:
            p.ensure(agents=most)
        p.k_start[slots] = p.fi[slots]
        p.step[slots] = 0
        p.need_begin[slots] = False
        for b, m in zip(slots.tolist(), n.tolist(), strict=True):
            ep = self.eps[b]
            assert ep is not None  # slots are live
            ep.n_sensed.append(m)
            if p.vec[b]:  # each sensed agent's lambda (a new one's at the prior)
                assert isinstance(ep.monitor, AgentMonitor)
                ep.keys = np.asarray(ep.parts.env.scene.agent_ids[p.sensed[b, :m]], np.int64)
                ep.lams = ep.monitor.values(ep.keys)
                ref = float(ep.lams.min()) if m else 0.0  # the family's smallest entry
                p.lam[b] = ref
                p.lam_off[b, :m] = ep.lams - ref
        predicted = slots[n > 0]  # the controller asks its predictor only about agents
        if self._acp:  # the acp family's begin_interval runs at every sampling time
            regions = p.acp[slots]
            for b in slots[regions].tolist():
                self._predict_own(b)
                self._regions(b)
            predicted = slots[(n > 0) & ~regions]
        if self._own:
            own = p.predictor[predicted] == _OWN
            for b in predicted[own].tolist():
                self._predict_own(b)
            predicted = predicted[~own]
        if predicted.size:
            noisy = predicted[p.shift[predicted] == bk.NOISY]
            if noisy.size:
                self._noise(noisy)
            bk.predict_interpolate(
                predicted, p.store, p.where, p.fi, p.sensed, p.n_agents, p.predictor, p.window,
                p.history, p.tau, p.substeps, p.dt_frame, p.samples, p.xp, p.vp, p.n_short,
                p.n_bad, p.shift, p.shift_k, p.shift_x, p.seeds, p.scene_keys, p.first_frame,
                p.agent_id, p.noise, p.shift_counts, p.rec, p.rec_at, p.rec_step, p.rec_counts,
            )  # fmt: skip
            p.n_predicted[predicted] += 1
            p.n_bad_total[predicted] += p.n_bad[predicted]
            p.n_short_total[predicted] += p.n_short[predicted]

    def _noise(self, slots: np.ndarray) -> None:
        """The ``noisy`` shift's displacement of each sensed agent of ``slots`` at this
        sampling time, drawn for all of them at once as the predictor draws its own
        (:func:`~conformal_control.predictors.shift.noise_offsets`)."""
        p = self.pool
        n = p.n_agents[slots]
        m = int(n.max())
        i, a = np.nonzero(np.arange(m)[None, :] < n[:, None])  # (slot, agent), slot-major
        rows = slots[i]
        ids = p.agent_id[rows, p.sensed[rows, a]]
        frames = p.first_frame[rows] + p.fi[rows]
        p.noise[rows, a] = noise_offsets(
            p.noise_sigma[rows], p.seeds[rows], p.scene_keys[rows], frames, ids
        )

    def _regions(self, b: int) -> None:
        """Slot ``b``'s barrier at each horizon step of the interval (the acp family:
        ``d_c`` raised by the region's inflation at the interval's lambda), as
        :meth:`ACPController.decide <conformal_control.families.cbf.acp.ACPController.decide>`
        sets up the compiled step."""
        p, ep = self.pool, self.eps[b]
        assert ep is not None and ep.parts.acp is not None  # b is a live acp slot
        if not p.n_agents[b]:  # no agent: no row, the controller computes no region
            return
        forms = ep.parts.acp.region_barriers(float(p.lam[b]))
        H = len(forms)
        if H > p.acp_dc.shape[1]:
            p.acp_dc = p.grown(p.acp_dc, 1, H)
            p.acp_delta = p.grown(p.acp_delta, 1, H)
        p.acp_h[b] = H
        for h, form in enumerate(forms):
            p.acp_dc[b, h] = form.d_c
            p.acp_delta[b, h] = form.delta

    def _capped(self, b: int) -> None:
        """Count slot ``b``'s control instants whose region was capped (the acp family's
        ``n_capped_``, one per instant with agents, as its ``decide`` counts them)."""
        p, ep = self.pool, self.eps[b]
        assert ep is not None and ep.parts.acp is not None
        s = int(p.step[b])
        if not p.n_agents[b] or not s:
            return
        capped = ep.parts.acp.compiled_state().capped
        h = np.minimum(np.arange(s) // int(p.substeps[b]), capped.size - 1)
        ep.parts.acp.n_capped_ += int(capped[h].sum())

    def _predict_own(self, b: int) -> None:
        """Slot ``b``'s predictions from its own predictor: the environment's query (its
        sensor on the engine's state), the controller's ``begin_interval`` (prediction,
        counters, sanitising, interpolation), copied into ``xp`` / ``vp``."""
        p, ep = self.pool, self.eps[b]
        assert ep is not None  # b is live
        env, policy = ep.parts.env, ep.fl.family
        n = int(p.n_agents[b])
        # the environment senses where the engine's robot is, at the engine's frame and time
        env.from_compiled(ReplayCursor(x=p.x[b].copy(), frame=int(p.fi[b]), t=float(p.t[b])))
        query = env.sense()
        sensed = env.compiled_state().sensed
        assert sensed is not None  # an environment's cursor always holds what it sensed
        if not np.array_equal(sensed, p.sensed[b, :n]):  # both are the same range test
            raise RuntimeError(
                f"run_batch: the sensor and the engine disagree on the agents sensed in "
                f"episode {ep.index} at frame {query.frame}; use run_episode"
            )
        policy.begin_interval(query)
        form = policy.compiled_state()
        s = int(form.xp.shape[0])
        p.xp[b, :s, :n] = form.xp
        p.vp[b, :s, :n] = form.vp

    # ------------------------------------------------------------------ control instants
    def control(self, slots: np.ndarray) -> None:
        """The control instants of the current interval of ``slots``, each slot up to its
        interval's end or its episode's end, in one compiled call
        (:func:`~conformal_control.runs.engines.interval.run_interval`: reference, filter,
        plant, goal with waypoints, frame clock and frame log)."""
        p = self.pool
        todo = slots
        walk = slots[p.reactive[slots]] if self.crowds is not None else slots[:0]
        if walk.size:  # the robots' velocities at the start, the log rows before
            v_start = p.x[walk, 2:4].copy()
            n_log0 = p.n_log[walk].copy()
        while True:
            bad, paused = run_interval(
                todo, p.x, p.t, p.step, p.n_ctrl, p.tau, p.done,
                p.goal, p.goal_idx, p.goals, p.n_goals, p.goal_radius, p.t_goal, p.neg_k_att,
                p.v_ref_max,
                p.lam, p.n_agents, p.xp, p.vp, p.prm, p.poly, p.poly_len, p.fallback, p.work,
                p.last, p.counts,
                p.dt, p.decay, p.gain, p.k_acc,
                p.rec_x, p.rec_v, p.rec_lam, p.rec_code,
                p.store, p.where, p.substeps, p.fi, p.last_frame, p.log, p.n_log,
                p.keep, p.st_t, p.st_x, p.st_cmd, p.n_st,
                p.acp, p.acp_dc, p.acp_delta, p.acp_h, p.forced, p.forced_v, p.paused,
                p.vec, p.lam_off,
            )  # fmt: skip
            if paused < 0 or bad >= 0:
                break
            todo = todo[paused:]  # the paused slot decides, then runs on with the rest
            self._fall_back(int(todo[0]))
        if walk.size and bad < 0:
            crowds = self.crowds
            assert crowds is not None
            crowds.advance(walk, p, v_start, n_log0)
            for b in walk[p.mirror[walk]].tolist():
                ep = self.eps[b]
                assert ep is not None and isinstance(ep.parts.env, ReactiveEnvironment)
                crowds.mirror(b, ep.parts.env, p.store, p.where)
        if self._acp:
            for b in slots[p.acp[slots]].tolist():
                self._capped(b)
        if bad >= 0:
            ep = self.eps[bad]
            assert ep is not None  # bad is one of slots, which are live
            which = f"episode {ep.index} of the batch, " if len(self.eps) > 1 else ""
            raise ValueError(
                "Exact2DSafetyFilter received non-finite constraints, lambda or nominal "
                f"decision ({which}scene {ep.fl.scene.name}, t = {p.t[bad]:.3f} s); "
                "predictions must be sanitised before building constraints"
            )

    def _fall_back(self, b: int) -> None:
        """Slot ``b``'s infeasible step decided by its own fallback (one the compiled step
        does not decide, e.g. ``relax``), on the rows the step left in the work buffer,
        as :meth:`Exact2DSafetyFilter.step_apf_record
        <conformal_control.families.cbf.filters.exact2d.Exact2DSafetyFilter.step_apf_record>`
        hands it over; the decision is applied when the slot runs on."""
        p, ep = self.pool, self.eps[b]
        assert ep is not None
        n, cap = int(p.n_agents[b]), p.cap
        n0, n1, lam = p.paused.tolist()
        step = InfeasibleStep(
            np.array((n0, n1)),
            p.work[: 2 * n].reshape(n, 2).copy(),
            p.work[2 * cap : 2 * cap + n].copy(),
            lam,
            p.last[b].copy(),
            escape=Exact2DSafetyFilter.escape_in(p.work, cap, int(p.poly_len[b]) // 5),
            # (the collision distance Exact2DSafetyFilter.contact_times takes)
            ttc=time_to_contact(
                p.x[b, :2],
                p.xp[b, int(p.step[b]), :n],
                p.vp[b, int(p.step[b]), :n],
                float(max(p.prm[b, 12], p.prm[b, 2])),
                np.array((n0, n1)),
            ),
        )
        res = ep.parts.safety_filter.fall_back(step)
        v = np.asarray(res.decision, dtype=float)
        p.forced_v[b] = (v[0], v[1], res.lambda_applied)
        p.forced[b] = True

    # ------------------------------------------------------------------ interval end
    def end(self, slots: np.ndarray) -> list[int]:
        """Score the intervals of ``slots`` (they end now), update lambda; returns the
        slots whose episode is over."""
        p = self.pool
        # the gap loss's intervals with pairs to score (other losses: their objects, below)
        if slots.size == 1:  # one episode (run_episode's): the same test on scalars
            b = int(slots[0])
            one = p.n_agents[b] > 0 and p.step[b] > 0 and not math.isnan(p.scale[b])
            scored = slots if one else slots[:0]
        else:
            scored = slots[
                (p.n_agents[slots] > 0) & (p.step[slots] > 0) & ~np.isnan(p.scale[slots])
            ]
        top, top_applied, n_pairs, loss, applied = self._scores
        top[slots] = -np.inf
        top_applied[slots] = -np.inf
        n_pairs[slots] = 0
        loss[slots] = np.nan
        applied[slots] = np.nan
        agent_top = np.zeros(0)  # per agent of each scored slot (lambda run per agent)
        where: dict[int, int] = {}  # scored slot -> its agents' offset in agent_top
        if scored.size:
            counts = p.n_agents[scored]
            offsets = np.zeros(scored.size, dtype=np.int64)
            if scored.size > 1:
                np.cumsum(counts[:-1], out=offsets[1:])
            agent_top = np.full(int(counts.sum()), -np.inf)
            where = dict(zip(scored.tolist(), offsets.tolist(), strict=True))
            frames = -(-p.step[scored] // p.substeps[scored])  # frames the interval ran
            truth = np.empty((int(counts.sum()), int(frames.max()) + 1, 2))
            bk.gather_windows(
                scored, p.store, p.where, p.k_start, p.sensed, p.n_agents, offsets, truth
            )
            gap_maxima(
                scored, offsets, p.n_agents, p.step, truth, p.dt_frame, p.substeps, p.rec_x,
                p.rec_v, p.rec_lam, p.xp, p.vp, p.lam, p.prm, top, top_applied, n_pairs,
                p.vec, p.lam_off, agent_top,
            )  # fmt: skip
            for scale, squash in self._squash.items():
                # one loss scale in the engine: every scored slot has it
                sel = scored if len(self._squash) == 1 else scored[p.scale[scored] == scale]
                if sel.size:  # the loss's own squashing, s(r) = arctan(r / c) / pi
                    loss[sel] = squash(top[sel] + p.lam[sel])
                    applied[sel] = squash(top_applied[sel])
        finished = []
        for b in slots.tolist():
            ep = self.eps[b]
            assert ep is not None
            lam = float(p.lam[b])
            s = int(p.step[b])
            pairs = int(n_pairs[b])
            gap = ep.parts.gap
            if isinstance(ep.monitor, AgentMonitor):
                log, lam = self._end_per_agent(b, ep, where.get(b), agent_top, pairs)
                ep.intervals.append(log)
                p.lam[b] = lam
                extreme = [lam, *ep.monitor.current().tolist()]
                for x in extreme:
                    if not (math.isfinite(x) and abs(x) <= LAMBDA_LIMIT):
                        check_lambda(x, ep.fl, log.k)  # raises
                if self.on_interval is not None:
                    self.on_interval(log)
                if p.done[b]:
                    finished.append(b)
                else:
                    p.need_begin[b] = True
                continue
            score: IntervalScore | None = None
            record = revealed = None
            if gap is None:  # the loss object on the interval's record and truth
                record, revealed = self._record(b), self._truth(b)
            elif pairs:  # the compiled gap loss: the same arithmetic as CBFGapLoss
                score = IntervalScore(
                    float(loss[b]),
                    {
                        "loss_applied": float(applied[b]),
                        "max_gap": float(top[b]),
                        "n_pairs": pairs,
                        "n_truth_missing": s * int(p.n_agents[b]) - pairs,
                    },
                    _GapLossAt(gap, top[b]),
                )
            else:
                score = IntervalScore(None)
            log, lam = close_interval(
                len(ep.intervals),
                lam,
                s,
                rule=ep.fl.rule,
                monitor=ep.monitor,
                learn=ep.learn,
                loss=ep.parts.loss,
                record=record,
                truth=revealed,
                score=score,
            )
            ep.intervals.append(log)
            p.lam[b] = lam
            if not (math.isfinite(lam) and abs(lam) <= LAMBDA_LIMIT):
                check_lambda(lam, ep.fl, log.k)  # raises
            if self.on_interval is not None:
                self.on_interval(log)
            if p.done[b]:
                finished.append(b)
            else:
                p.need_begin[b] = True
        return finished

    def _end_per_agent(
        self, b: int, ep: _Episode, o: int | None, agent_top: np.ndarray, pairs: int
    ) -> tuple[IntervalLog, float]:
        """Slot ``b``'s interval end with lambda run per agent: each agent's gap loss from
        its largest gap (``agent_top[o:]``, the compiled gap loss), or the loss object's
        components on the interval's record and truth; then each agent's update
        (:func:`~conformal_control.core.loop.close_agent_interval`)."""
        p = self.pool
        assert isinstance(ep.monitor, AgentMonitor)
        s, n = int(p.step[b]), int(p.n_agents[b])
        gap = ep.parts.gap
        k = len(ep.intervals)
        if gap is None:  # the loss object on the interval's record and truth
            return close_agent_interval(
                k, ep.keys, ep.lams, s, monitor=ep.monitor, loss=ep.parts.loss,
                record=self._record(b), truth=self._truth(b),
            )  # fmt: skip
        top = np.full(n, np.nan)
        if o is not None:
            got = agent_top[o : o + n]
            top = np.where(np.isfinite(got), got, np.nan)
        comp = gap.keyed(ep.keys, top, ep.lams)
        diagnostics: dict[str, float] = {}
        if pairs and np.isfinite(comp.values).any():
            top_b, applied_b = self._scores[0][b], self._scores[1][b]
            diagnostics = {
                "loss_applied": float(gap.squash(applied_b)),
                "max_gap": float(top_b),
                "n_pairs": pairs,
                "n_truth_missing": s * n - pairs,
            }
        return close_agent_interval(
            k, ep.keys, ep.lams, s, monitor=ep.monitor, components=comp, diagnostics=diagnostics
        )

    def _record(self, b: int) -> CBFIntervalRecord:
        """Slot ``b``'s interval as the controller's ``interval_record`` gives it, without
        the filter's status strings (the engine keeps them as codes, ``rec_code``, for the
        animation record; the losses that read a record do not use them)."""
        p, ep = self.pool, self.eps[b]
        assert ep is not None
        s, n = int(p.step[b]), int(p.n_agents[b])
        fields = {
            "ids": np.asarray(ep.parts.env.scene.agent_ids[p.sensed[b, :n]]),
            "x_ego": p.rec_x[b, :s].copy(),
            "v_ego": p.rec_v[b, :s].copy(),
            "x_pred": p.xp[b, :s, :n].copy(),
            "v_pred": p.vp[b, :s, :n].copy(),
            "lam_applied": p.rec_lam[b, :s].copy(),
        }
        acp = ep.parts.acp
        if acp is not None:  # what its regions were made of (ACPController.interval_record)
            form = acp.compiled_state()
            return ACPIntervalRecord(
                **fields,
                pred_samples=form.pred_samples.copy(),
                sorted_scores=form.sorted_scores,
                inflation=form.inflation.copy(),
            )
        return CBFIntervalRecord(**fields)

    def _truth(self, b: int) -> CBFTruth:
        """Slot ``b``'s truth, revealed by its environment (its own code) on the engine's
        state of the interval: its start frame, the agents sensed then, its steps."""
        p, ep = self.pool, self.eps[b]
        assert ep is not None
        ep.parts.env.from_compiled(
            ReplayCursor(
                k_start=int(p.k_start[b]),
                sensed=p.sensed[b, : int(p.n_agents[b])].copy(),
                step=int(p.step[b]),
            )
        )
        return ep.parts.env.reveal()

    # ------------------------------------------------------------------ episode end
    def finish(self, b: int) -> tuple[int, EpisodeResult | EpisodeMetrics]:
        """Measure the episode of slot ``b`` with run_episode's code; free the slot.

        The counters go where the per-episode loop keeps them (the environment's frame log,
        ``t_goal_`` and ``n_sensed_``; the controller's and the filter's learned attributes),
        then :func:`run_episode`'s own measuring code runs on them.
        """
        p, ep = self.pool, self.eps[b]
        assert ep is not None
        fl = ep.fl
        sc, env, policy, filt = fl.scene, ep.parts.env, fl.family, ep.parts.safety_filter
        n = int(p.n_log[b])
        rows = p.log[b, :n]
        env.log = FrameLog(
            frame=(sc.first_frame + sc.start_index + np.arange(n)).tolist(),
            t=rows[:, 0].tolist(),
            state=list(rows[:, 1:5].copy()),
            d_min=rows[:, 5].tolist(),
        )
        env.t_goal_ = None if math.isnan(p.t_goal[b]) else float(p.t_goal[b])
        env.n_sensed_ = ep.n_sensed
        c = p.counts[b].tolist()
        policy.n_steps_ = c[4]
        if p.predictor[b] != _OWN:  # (an own predictor's are the controller's already)
            policy.n_nonfinite_predictions_ = int(p.n_bad_total[b])
        if p.n_predicted[b] and ep.info_keys:
            totals = {
                "n_short_history": int(p.n_short_total[b]),
                "n_stale": int(p.shift_counts[b, 0]),
                "n_unseen": int(p.shift_counts[b, 1]),
                "n_dropped": int(p.shift_counts[b, 2]),
                "n_missing": int(p.rec_counts[b, 0]),
                "n_missing_steps": int(p.rec_counts[b, 1]),
                "n_extrapolated": int(p.rec_counts[b, 2]),
                "n_nonfinite_current": int(p.rec_counts[b, 3]),
            }
            policy.forecast_info_ = {key: totals[key] for key in ep.info_keys}
        # the compiled step's counts, added to those a fallback decided in Python counted
        filt.n_solves_ += c[0]
        filt.n_infeasible_ += c[1]
        filt.n_fallback_ += c[2]
        name = filt.fallback_.name
        if c[2] - c[5]:
            filt.fallback_counts_[name] = filt.fallback_counts_.get(name, 0) + c[2] - c[5]
        if c[5]:  # steps the edge rule decided alone
            filt.fallback_counts_["escape"] = filt.fallback_counts_.get("escape", 0) + c[5]
        if c[3]:
            filt.events_["lambda_search_vertex"] = c[3]
        if c[6]:  # brake / hold decisions moved into the edge rule's escape polygon
            filt.events_["escape_projected"] = filt.events_.get("escape_projected", 0) + c[6]
        crowd_config: dict[str, Any] = {"crowd": "replay"}
        if p.reactive[b]:  # the simulated crowd back to its environment, as it walked
            assert self.crowds is not None and isinstance(env, ReactiveEnvironment)
            self.crowds.mirror(b, env, p.store, p.where)
            self.crowds.finish(b, env)
            crowd_config = env.crowd_config()
        result = LoopResult(
            intervals=ep.intervals, lambda_final=float(p.lam[b]), monitor=ep.monitor
        )
        metrics, intervals, traj = measure(
            fl, result, ep.learn, ep.lambda_safe, ep.floor, float(p.wall[b])
        )
        warn_after_run(fl, metrics, ep.learn, ep.max_frames, stacklevel=self.warn_stacklevel)
        p.active[b] = False
        self.eps[b] = None
        if self.output == "metrics":
            return ep.index, metrics
        config = episode_config(fl, ep.run, ep.lambda_safe)
        config["feasibility"] = jsonable(ep.floor.as_dict())
        config.update(self.extra_config or {})
        config["crowd"] = crowd_config
        config["engine"] = "batch"
        return ep.index, EpisodeResult(sc, config, metrics, intervals, traj, {}, result, None)

    # ------------------------------------------------------------------ the loop
    def load(self, b: int, index: int, scene: Scene, seed: int, max_frames: int | None) -> None:
        """Start episode ``index`` in slot ``b`` and lay out its interval's buffers."""
        p = self.pool
        self.start(b, index, scene, seed, max_frames)
        ep = self.eps[b]
        assert ep is not None
        frames = int(p.last_frame[b] - p.fi[b]) + 1
        p.prepare(b, ep.goals, frames * int(p.substeps[b]))

    def run(
        self, source: Iterator[tuple[int, Scene, int, int | None]], started: int = 0
    ) -> Iterator[tuple[int, EpisodeResult | EpisodeMetrics]]:
        """Advance every live episode one interval per iteration (every slot is then at a
        sampling time, so free slots are refilled at every iteration). Slots below
        ``started`` hold episodes loaded already (:meth:`load`)."""
        p = self.pool
        free = list(range(p.size - 1, started - 1, -1))  # slots to fill (popped from the end)
        slots = np.flatnonzero(p.active) if started else np.zeros(0, dtype=np.int64)
        elapsed = 0.0  # time of the iterations since the live slots last changed
        while True:
            if free:
                loaded = False
                while free:
                    nxt = next(source, None)
                    if nxt is None:
                        break
                    self.load(free.pop(), *nxt)
                    loaded = True
                if loaded:
                    slots = np.flatnonzero(p.active)
            if not slots.size:
                return
            t0 = time.perf_counter()
            # every live slot is at a sampling time: a new one, or its interval was scored
            self.begin(slots)
            self.control(slots)
            if self.on_control is not None:
                self.on_control(slots)
            finished = self.end(slots)
            elapsed += time.perf_counter() - t0
            if finished:  # each slot's share of the iterations it took part in
                p.wall[slots] += elapsed / slots.size
                elapsed = 0.0
                for b in finished:
                    yield self.finish(b)
                free += reversed(finished)
                slots = np.flatnonzero(p.active)


def _per_episode(value: Any, name: str) -> Iterator[Any]:
    """A value for every episode: a scalar repeated, or one per episode from a sequence."""
    if value is None or isinstance(value, (int, np.integer)):
        return repeat(None if value is None else int(value))
    if isinstance(value, Iterable) and not isinstance(value, (str, bytes)):
        return iter(value)
    raise TypeError(f"{name} must be an int, None or one value per scene, got {value!r}")


def iter_batch(
    scenes: Iterable[Scene],
    spec: Any = None,
    params: dict[str, Any] | None = None,
    *,
    max_frames: int | Iterable[int | None] | None = None,
    seeds: int | Sequence[int] | None = None,
    batch_size: int = 256,
    output: str = "metrics",
    extra_config: dict[str, Any] | None = None,
    **settings: Any,
) -> Iterator[tuple[int, EpisodeResult | EpisodeMetrics]]:
    """:func:`run_batch`, yielding ``(index, result)`` as episodes finish.

    Parameters
    ----------
    scenes : iterable of Scene
        Consumed lazily, one scene as a slot opens.
    spec : RunSpec or str, optional
        The run of every episode, or its predictor's registered name.
    params : dict, optional
        Parameter overrides (the run's ``params``).
    max_frames : int, iterable or None
        The frame limit of every episode, or one per scene (an iterator is consumed one
        value per scene as the scene is started).
    seeds : int, sequence or None
        The seed of every episode, or one per scene.
    batch_size : int
        Episodes alive at a time.
    output : {"metrics", "results"}
        What is yielded per episode.
    extra_config : dict, optional
        Merged into each episode's configuration.
    **settings
        Other settings of the run (:meth:`RunSpec.from_settings
        <conformal_control.core.spec.RunSpec.from_settings>`).

    Yields
    ------
    (int, EpisodeMetrics or EpisodeResult)
        In completion order; the int is the scene's position in ``scenes``.
    """
    settings.pop("max_frames", None)
    settings.pop("seed", None)
    run = as_run_spec(spec or settings.pop("predictor", None), params, **settings)
    # the engine keeps no animation record of a batch: the specification says so
    run = dataclasses.replace(run, record_animation=False)
    reason = supports(run)
    if reason is not None:
        raise ValueError(f"run_batch does not support this configuration: {reason}")
    if output not in ("metrics", "results"):
        raise ValueError(f"output must be 'metrics' or 'results', got {output!r}")
    if int(batch_size) != batch_size or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    compile_now()  # many episodes: compiled from the start (see conformal_control.core.jit)
    frames = _per_episode(max_frames, "max_frames")
    seed_values = _per_episode(0 if seeds is None else seeds, "seeds")

    def source() -> Iterator[tuple[int, Scene, int, int | None]]:
        for i, scene in enumerate(scenes):
            try:
                mf, seed = next(frames), next(seed_values)
            except StopIteration:
                raise ValueError("max_frames / seeds have fewer values than scenes") from None
            yield i, run.on_scene(scene), int(seed), None if mf is None else int(mf)

    engine = _Engine(int(batch_size), output, run, extra_config)
    yield from engine.run(source())


def run_batch(
    scenes: Iterable[Scene],
    spec: Any = None,
    params: dict[str, Any] | None = None,
    *,
    max_frames: int | Sequence[int | None] | None = None,
    seeds: int | Sequence[int] | None = None,
    batch_size: int = 256,
    output: str = "metrics",
    **settings: Any,
) -> list[EpisodeMetrics] | list[EpisodeResult]:
    """Run one episode per scene, many at once, with the metrics of :func:`run_episode`.

    Parameters
    ----------
    scenes : iterable of Scene
        Consumed lazily (a generator keeps only the live episodes' scenes in memory).
    spec : RunSpec or str, optional
        The run of every episode (:class:`~conformal_control.core.spec.RunSpec`), or its
        predictor (a registered name).
    params : dict, optional
        Parameter overrides (the run's ``params``).
    max_frames : int, sequence or None
        The frame limit of every episode, or one per scene (e.g. each benchmark
        scenario's ``max_frames``).
    seeds : int, sequence or None
        The seed recorded for every episode (default 0, as ``run_episode``), or one per
        scene.
    batch_size : int
        Episodes alive at a time (memory grows with it; 256 keeps the per-iteration
        overhead well below the compiled work).
    output : {"metrics", "results"}
        Return :class:`EpisodeMetrics` (default) or :class:`EpisodeResult` objects.
    **settings
        Any other setting of the run that :func:`supports` accepts (``units``,
        ``learn``, ``rule_params``, ``fallback``, ``lambda_safe``, ...), and
        ``extra_config`` (merged into each episode's config).

    Returns
    -------
    list
        One item per scene, in the order of ``scenes``.

    Raises
    ------
    ValueError
        For a configuration :func:`supports` rejects (the message gives the reason), and
        for anything ``run_episode`` rejects.
    """
    out: dict[int, Any] = {}
    for index, item in iter_batch(
        scenes,
        spec,
        params,
        max_frames=max_frames,
        seeds=seeds,
        batch_size=batch_size,
        output=output,
        **settings,
    ):
        out[index] = item
    return [out[i] for i in range(len(out))]


# ------------------------------------------------------------------------------ one episode
def run_single(
    scene: Scene,
    run: RunSpec,
    *,
    on_interval: Callable[[IntervalLog], None] | None = None,
    extra_config: dict[str, Any] | None = None,
) -> EpisodeResult | None:
    """One episode of ``run`` on the compiled engine, as :func:`run_episode` returns it.

    The result is the one the per-episode loop gives (metrics but the wall time,
    intervals, trajectory, per-instant ``steps`` and, with ``record_animation``, the
    animation record), with ``config["engine"] = "batch"``. With ``run.engine == "auto"``
    returns None if the engine does not run this configuration (the caller runs the
    loop); with ``"batch"`` raises ``ValueError`` saying why.

    Parameters
    ----------
    scene : Scene
    run : RunSpec
        The episode's specification.
    on_interval : callable, optional
        Called with each scored interval's log, as the loop calls it.
    extra_config : dict, optional
        Merged into the configuration.
    """
    engine = run.engine
    reason = supports(run)
    if reason is None and not EXACT_FOR_THIS_PYTHON:
        reason = (
            "the engine's distances reproduce CPython 3.11's math.hypot, not this "
            f"Python's ({sys.version_info[0]}.{sys.version_info[1]})"
        )
    if reason is not None:
        if engine == "auto":
            return None
        raise ValueError(f"engine='batch' cannot run this configuration: {reason}")
    record_animation = run.record_animation
    eng = _Engine(1, "results", run, extra_config)
    p = eng.pool
    p.keep = True
    recorder: list[AnimationRecorder] = []
    built: list[Flagship] = []

    def on_control(slots: np.ndarray) -> None:
        ep = eng.eps[0]
        assert ep is not None
        if not built:
            fl = ep.fl
            built.append(fl)
            if record_animation:
                si = fl.params.si
                recorder.append(
                    AnimationRecorder(
                        fl.scene,
                        fl.family,
                        fl.barrier,
                        fl.params.tau_frames,
                        si["substeps"],
                        si["sensing_radius"],
                    )
                )
        if recorder:  # what the recorder reads of the controller after an interval
            s, n = int(p.step[0]), int(p.n_agents[0])
            recorder[0].add_interval(
                ep.fl.scene.agent_ids[p.sensed[0, :n]], p.xp[0, :s, :n], p.rec_code[0, :s]
            )

    eng.on_control = on_control
    eng.on_interval = on_interval
    seed, max_frames = run.seed, run.max_frames
    # the warnings of building the episode (before the engine knows whether it runs it)
    # are re-issued for run_episode's caller, unless the loop runs it instead; the
    # warnings of the run point at the caller by themselves
    caught: list[warnings.WarningMessage] = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            eng.load(0, 0, scene, seed, max_frames)
    except _NotRun:
        if engine == "auto":
            caught.clear()  # the loop builds the episode again and warns itself
            return None
        raise
    finally:
        for w in caught:
            warnings.warn(w.message, w.category, stacklevel=3)
    # warn_after_run < finish < run < run_single < run_episode < its caller
    eng.warn_stacklevel = 6
    [(_, result)] = list(eng.run(iter(()), started=1))
    assert isinstance(result, EpisodeResult)
    n = int(p.n_st[0])
    result.steps = {
        "t": p.st_t[0, :n].copy(),
        "x": p.st_x[0, :n].copy(),
        "cmd": p.st_cmd[0, :n].copy(),
    }
    if recorder:
        si = built[0].params.si
        env = built[0].env
        if isinstance(env, ReactiveEnvironment):  # the pedestrians the robot met, as the loop
            recorder[0].scene = env.simulated_scene()
        result.animation = recorder[0].finish(
            result.trajectory,
            result.intervals,
            {"epsilon": si["epsilon"], "lambda_unit": result.metrics.unit("lambda_final")},
        )
    return result
