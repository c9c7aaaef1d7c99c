"""What the batch engine runs, and how it reads a built episode: :func:`supports` (None or
the reason, from a run's specification), the compiled counterparts it has kernels for
(:data:`KERNELS`), :func:`episode_parts` (a built flagship's roles as the classes the engine
runs, or :class:`NotRun`), and how each episode's predictor runs (:func:`prediction`:
compiled, with a shift, replayed from a predictions file, or its own object).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, TypeVar, cast

import numpy as np

from ....core import registry
from ....core.base import Loss, Plugin
from ....core.spec import RunSpec
from ....data.scene import Scene
from ....families.cbf.acp import ACPController
from ....families.cbf.barriers import APFBarrier
from ....families.cbf.constraint import ConformalConstraint
from ....families.cbf.controller import ConformalCBFController
from ....families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from ....families.cbf.filters.exact2d import Exact2DSafetyFilter
from ....families.cbf.loss import CBFGapLoss
from ....families.cbf.reference import AttractiveField
from ....predictors.constant_velocity import ConstantVelocityForm
from ....predictors.recorded import RecordedForm
from ....predictors.shift import DelayedForm, ScaledForm, ShiftForm
from ....world.crowds.crowd import Crowd
from ....world.reactive import ReactiveEnvironment
from ....world.replay import ReplayEnvironment
from ...build import Flagship
from .. import kernels as bk
from .. import recorded_kernels as rk
from ..gap_kernels import BRAKE, HOLD, SEARCH
from ..reactive import unsupported_crowd

_T = TypeVar("_T")

#: What the engine compiles, per role of a run: the compiled counterparts it has kernels
#: for. A plugin runs compiled when its class declares one of them (``capabilities.compiled``,
#: see :class:`~conformal_control.core.capabilities.Capabilities`); the role's default (None)
#: always does.
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
RECORD_LOSSES = frozenset({"collision", "distance_shortfall", "acp_miscoverage"})
#: Predictor code of an episode whose predictor is called in Python (not compiled).
OWN = -1
FALLBACKS = {"lambda_search": SEARCH, "brake": BRAKE, "hold": HOLD}  # else PYTHON
PREDICTORS = {
    "constant_velocity": bk.CONSTANT_VELOCITY,
    "oracle": bk.ORACLE,
    "recorded": bk.RECORDED,
}
#: The predictor shifts the compiled prediction applies (to a compiled predictor).
SHIFTS = {"delayed": bk.DELAYED, "noisy": bk.NOISY, "scaled": bk.SCALED, "dropout": bk.DROPOUT}


def compiled_name(cls: type) -> str | None:
    """The compiled form ``cls`` declares (its ``capabilities.compiled``; None for a class
    that is no plugin)."""
    return cls.capabilities.compiled if issubclass(cls, Plugin) else None


def _kernel_of(role: str, name: str) -> str | None:
    """The compiled counterpart the plugin registered as ``name`` declares (None: none,
    or no such plugin: the loop then says so)."""
    try:
        return compiled_name(registry.get(role, name))
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


class NotRun(ValueError):
    """An episode as built is not one the engine runs (a name resolved to a plugin of
    another class); the message says why."""

    def __init__(self, why: str) -> None:
        super().__init__(f"run_batch cannot run this episode: {why}; use run_episode")


def _exact(obj: object, cls: type[_T], role: str) -> _T:
    """``obj`` if its class is exactly ``cls`` (a subclass may compute something else
    than the compiled step does), else :class:`NotRun`."""
    if type(obj) is not cls:
        raise NotRun(f"the {role} is a {type(obj).__name__}, not a {cls.__name__}")
    return obj


def _compiled(obj: object, cls: type[_T], role: str) -> _T:
    """``obj`` if its class declares the compiled counterpart ``cls`` declares (its own
    ``capabilities.compiled``), else
    :class:`NotRun`."""
    kernel = compiled_name(cls)
    if kernel is None or compiled_name(type(obj)) != kernel:
        raise NotRun(
            f"the {role} is a {type(obj).__name__}, which does not declare the compiled "
            f"counterpart {kernel!r}"
        )
    return cast(_T, obj)


@dataclass(frozen=True)
class Parts:
    """The roles of a built episode the engine reads, as the classes it runs."""

    env: ReplayEnvironment
    barrier: APFBarrier
    safety_filter: Exact2DSafetyFilter
    reference: AttractiveField
    dynamics: VelocityTrackingDoubleIntegrator
    loss: Loss[Any, Any]  # a CBFGapLoss (compiled) or one of RECORD_LOSSES
    gap: CBFGapLoss | None  # the loss if it is the gap loss
    acp: ACPController | None  # the decision family if it is the acp family


def episode_parts(fl: Flagship) -> Parts:
    """The roles of ``fl`` as the classes the engine runs; raises :class:`NotRun` (a
    ValueError) if the episode as built is not one it runs."""
    policy = fl.family
    if compiled_name(type(policy)) not in KERNELS["family"] or not isinstance(
        policy, ConformalCBFController
    ):
        raise NotRun(
            f"the decision family is a {type(policy).__name__}, which declares none of "
            f"{', '.join(sorted(KERNELS['family']))}"
        )
    if policy.reciprocity is not None:
        raise NotRun("the decision family has robots' reciprocity")
    env = fl.env
    if type(env) is ReactiveEnvironment:
        crowd = env.crowd
        if type(crowd) is not Crowd:
            raise NotRun(f"the crowd is a {type(crowd).__name__}, not a Crowd")
    else:
        env = _exact(env, ReplayEnvironment, "environment")
    constraint = _exact(fl.constraint, ConformalConstraint, "constraint")
    barrier = _compiled(fl.barrier, APFBarrier, "barrier")
    filt = _compiled(fl.safety_filter, Exact2DSafetyFilter, "safety filter")
    reference = _compiled(fl.reference, AttractiveField, "reference")
    dynamics = _compiled(fl.dynamics, VelocityTrackingDoubleIntegrator, "dynamics")
    loss = fl.loss
    kernel = compiled_name(type(loss))
    gap = cast(CBFGapLoss, loss) if kernel == "cbf_gap" else None
    if gap is None and kernel not in RECORD_LOSSES:
        shown = ", ".join(sorted(KERNELS["loss"]))
        raise NotRun(f"the loss is a {type(loss).__name__}, which declares none of {shown}")
    if (gap is not None and gap.constraint is not constraint) or (
        policy.constraint is not constraint
    ):
        raise NotRun("the loss and the controller do not share the run's constraint")
    if filt.compiled_step is not True:
        raise NotRun("the safety filter's compiled step is off")
    fallback = filt.fallback
    if not isinstance(fallback, str) and compiled_name(type(fallback)) in COMPILED_FALLBACKS:
        # (a fallback decided in Python is the episode's own object, parameters and all)
        raise NotRun("the compiled fallbacks run as registered, not as a configured instance")
    acp = policy if isinstance(policy, ACPController) else None
    if (acp is not None) != (compiled_name(type(policy)) == "acp"):
        raise NotRun(f"the decision family {type(policy).__name__} is not the class it declares")
    return Parts(env, barrier, filt, reference, dynamics, loss, gap, acp)


def form_of(forms: dict[str, Any], role: str, cls: type[_T]) -> _T:
    """The compiled form of ``role`` among ``forms`` (the flagship's
    :meth:`~conformal_control.runs.build.Flagship.compiled_forms`), as the kernel it
    declares reads it; :class:`NotRun` if the part hands another."""
    form = forms.get(role)
    if not isinstance(form, cls):
        raise NotRun(f"the {role} declares {cls.kernel!r} but hands no {cls.__name__}")  # type: ignore[attr-defined]
    return form


def _predictor_code(pred: object) -> int:
    """The compiled predictor of :func:`~conformal_control.runs.engines.kernels.predict_interpolate`
    that ``pred``'s class declares (``capabilities.compiled``), else ``OWN``."""
    return PREDICTORS.get(compiled_name(type(pred)) or "", OWN)


def _window_of(form: object) -> Any:
    """The constant-velocity predictor's window, read from its compiled form (as given:
    checked by the caller); :class:`NotRun` if the predictor hands no such form."""
    if not isinstance(form, ConstantVelocityForm):
        raise NotRun("the predictor declares 'constant_velocity' but hands no form of it")
    return form.window


def _valid_window(window: Any) -> bool:
    return bool(int(window) == window and window >= 1)


def prediction(
    pred: Plugin, form: object, dt_frame: float, history: int, ids: np.ndarray
) -> tuple[int, int, ShiftForm | None, Any]:
    """How the compiled prediction runs ``pred`` (whose compiled form is ``form``): (the
    predictor code, the shift code, the shift's form, the constant-velocity window, 1 for
    another predictor). A predictor shift (:mod:`~conformal_control.predictors.shift`) of
    a compiled predictor runs compiled with it (the wrapped predictor read through its own
    compiled form); one that returns the wrapped forecast itself is that predictor; one
    the compiled form would not follow exactly where the wrapper raises or reads what the
    kernel does not hold (a delay beyond the history, a bad window, agent ids that are not
    integers) is called as it is (``OWN``).

    Parameters
    ----------
    pred : Plugin
        The episode's predictor.
    form : object
        Its compiled form.
    dt_frame : float
        The scene's frame period (s).
    history : int
        Frames of history the environment keeps.
    ids : np.ndarray
        The scene's agent ids.
    """
    kernel = compiled_name(type(pred)) or ""
    own = (OWN, bk.NO_SHIFT, None, 1)
    if kernel not in SHIFTS:
        code = _predictor_code(pred)
        if code == bk.RECORDED:
            return _recorded_prediction(form, ids)
        return code, bk.NO_SHIFT, None, _window_of(form) if code == bk.CONSTANT_VELOCITY else 1
    if not isinstance(form, ShiftForm) or form.kernel != kernel:
        raise NotRun(f"the predictor declares {kernel!r} but hands no form of that shift")
    base = form.base
    code = _predictor_code(base)
    window: Any = 1
    if code == bk.CONSTANT_VELOCITY:
        window = _window_of(base.compiled_state())
        if not _valid_window(window):
            return own
    if code in (OWN, bk.RECORDED):  # (a shift of recorded forecasts: called as it is)
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
    return code, SHIFTS[kernel], form, window


def _recorded_prediction(form: object, ids: np.ndarray) -> tuple[int, int, None, Any]:
    """How the compiled prediction runs a ``recorded`` predictor (whose compiled form is
    ``form``): compiled with its fallback's window when the fallback is the constant-velocity
    predictor with a valid window and the agents' ids are integers (the predictor's
    ``astype(int64)`` of other ids is not what the kernel reads), else called as it is."""
    if not isinstance(form, RecordedForm):
        raise NotRun("the predictor declares 'recorded' but hands no RecordedForm")
    own = (OWN, bk.NO_SHIFT, None, 1)
    fallback = form.fallback
    if _predictor_code(fallback) != bk.CONSTANT_VELOCITY:
        return own
    window = _window_of(fallback.compiled_state())
    if not _valid_window(window) or not np.issubdtype(ids.dtype, np.integer):
        return own
    return bk.RECORDED, bk.NO_SHIFT, None, window


def recorded_block(
    form: RecordedForm, sc: Scene, dt_frame: float, last: int
) -> tuple[np.ndarray, float] | None:
    """The forecasts of ``sc``'s predictions file that an episode sampling at frames
    ``sc.start_index`` .. ``last`` can read, packed
    (:func:`~conformal_control.runs.engines.recorded_kernels.pack`: the latest issue at or before
    the first sampling time, and every later one up to the last), and the step length;
    None where the predictor raises on this scene (no file for it, a missing or malformed
    file): the episode's own predictor is then called, and raises as in the loop, at its
    first prediction.

    Parameters
    ----------
    form : RecordedForm
        The ``recorded`` predictor's compiled form.
    sc : Scene
        The episode's scene.
    dt_frame : float
        The scene's frame period (s).
    last : int
        The episode's last frame index.
    """
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


def info_keys(code: int, shift: int, form: ShiftForm | None) -> tuple[str, ...]:
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
