"""Adaptive conformal prediction regions in the CBF safety filter (the ``acp`` family).

In the style of Dixit, Lindemann, Wei, Cleaveland, Pappas & Burdick, "Adaptive conformal
prediction for motion planning among dynamic agents" (L4DC 2023): the robot keeps, for
every horizon step h of its predictor, the errors ``||y_j(t + h) - y^_j(t + h | t)||``
its past predictions made, and avoids every agent's predicted position inflated by a
conformal quantile ``C^h`` of those errors. The quantile's level is tracked online by
adaptive conformal inference (ACI, Gibbs & Candès 2021) so that the regions cover the
true positions a target fraction ``1 - alpha`` of the time, whatever the data do.

Here the ACI step runs through the SAME generic loop as every other family
(:class:`~conformal_control.core.loop.ConformalLoop` with the registered ``aci`` rule): the
conformal variable lambda IS the miscoverage level alpha_t of the regions, the loss is
the observed miscoverage (:class:`ACPMiscoverageLoss`) and the target epsilon is alpha.
Smaller lambda = larger quantile = larger regions = more conservative, as the toolkit's
sign convention requires.

The family (:class:`ACPController`) is the conformal CBF controller's machinery
(predictor, barrier, safety filter, reference; a subclass of
:class:`~conformal_control.families.cbf.controller.ConformalCBFController`) with its knob moved:

* at a control instant between prediction samples h - 1 and h (h = 1..H), every agent's
  collision distance in the barrier is ``d_c + C^h(lambda)`` (the barrier is evaluated
  with its ``d_c`` parameter raised; the barrier must have one, as the APF barrier does);
* the slack of the conformal constraint is 0: lambda does not enter the rows as a slack
  (``dh/dx . v + dh/dx_j . v_j + a h_inflated >= 0``). The safety filter's fallback for
  an infeasible QP is unchanged (it may raise the slack; its record says so);
* ``C^h(lambda)`` is the conformal quantile at level ``1 - lambda`` of the last
  ``window`` errors of step h (:func:`conformal_control.core.losses.conformal_radius`:
  infinite for lambda <= 0 or too few errors, empty for lambda >= 1); the barrier uses
  ``min(C^h, max_inflation)`` (a finite region the QP can work with; capped instants are
  counted in ``n_capped_``) and 0 for an empty region;
* errors are scored at the next sampling time from the sensor's histories (the robot's
  own observation: agents that left the sensor before being scored are counted in
  ``n_unscored_``, not guessed).

Where this differs from Dixit et al.:

1. **One alpha for all horizon steps.** They run one ACI per horizon step tau (its own
   alpha_t^tau, updated with a lag of tau steps); here one lambda (the generic loop's
   scalar) sets the level of every step, while the per-step error distributions still
   give step-dependent radii C^h. Reason: the loop tunes one scalar over a family
   ordered by conservativeness, which is what the benchmark compares across families;
   and because our prediction horizon equals the update interval, every step of an
   interval is revealed at the same sampling time, so there is no lag to keep track of.
   The guarantee is therefore on the per-interval miscoverage fraction averaged over
   intervals, not on each step separately.
2. **Per-agent errors, pooled over agents.** They score the largest error over agents
   (one region covering all agents jointly); here every (agent, step) pair is one
   score and the loss is the fraction of (agent, step) pairs of the interval whose true
   position fell outside its region - the per-agent (marginal) reading of the region.
3. **A CBF safety filter instead of an MPC.** The region enters the barrier as an
   inflated collision distance rather than as an MPC distance constraint.

Guarantee (ACI, with the loss in [0, 1]): the loss is 0 for lambda <= 0 (infinite
regions) and 1 for lambda >= 1 (empty regions), so lambda stays in [-gamma, 1 + gamma]
and, for every data sequence, ``|mean loss - alpha| <= (max(lambda_1, 1 - lambda_1) +
gamma) / (gamma K)`` after K scored intervals (the ``aci`` rule's ``long_run_bound``).
This is about the regions C^h(lambda) themselves; the cap ``max_inflation`` only limits
what the barrier is given.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ...core.base import Loss
from ...core.losses import check_lambda, conformal_radius
from ...predictors.base import Forecast, PredictionQuery, Predictor
from .barriers import APFForm
from .constraint import ConformalConstraint
from .controller import CBFIntervalForm, CBFIntervalRecord, ConformalCBFController, ControlState
from .loss import CBFTruth
from .roles import EscapeRows, ReferenceController, SafetyFilter

__all__ = [
    "ACPController",
    "ACPIntervalForm",
    "ACPIntervalRecord",
    "ACPMiscoverageLoss",
    "region_radii",
]


def region_radii(sorted_scores: tuple[np.ndarray, ...], lam: float) -> np.ndarray:
    """Radii ``C^h(lambda)`` of the regions of steps h = 1..H (``inf``: everything,
    ``-inf``: empty), from each step's sorted past errors."""
    return np.array([conformal_radius(s, lam, "level") for s in sorted_scores], dtype=float)


@dataclass
class ACPIntervalRecord(CBFIntervalRecord):
    """The CBF record of an interval plus what its prediction regions were made of.

    Attributes
    ----------
    pred_samples : ndarray of shape (N, H, 2)
        The predictor's positions at the H samples after the sampling time (m; NaN
        where the predictor gave none).
    sorted_scores : tuple of H ndarrays
        Past errors of each horizon step (sorted), as they were when the interval began:
        the regions of the interval are their quantiles.
    inflation : ndarray of shape (H,)
        Inflation the barrier was given at each step (m), at the interval's lambda.
    """

    pred_samples: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 2)))
    sorted_scores: tuple[np.ndarray, ...] = ()
    inflation: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class ACPIntervalForm(CBFIntervalForm):
    """What the compiled engine reads of the acp family after its ``begin_interval`` (and
    after :meth:`ACPController.region_barriers` at the interval's lambda): the
    predictions, and what its regions are made of.

    Attributes
    ----------
    xp, vp : ndarray
        As :class:`~conformal_control.families.cbf.controller.CBFIntervalForm`.
    pred_samples : ndarray
        The predictor's positions over the horizon, ``(agents, horizon, 2)``.
    sorted_scores : tuple of ndarray
        Past errors per horizon step, sorted.
    inflation : ndarray
        The regions' radii at the interval's lambda, per horizon step (m).
    capped : ndarray
        Whether each horizon step's region was capped at ``max_inflation`` (bool).
    """

    kernel = "acp"
    pred_samples: np.ndarray
    sorted_scores: tuple[np.ndarray, ...]
    inflation: np.ndarray
    capped: np.ndarray


class ACPController(ConformalCBFController, compiled="acp"):
    """Adaptive conformal prediction regions (Dixit et al. 2023) inflating a CBF barrier.

    lambda is the miscoverage level of the regions (see the module docstring); run it
    with the ``aci`` rule (``epsilon = alpha``) and :class:`ACPMiscoverageLoss`.

    Parameters
    ----------
    predictor, constraint, safety_filter, reference, substeps
        As for :class:`~conformal_control.families.cbf.controller.ConformalCBFController`. The
        constraint's barrier must have a ``d_c`` parameter (collision distance, m).
    window : int
        Errors kept per horizon step (the most recent ones) for the quantiles.
    max_inflation : float
        Largest inflation handed to the barrier (m, >= 0), for infinite regions (lambda
        <= 0, or fewer errors than the level needs at the start of an episode).
    """

    def __init__(
        self,
        predictor: Predictor,
        constraint: ConformalConstraint,
        safety_filter: SafetyFilter,
        reference: ReferenceController,
        substeps: int = 4,
        window: int = 2000,
        max_inflation: float = 0.5,
    ) -> None:
        super().__init__(predictor, constraint, safety_filter, reference, substeps)
        self.window = window
        self.max_inflation = max_inflation

    # ------------------------------------------------------------------ episode
    def reset(self) -> None:
        super().reset()
        barrier_params = self.constraint.barrier.get_params()
        if "d_c" not in barrier_params:
            raise ValueError(
                f"the acp family inflates the barrier's collision distance d_c; "
                f"{type(self.constraint.barrier).__name__} has no d_c parameter"
            )
        self._d_c = float(barrier_params["d_c"])
        if int(self.window) != self.window or self.window < 1:
            raise ValueError(f"window must be a positive integer, got {self.window!r}")
        if not (math.isfinite(self.max_inflation) and self.max_inflation >= 0):
            raise ValueError(
                f"max_inflation must be a finite number >= 0, got {self.max_inflation!r}"
            )
        self.scores_: list[deque[float]] = []
        self.n_scored_ = 0
        self.n_unscored_ = 0
        self.n_capped_ = 0
        self._prev: tuple[np.ndarray, np.ndarray, float] | None = None
        self._pred = np.zeros((0, 0, 2))
        self._sorted: tuple[np.ndarray, ...] = ()
        self._lam: float | None = None
        self._infl = np.zeros(0)
        self._capped = np.zeros(0, dtype=bool)
        self._constraints: dict[float, ConformalConstraint] = {}

    def stats(self) -> dict[str, float]:
        return {
            **super().stats(),
            "n_scored": self.n_scored_,
            "n_unscored": self.n_unscored_,
            "n_capped": self.n_capped_,
        }

    # ------------------------------------------------------------------ sampling time
    def _predict(self, observation: PredictionQuery) -> Forecast:
        forecast = super()._predict(observation)
        pos = np.asarray(forecast.positions, dtype=float)
        if pos.ndim == 3 and pos.shape[1] >= observation.horizon:
            self._pred = pos[:, : observation.horizon].copy()
        return forecast

    def _score_previous(self, observation: PredictionQuery) -> None:
        """Errors of the previous interval's predictions, read from the sensor's histories."""
        if self._prev is None:
            return
        ids, pred, t_prev = self._prev
        self._prev = None
        if ids.size == 0 or pred.size == 0:
            return
        horizon = pred.shape[1]
        elapsed = min(round((observation.t - t_prev) / observation.dt), horizon)
        if elapsed <= 0:
            return
        hist = observation.history
        cur = {int(i): r for r, i in enumerate(np.asarray(observation.ids))}
        rows = np.array([cur.get(int(i), -1) for i in ids])
        kept = rows >= 0
        self.n_unscored_ += int((~kept).sum()) * elapsed
        if not kept.any():
            return
        # truth of step h (1..elapsed) is the history sample elapsed - h before the last
        cols = hist.shape[1] - 1 - (elapsed - np.arange(1, elapsed + 1))
        ok_col = cols >= 0
        truth = np.full((int(kept.sum()), elapsed, 2), np.nan)
        truth[:, ok_col] = hist[rows[kept]][:, cols[ok_col]]
        diff = truth - pred[kept, :elapsed]
        err = np.hypot(diff[..., 0], diff[..., 1])
        finite = np.isfinite(err)
        self.n_unscored_ += int((~finite).sum())
        self.n_scored_ += int(finite.sum())
        for h in range(elapsed):
            self.scores_[h].extend(err[finite[:, h], h].tolist())

    def begin_interval(self, observation: PredictionQuery) -> None:
        self._score_previous(observation)
        self._pred = np.zeros((0, observation.horizon, 2))
        super().begin_interval(observation)
        horizon = observation.horizon
        while len(self.scores_) < horizon:
            self.scores_.append(deque(maxlen=int(self.window)))
        self._sorted = tuple(np.sort(np.fromiter(self.scores_[h], float)) for h in range(horizon))
        # the predicted agents (robots handled reciprocally are not predicted)
        self._prev = (np.asarray(self._ids), self._pred, observation.t)
        self._lam = None
        self._infl = np.zeros(horizon)
        self._capped = np.zeros(horizon, dtype=bool)
        self._constraints = {}

    # ------------------------------------------------------------------ control instant
    def _fused_apf(self) -> bool:
        """The compiled step (with the APF parts it computes, see the base class): its
        barrier's ``d_c`` is raised by the step's inflation before each decision
        (:meth:`decide`), and lambda is not a slack of its rows."""
        me = type(self)
        self._apf_c: float | None = None  # the inflation the compiled step is set up with
        return (
            me.constraint_rows is ACPController.constraint_rows
            and me.slack is ACPController.slack
            and self._apf_parts()
        )

    def decide(self, state: ControlState, lam: float) -> np.ndarray:
        if not self._fast:  # the generic path: constraint_rows and slack below
            return super().decide(state, lam)
        # the compiled step on the rows constraint_rows gives: the inflated barrier, slack 0
        infl = self._inflation(lam)
        h = min(state.step // int(self.substeps), infl.size - 1)
        self.n_capped_ += int(self._capped[h])
        c = float(infl[h])
        if c != self._apf_c:
            form = self._inflated(c).barrier.compiled_state()
            assert isinstance(form, APFForm)  # an APF barrier (_fused_apf)
            self.safety_filter.configure_apf(  # type: ignore[attr-defined]
                (form.K_rep, form.rho0, form.d_c, form.delta, form.surface),
                float(self.constraint.a),
                self.constraint.edge_settings(),  # the edge rule on the true d_c
            )
            self._apf_c = c
        return super().decide(state, self.slack(lam))

    def compiled_state(self) -> ACPIntervalForm:
        """The interval's predictions and regions (empty before the first interval)."""
        base = super().compiled_state()
        get = self.__dict__.get
        return ACPIntervalForm(
            base.xp,
            base.vp,
            get("_pred", np.zeros((0, 0, 2))),
            get("_sorted", ()),
            get("_infl", np.zeros(0)),
            get("_capped", np.zeros(0, dtype=bool)),
        )

    def region_barriers(self, lam: float) -> list[APFForm]:
        """The barrier of each horizon step of the interval at level ``lam``, as the
        compiled step reads it (``d_c`` raised by the step's region, as :meth:`decide`
        sets the compiled step up); the regions are then those of
        :meth:`compiled_state`.

        Parameters
        ----------
        lam : float
            The interval's level.
        """
        forms = []
        for c in self._inflation(lam):
            form = self._inflated(float(c)).barrier.compiled_state()
            assert isinstance(form, APFForm)  # the engine runs the APF barrier only
            forms.append(form)
        return forms

    def _inflation(self, lam: float) -> np.ndarray:
        if self._lam != lam:
            radii = region_radii(self._sorted, lam)
            self._infl = np.clip(np.where(np.isnan(radii), 0.0, radii), 0.0, self.max_inflation)
            self._capped = radii > self.max_inflation
            self._lam = lam
        return self._infl

    def _inflated(self, c: float) -> ConformalConstraint:
        con = self._constraints.get(c)
        if con is None:
            barrier = copy.copy(self.constraint.barrier)
            barrier.d_c = self._d_c + c  # type: ignore[attr-defined]
            base = self.constraint
            con = ConformalConstraint(
                barrier,
                base.a,
                edge=base.edge,
                escape_gain=base.escape_gain,
                escape_margin=base.escape_margin,
            )  # the edge rule within the inflated d_c (the rows are flat there)
            self._constraints[c] = con
        return con

    def constraint_rows(self, state: ControlState, lam: float) -> tuple[np.ndarray, np.ndarray]:
        if not self._ids.size:
            return np.zeros((0, 2)), np.zeros(0)
        infl = self._inflation(lam)
        h = min(state.step // int(self.substeps), infl.size - 1)
        self.n_capped_ += int(self._capped[h])
        con = self._inflated(float(infl[h]))
        return con.rows(state.x[:2], self._xp[state.step], self._vp[state.step])

    def escape_rows(self, state: ControlState) -> EscapeRows | None:
        """The edge rule on the inflated constraint of this instant (its rows are flat
        within the inflated ``d_c``), as the compiled step applies it; the inflation is
        the one :meth:`constraint_rows` computed for this instant."""
        if not self._ids.size:
            return None
        infl = self._infl
        h = min(state.step // int(self.substeps), infl.size - 1)
        con = self._inflated(float(infl[h]))
        s = state.step
        return con.escape(state.x[:2], self._xp[s], self._vp[s])

    def slack(self, lam: float) -> float:
        """lambda is the regions' level, not a slack: the rows get 0."""
        return 0.0

    def interval_record(self) -> ACPIntervalRecord:
        base = super().interval_record()
        fields = {k: getattr(base, k) for k in base.__dataclass_fields__}
        return ACPIntervalRecord(
            **fields,
            pred_samples=self._pred.copy(),
            sorted_scores=self._sorted,
            inflation=self._infl.copy(),
        )


class ACPMiscoverageLoss(Loss[ACPIntervalRecord, CBFTruth], compiled="acp_miscoverage"):
    """Miscoverage of the acp regions: the fraction of (agent, step) pairs of the interval
    whose true position fell outside its region.

    l_k(lambda) = mean over sensed agents j and horizon steps h (with a true position) of
    1{ ||y_j(t_k + h) - y^_j(t_k + h)|| > C^h(lambda) }, with C^h(lambda) the conformal
    quantile at level 1 - lambda of the step's past errors (infinite for lambda <= 0,
    empty for lambda >= 1), as recorded by :class:`ACPController`. In [0, 1],
    non-decreasing in lambda; target: the ``aci`` rule's alpha. An interval without any
    (agent, step) pair with a true position has no loss.
    """

    bounds = (0.0, 1.0)

    def __init__(self) -> None:
        pass

    @classmethod
    def _unit_test_inputs(cls) -> list[tuple[ACPIntervalRecord, CBFTruth]]:
        """A noisy prediction with 40 past errors per step, the same with an agent whose
        truth goes missing, no past errors yet, nothing sensed."""
        rng = np.random.default_rng(0)
        dt, substeps, horizon, n = 0.4, 4, 3, 4
        s = horizon * substeps
        true = rng.uniform(-3, 3, (n, 1, 2)) + np.cumsum(
            np.concatenate([np.zeros((n, 1, 2)), rng.normal(0.5, 0.2, (n, horizon, 2))], 1), 1
        )
        pred = true[:, 1:] + rng.normal(0.0, 0.3, (n, horizon, 2))
        scores = tuple(np.sort(np.abs(rng.normal(0.0, 0.3 * (h + 1), 40))) for h in range(horizon))

        def record(k: int, sc: tuple[np.ndarray, ...]) -> ACPIntervalRecord:
            return ACPIntervalRecord(
                ids=np.arange(k),
                x_ego=np.zeros((s, 2)),
                v_ego=np.zeros((s, 2)),
                x_pred=np.zeros((s, k, 2)),
                v_pred=np.zeros((s, k, 2)),
                lam_applied=np.zeros(s),
                status=["optimal"] * s,
                pred_samples=pred[:k].copy(),
                sorted_scores=sc,
                inflation=np.zeros(horizon),
            )

        missing = true.copy()
        missing[1, 2:] = np.nan
        empty = tuple(np.zeros(0) for _ in range(horizon))
        return [
            (record(n, scores), CBFTruth(true, dt, substeps)),
            (record(n, scores), CBFTruth(missing, dt, substeps)),
            (record(n, empty), CBFTruth(true, dt, substeps)),
            (record(0, scores), CBFTruth(np.zeros((0, horizon + 1, 2)), dt, substeps)),
        ]

    def errors(self, record: ACPIntervalRecord, truth: CBFTruth) -> np.ndarray:
        """Prediction errors (m), shape (N, steps); NaN where the truth is missing."""
        pred = np.asarray(record.pred_samples, dtype=float)
        samples = np.asarray(truth.samples, dtype=float)
        n = min(pred.shape[0], samples.shape[0])
        steps = min(pred.shape[1] if pred.ndim == 3 else 0, samples.shape[1] - 1)
        if n == 0 or steps <= 0:
            return np.zeros((n, 0))
        diff = samples[:n, 1 : steps + 1] - pred[:n, :steps]
        return np.asarray(np.hypot(diff[..., 0], diff[..., 1]), dtype=float)

    def _misses(
        self, record: ACPIntervalRecord, truth: CBFTruth, lam: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        err = self.errors(record, truth)
        radii = region_radii(tuple(record.sorted_scores[: err.shape[1]]), lam)
        valid = np.isfinite(err)
        with np.errstate(invalid="ignore"):
            miss = err > radii[None, :]
        return miss, valid, radii

    def __call__(self, record: ACPIntervalRecord, truth: CBFTruth, lam: float) -> float | None:
        lam = check_lambda(lam)
        miss, valid, _ = self._misses(record, truth, lam)
        if not valid.any():
            return None
        return float(miss[valid].mean())

    def diagnostics(
        self, record: ACPIntervalRecord, truth: CBFTruth, lam: float
    ) -> dict[str, float]:
        lam = check_lambda(lam)
        miss, valid, radii = self._misses(record, truth, lam)
        if not valid.any():
            return {}
        err = self.errors(record, truth)
        finite = radii[np.isfinite(radii)]
        out = {
            "n_pairs": int(valid.sum()),
            "n_truth_missing": int((~valid).sum()),
            "n_missed": int(miss[valid].sum()),
            "max_error": float(np.nanmax(err)),
            "mean_inflation": float(np.mean(record.inflation)) if record.inflation.size else 0.0,
        }
        if finite.size:
            out["mean_finite_radius"] = float(finite.mean())
        return out
