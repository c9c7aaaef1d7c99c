"""The conformal CBF controller for your own simulator or robot, one call at a time.

:class:`StepwiseCBF` keeps what the replay environment keeps for a recorded scene -- the
agents' histories, the sampling times, the truth of each interval -- but from a live
stream: you hand it every sensor sample with :meth:`StepwiseCBF.observe` and ask it for a
velocity at every control instant with :meth:`StepwiseCBF.step`::

    ctrl = StepwiseCBF("constant_velocity", epsilon=0.0, eta=0.5, stream=Stream(tau=0.4, dt=0.1))
    for k in range(n_samples):                    # sensor samples, every dt seconds
        ctrl.observe(ids, positions, t=k * dt)    # agents seen at this sample (m)
        for j in range(ctrl.substeps):            # control instants, every dt/substeps
            v = ctrl.step(ego_state, t=k * dt + j * ctrl.dt_control, goal=goal)
            ego_state = my_robot.apply(v)

Timing, as in the paper: every ``tau`` seconds (a sampling time) it closes the interval
that ends there -- the truth of the agents sensed at its start is read from the samples
observed since, the loss is scored and lambda updated -- then senses the agents within
``sensing_radius``, predicts them over the next ``tau`` and decides with the new lambda
until the next sampling time. Call :meth:`observe` with a sample BEFORE :meth:`step` at
the same time; call :meth:`step` exactly every ``dt / substeps`` seconds. Units are SI.

The input contract, checked at every call (a ``ValueError`` naming the offending value,
never a silent repair):

* **times** lie on the grid: sample times ``t = k dt`` (any integer ``k``, so samples
  before the start may be negative), control times ``t = k dt + j dt / substeps``;
* **samples** arrive once each, in increasing time (a second :meth:`observe` at the same
  ``t`` is refused, not merged or replaced), not earlier than the next control instant
  (once :meth:`step` has been called) and at most one interval (``tau``) ahead of it;
  samples may be skipped (a sensor dropout is missing truth, counted), except the sample
  at a sampling time, which :meth:`step` needs;
* **agent ids** are whole numbers, unique within a sample; positions are finite, one
  (x, y) row per id;
* **control steps**: exactly ``substeps`` calls of :meth:`step` per sample, at the
  control times in order (a skipped or repeated control instant is refused);
* **ego state** is 4 finite numbers, **goal** 2 finite numbers;
* **parameters**: ``epsilon`` strictly inside the loss's range ((-1/2, 1/2) for the
  default loss, checked by the same function as the command line and
  :func:`conformal_control.run`), ``eta`` finite and >= 0, lengths, gains and rates
  finite and > 0.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core import registry
from ...core.base import Loss, Settings, UpdateRule
from ...core.exceptions import ConformalControlDeprecationWarning, InputError
from ...core.loop import ConformalStepper, LoopResult
from ...data.tracks import agent_ids
from ...predictors.base import PredictionQuery, Predictor
from .barriers import APFBarrier
from .constraint import ConformalConstraint
from .controller import ConformalCBFController, ControlState
from .loss import CBFGapLoss, CBFTruth
from .reference import AttractiveField
from .roles import Barrier, ReferenceController, SafetyFilter

#: Tolerance on time grids, as a fraction of the grid's step.
_GRID_TOL = 1e-6

__all__ = ["StepwiseCBF", "Stream"]


@dataclass(frozen=True)
class Stream(Settings):
    """The timing and sensing of the stream a stepwise controller is fed.

    Parameters
    ----------
    tau : float
        Sampling period of sensor, predictor and lambda update (s); a whole number of
        sensor samples.
    dt : float
        Sensor sample period (s, > 0).
    substeps : int
        Control instants per sensor sample (>= 1).
    sensing_radius : float
        Agents farther than this (m) at a sampling time are ignored until the next one.
    history : int
        Samples of history handed to the predictor (>= 1).
    """

    tau: float = 0.4
    dt: float = 0.1
    substeps: int = 4
    sensing_radius: float = 10.0
    history: int = 40

    def check(self) -> int:
        """Validate the fields (one-line errors naming the field); return the number
        of sensor samples per interval (``tau / dt``)."""
        from ...core.update_rules.base import check_positive

        for name in ("tau", "dt", "sensing_radius"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
                raise InputError(f"{name} must be a finite number > 0, got {value!r}")
            check_positive(name, float(value))
        for name in ("substeps", "history"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        tau_samples = self.tau / self.dt
        if round(tau_samples) < 1 or abs(tau_samples - round(tau_samples)) > 1e-9:
            raise ValueError(
                f"tau ({self.tau} s) must be a whole number of samples of dt ({self.dt} s)"
            )
        return round(tau_samples)


def stream_from(stream: Stream | None, legacy: dict[str, Any], owner: str) -> Stream:
    """``stream`` (default ``Stream()``) with the former flat keywords in ``legacy``
    (``tau=``, ``dt=``, ``substeps=``, ``sensing_radius=``, ``history=``) applied, each
    with a ``DeprecationWarning``; they are removed from ``legacy``.

    Parameters
    ----------
    stream : Stream or None
        The caller's stream settings (None: the defaults).
    legacy : dict
        The constructor's extra keywords (modified: the stream's fields are taken out).
    owner : str
        The class named in the warning.
    """
    out = Stream() if stream is None else stream
    old = {k: legacy.pop(k) for k in [k for k in legacy if k in Stream.__dataclass_fields__]}
    if old:
        given = ", ".join(f"{k}={v!r}" for k, v in old.items())
        warnings.warn(
            f"{owner}({', '.join(f'{k}=...' for k in old)}) is deprecated: give "
            f"stream=Stream({given}) (removed in 0.4, not before 2027-06-30)",
            ConformalControlDeprecationWarning,
            stacklevel=3,
        )
        out = Stream(**{**out.get_params(), **old})
    return out


def reject_unknown(owner: str, legacy: dict[str, Any]) -> None:
    """A ``TypeError`` for keywords left in ``legacy``, as Python's own."""
    if legacy:
        raise TypeError(
            f"{owner}.__init__() got an unexpected keyword argument {next(iter(legacy))!r}"
        )


class StepwiseCBF:
    """Conformal CBF controller driven by your own loop (SI units throughout).

    Parameters
    ----------
    predictor : Predictor or str
        A predictor instance or a registered name.
    epsilon : float
        Target average loss, in (-1/2, 1/2).
    eta : float
        Learning rate of lambda (1/s); 0 keeps lambda fixed.
    stream : Stream, optional
        Timing and sensing of the stream: ``tau`` (s), ``dt`` (s), ``substeps``,
        ``sensing_radius`` (m), ``history`` (samples); default ``Stream()`` (0.4 s,
        0.1 s, 4, 10 m, 40).
    a : float
        Slope of alpha(h) = a h (1/s).
    barrier : Barrier, optional
        Default: the APF barrier with ``d_c`` and a 10 m influence distance.
    d_c : float
        Collision distance robot-agent, centre to centre (m), for the default barrier.
    safety_filter : SafetyFilter or str, optional
        Default: the registered ``exact2d`` filter (exact 2-D QP, compiled) with ``v_max``.
    reference : ReferenceController, optional
        Default: the attractive field with ``K_att`` and ``v_max``.
    rule : UpdateRule, optional
        Default: the fixed-step rule with ``epsilon``, ``eta``, ``lambda_init`` and the
        CBF's default lambda floor
        (:func:`~conformal_control.families.cbf.feasibility.default_lambda_min`:
        0.8 times ``-a h_max``, -4/s with the defaults); give a rule to widen it.
    loss : Loss, optional
        Default: the paper's gap loss on the same constraint with scale ``loss_scale``.
    v_max, K_att : float
        Speed bound (m/s) and attractive gain (1/s) of the defaults.
    loss_scale : float
        c in s(r) = arctan(r / c) / pi (1/s).
    lambda_init : float
        lambda_1 (1/s).
    **legacy
        The former flat keywords ``tau``, ``dt``, ``substeps``, ``sensing_radius``,
        ``history``: still accepted, with a ``DeprecationWarning`` (give ``stream=``).
    """

    def __init__(
        self,
        predictor: Predictor | str = "constant_velocity",
        *,
        epsilon: float = 0.0,
        eta: float = 1.0,
        stream: Stream | None = None,
        a: float = 10.0,
        barrier: Barrier | None = None,
        d_c: float = 1.0,
        safety_filter: SafetyFilter | str | None = None,
        reference: ReferenceController | None = None,
        rule: UpdateRule | None = None,
        loss: Loss[Any, Any] | None = None,
        v_max: float = 2.0,
        K_att: float = 1.0,
        loss_scale: float = 1.0,
        lambda_init: float = 0.0,
        **legacy: Any,
    ) -> None:
        from ...core.update_rules.base import check_epsilon, check_finite, check_positive

        stream = stream_from(stream, legacy, "StepwiseCBF")
        reject_unknown("StepwiseCBF", legacy)
        for name, value in (
            ("a", a),
            ("d_c", d_c),
            ("v_max", v_max),
            ("K_att", K_att),
            ("loss_scale", loss_scale),
        ):
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
                raise InputError(f"{name} must be a finite number > 0, got {value!r}")
            check_positive(name, value)
        self.tau_samples = stream.check()
        if isinstance(eta, bool) or not isinstance(eta, (int, float, np.number)):
            raise InputError(f"eta must be a finite number >= 0, got {eta!r}")
        check_positive("eta", eta, allow_zero=True)
        check_finite("lambda_init", lambda_init)
        bounds = loss.bounds if loss is not None else CBFGapLoss.bounds
        if rule is None:
            check_epsilon(epsilon, bounds)
        else:
            target = getattr(rule, "epsilon", None)
            if target is not None:
                check_epsilon(target, bounds)
        self.stream = stream
        self.dt = float(stream.dt)
        self.substeps = int(stream.substeps)
        self.dt_control = self.dt / self.substeps
        self.sensing_radius = float(stream.sensing_radius)
        self.history = int(stream.history)
        pred: Predictor = (
            registry.create("predictor", predictor) if isinstance(predictor, str) else predictor
        )
        barrier = barrier if barrier is not None else APFBarrier(rho0=10.0, d_c=d_c)
        self.constraint = ConformalConstraint(barrier, a=a)
        filt: SafetyFilter
        if safety_filter is None or isinstance(safety_filter, str):
            name = safety_filter or "exact2d"
            filt = registry.create("safety_filter", name, v_max=v_max)
        else:
            filt = safety_filter
        reference = reference if reference is not None else AttractiveField(K_att, v_max)
        self.controller = ConformalCBFController(
            pred, self.constraint, filt, reference, substeps=self.substeps
        )
        if rule is None:
            from ...core.update_rules import FixedEtaRule
            from .feasibility import default_lambda_min

            # lambda never sinks below the default floor (a share of -a h_max, issue 30)
            floor = default_lambda_min(float(a), barrier.upper_bound)
            rule = FixedEtaRule(
                epsilon=epsilon,
                eta=eta,
                lambda_init=lambda_init,
                lambda_min=min(floor, float(lambda_init)),
            )
        loss = loss if loss is not None else CBFGapLoss(self.constraint, scale=loss_scale)
        self.stepper = ConformalStepper(self.controller, loss, rule, learn=eta > 0)
        self.stepper.start()
        self._samples: dict[int, dict[int, np.ndarray]] = {}  # sample index -> id -> xy
        self._latest: int | None = None
        self._start: int | None = None  # sample index of the open interval's start
        self._sensed = np.zeros(0, dtype=np.int64)
        self._step = 0

    # ------------------------------------------------------------------ input
    @staticmethod
    def _time(t: object, call: str) -> float:
        if isinstance(t, bool) or not isinstance(t, (int, float, np.number)):
            raise InputError(f"{call}: t must be a number of seconds, got {t!r}")
        value = float(t)
        if not math.isfinite(value):
            raise InputError(f"{call}: t must be finite, got {t!r}")
        return value

    def _index(self, t: object) -> int:
        value = self._time(t, "observe()")
        k = value / self.dt
        if abs(k - round(k)) > _GRID_TOL * max(1.0, abs(k) * 1e-9):
            raise InputError(f"observe() at t = {t} s is not a multiple of dt = {self.dt} s")
        return round(k)

    def _next_tick(self) -> int | None:
        """Control instant (in units of dt / substeps) of the next :meth:`step`, if started."""
        if self._start is None:
            return None
        return self._start * self.substeps + self._step

    def observe(self, ids: Sequence[int] | np.ndarray, positions: np.ndarray, t: float) -> None:
        """One sensor sample: the agents seen at time ``t`` (s) and their positions (m).

        Agents not listed are absent at that sample (they may reappear later). ``ids``
        are whole numbers, unique within the sample; ``positions`` is (len(ids), 2). See
        the module docstring for the time grid and the order of calls.
        """
        k = self._index(t)
        idv = agent_ids(ids, f"observe() at t = {t} s: ids").reshape(-1)
        pos = np.asarray(positions, dtype=float)
        if pos.size == 0 and idv.size == 0:
            pos = pos.reshape(0, 2)
        if pos.ndim != 2 or pos.shape[1] != 2:
            raise InputError(
                f"observe() at t = {t} s: positions must be an (n, 2) array, got shape {pos.shape}"
            )
        if idv.size != pos.shape[0]:
            raise InputError(f"observe() at t = {t} s: {idv.size} ids for {pos.shape[0]} positions")
        uniq, counts = np.unique(idv, return_counts=True)
        if (counts > 1).any():
            dup = int(uniq[np.argmax(counts > 1)])
            raise InputError(
                f"observe() at t = {t} s: id {dup} appears {int(counts.max())} times; each "
                "agent once per sample"
            )
        if not np.isfinite(pos).all():
            raise InputError("observed positions must be finite (leave absent agents out)")
        if self._latest is not None and k == self._latest:
            raise InputError(
                f"observe() at t = {t} s: that sample was already observed (one call per "
                "sample; put every agent seen at that time in it)"
            )
        if self._latest is not None and k < self._latest:
            raise InputError(f"samples must arrive in time order (t = {t} s after a later one)")
        tick = self._next_tick()
        if tick is not None:
            if k * self.substeps < tick:
                raise InputError(
                    f"observe() at t = {t} s comes after step() reached t = "
                    f"{tick * self.dt_control:g} s; observe each sample before the steps at "
                    f"its time ({self.substeps} step() calls per sample)"
                )
            ahead = k * self.substeps - tick
            if ahead > self.tau_samples * self.substeps:
                raise InputError(
                    f"observe() at t = {t} s is more than one interval (tau) ahead of the next "
                    f"control time {tick * self.dt_control:g} s; call step() for the control "
                    "instants in between first"
                )
        self._samples[k] = {int(i): p.copy() for i, p in zip(idv, pos, strict=True)}
        self._latest = k
        # keep what a history or an open interval's truth can still need
        keep_from = k - self.history - self.tau_samples - 1
        if self._start is not None:
            keep_from = min(keep_from, self._start)
        for old in [j for j in self._samples if j < keep_from]:
            del self._samples[old]

    def _window(self, lo: int, hi: int, ids: np.ndarray) -> np.ndarray:
        out = np.full((ids.size, hi - lo, 2), np.nan)
        for c, k in enumerate(range(lo, hi)):
            sample = self._samples.get(k)
            if sample:
                for r, i in enumerate(ids):
                    p = sample.get(int(i))
                    if p is not None:
                        out[r, c] = p
        return out

    # ------------------------------------------------------------------ control
    def step(self, ego_state: np.ndarray, t: float, goal: np.ndarray) -> np.ndarray:
        """The safe velocity (m/s) at control time ``t`` for ego state (x, y, vx, vy)."""
        x = np.asarray(ego_state, dtype=float)
        if x.shape != (self.state_dim,) or not np.isfinite(x).all():
            raise InputError(
                f"ego_state must be {self.state_dim} finite numbers (x, y, vx, vy"
                f"{', ...' if self.state_dim > 4 else ''}), got {x}"
            )
        g = np.asarray(goal, dtype=float)
        if g.shape != (2,) or not np.isfinite(g).all():
            raise InputError(f"goal must be 2 finite numbers (x, y) in m, got {g}")
        value = self._time(t, "step()")
        tick = self._next_tick()
        if tick is None:  # the first step: at a sample time
            k = round(value / self.dt)
            if abs(value / self.dt - k) > _GRID_TOL * max(1.0, abs(k) * 1e-9):
                raise InputError(
                    f"step() at t = {t} s: the first step is at a sample time (a multiple of "
                    f"dt = {self.dt} s)"
                )
        else:
            want = tick * self.dt_control
            if abs(value - want) > _GRID_TOL * max(self.dt_control, abs(want) * 1e-9):
                raise InputError(
                    f"step() at t = {t} s, expected t = {want:g} s: call step() exactly "
                    f"{self.substeps} times per sample, every dt / substeps = "
                    f"{self.dt_control:g} s"
                )
        at_sampling = tick is None or self._step >= self.tau_samples * self.substeps
        if at_sampling:
            k = round(value / self.dt) if tick is None else tick // self.substeps
            if k not in self._samples:
                raise InputError(
                    f"t = {t} s is a sampling time: observe() the sample at t = {k * self.dt} s "
                    "before step()"
                )
            if self._start is not None:
                self._close(k)
            self._open(k, x[:2])
        state = ControlState(x=x, t=value, step=self._step, goal=g)
        self._step += 1
        v: np.ndarray = self.stepper.decide(state)
        return v

    def _open(self, k: int, ego: np.ndarray) -> None:
        current = self._samples.get(k, {})
        ids = np.array(sorted(current), dtype=np.int64)
        if ids.size:
            xy = np.array([current[int(i)] for i in ids])
            near = np.hypot(*(xy - ego).T) <= self.sensing_radius
            ids = ids[near]
        self._sensed = ids
        self._start = k
        self._step = 0
        query = PredictionQuery(
            ids=ids,
            history=self._window(k - self.history + 1, k + 1, ids),
            dt=self.dt,
            horizon=self.tau_samples,
            t=k * self.dt,
            frame=k,
            scene="stepwise",
        )
        self.stepper.begin_interval(query)

    def _close(self, k: int) -> None:
        assert self._start is not None
        n = -(-self._step // self.substeps)
        samples = self._window(self._start, self._start + n + 1, self._sensed)
        self.stepper.end_interval(CBFTruth(samples, self.dt, self.substeps))

    def finish(self) -> LoopResult:
        """Close the open interval with the samples observed so far; return the result.

        Sample times of the interval that were never observed count as missing truth (NaN,
        reported as ``n_truth_missing`` in the interval's diagnostics): the loss is taken
        over the control instants the observed samples cover, and the interval is left
        unscored if they cover none.
        """
        if self._start is not None and self._step:
            n = -(-self._step // self.substeps)
            samples = self._window(self._start, self._start + n + 1, self._sensed)
            self.stepper.end_interval(CBFTruth(samples, self.dt, self.substeps))
            self._start = None
        return self.stepper.result()

    # ------------------------------------------------------------------ state
    @property
    def state_dim(self) -> int:
        """Numbers in the ego state :meth:`step` takes: (x, y, vx, vy)."""
        return 4

    @property
    def lam(self) -> float:
        """The lambda decisions are taken with now (1/s)."""
        return self.stepper.lam

    def result(self) -> LoopResult:
        """Intervals scored so far, lambda and the guarantee monitor."""
        return self.stepper.result()

    def stats(self) -> dict[str, float]:
        """Counters of the controller and its safety filter."""
        return self.controller.stats()
