"""Adaptive conformal prediction regions in the sampling MPC (the ``acp_mpc`` family).

ACP-MPC (Dixit, Lindemann, Wei, Cleaveland, Pappas & Burdick, "Adaptive conformal
prediction for motion planning among dynamic agents", L4DC 2023): the robot keeps, for
every plan step h, the errors ``|y_j(t + h dt) - y^_j(t + h dt | t)|`` its predictor made
h steps ahead, and plans around every agent's predicted position inflated by a conformal
quantile ``C^h`` of those errors, at a level tracked online by adaptive conformal inference.

Here the ACI step runs through the generic loop with the registered ``aci`` rule: lambda is
the regions' miscoverage level alpha (``epsilon = alpha``), the loss is the observed
miscoverage (:class:`PlanMiscoverageLoss`), and the MPC's safe distance at plan step h is
``d_c + margin + min(C^h(lambda), max_inflation)`` (:meth:`ACPMPC.safe_radius`; a larger
lambda = smaller regions = less conservative, the toolkit's convention).

Scoring. At every sampling time the family stores its predictions at the plan steps
(``t + h dt_plan``, h = 1..H). At each later sampling time it scores every stored
prediction whose target time has passed and is still within the sensor's history: the
true position is read from the history (linear between samples), and the error joins the
step's scores (the last ``window`` kept). Agents that left the sensor, and targets older
than the history, are counted (``n_unscored``), not guessed. The errors scored at the start
of interval k are the record of that interval; its loss is the fraction of them that fell
outside the region of their step at lambda_k, computed from the scores known *before*
they were added (out of sample, as conformal prediction requires).

Where this differs from Dixit et al.:

1. **One alpha for all plan steps** (their ACI runs one alpha per step): the loop tunes one
   scalar; the per-step error distributions still give step-dependent radii C^h. The
   guarantee is on the miscoverage of all scored (agent, step) pairs together.
2. **Per-agent errors** (they score the largest error over agents, one region covering all
   agents jointly): each (agent, step) pair is one score.
3. **Quantiles of the last ``window`` errors** (they draw a bootstrap sample of 12 with
   replacement and fill missing scores with a fixed bound): deterministic and without a
   prior. Before enough errors are known the region is unbounded and capped at
   ``max_inflation`` (the published code starts from ``1.5 dt h``).
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...core.base import Loss
from ...core.losses import check_lambda
from ...predictors.base import PredictionQuery, Predictor
from ..cbf.acp import region_radii
from ..cbf.roles import Dynamics, ReferenceController
from .controller import MPCIntervalRecord, SamplingMPC
from .settings import Costs, Limits, Sampling

__all__ = ["ACPMPC", "ACPMPCIntervalRecord", "PlanMiscoverageLoss"]


@dataclass
class ACPMPCIntervalRecord(MPCIntervalRecord):
    """The MPC record plus the prediction errors scored at the interval's start.

    Attributes
    ----------
    scored_step : ndarray of shape (P,)
        Plan step (1..H) of each error scored at the interval's start.
    scored_error : ndarray of shape (P,)
        The errors (m).
    sorted_scores : tuple of H ndarrays
        Each step's past errors (sorted) before these were added.
    inflation : ndarray of shape (H,)
        Inflation of the safe distance at each plan step (m), at the interval's first
        lambda.
    """

    scored_step: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    scored_error: np.ndarray = field(default_factory=lambda: np.zeros(0))
    sorted_scores: tuple[np.ndarray, ...] = ()
    inflation: np.ndarray = field(default_factory=lambda: np.zeros(0))


class ACPMPC(
    SamplingMPC,
    default_loss="plan_miscoverage",
    lambda_unit="level",
    # with the fixed-eta rule (ACI's update when epsilon = alpha): alpha 0.1, step 0.02
    default_rule_params={"epsilon": 0.1, "eta": 0.02},
):
    """Sampling MPC avoiding adaptive conformal prediction regions (Dixit et al. 2023).

    lambda is the regions' miscoverage level (see the module docstring); run it with the
    ``aci`` rule (``epsilon = alpha``) and :class:`PlanMiscoverageLoss`.

    Parameters
    ----------
    predictor, dynamics, reference, sampling, d_c, margin, limits, costs
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    fallback, continuous, substeps, random_state
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    window : int
        Errors kept per plan step (the most recent ones) for the quantiles.
    max_inflation : float
        Largest inflation of the safe distance (m, >= 0), for unbounded regions (lambda
        <= 0, or too few errors for the level).
    edge : {"escape", "paper"}
        The edge rule of :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    **grouped
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`
        (``<group>__<field>``,
        or a former flat keyword with a ``DeprecationWarning``).
    """

    @classmethod
    def lambda_ceiling(cls, margin: float) -> float:
        """``inf``: lambda is a level here, the safe distance is never below ``d_c +
        margin`` whatever it is.

        Parameters
        ----------
        margin : float
            The family's fixed extra safe distance (m).
        """
        return math.inf

    def __init__(
        self,
        predictor: Predictor,
        dynamics: Dynamics,
        reference: ReferenceController | None = None,
        sampling: Sampling | None = None,
        d_c: float = 1.0,
        margin: float = 0.0,
        limits: Limits | None = None,
        costs: Costs | None = None,
        fallback: str = "brake",
        continuous: bool = True,
        substeps: int = 4,
        random_state: int = 0,
        window: int = 2000,
        max_inflation: float = 2.0,
        edge: str = "escape",
        **grouped: Any,
    ) -> None:
        self.window = window
        self.max_inflation = max_inflation
        super().__init__(
            predictor,
            dynamics,
            reference,
            sampling,
            d_c,
            margin,
            limits,
            costs,
            fallback,
            continuous,
            substeps,
            random_state,
            edge,
            **grouped,
        )

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        base = super()._unit_test_params()
        return [{**base[0], "window": 50, "max_inflation": 1.0}, base[1]]

    def reset(self) -> None:
        super().reset()
        if isinstance(self.window, bool) or int(self.window) != self.window or self.window < 1:
            raise ValueError(f"window must be a positive integer, got {self.window!r}")
        if not (math.isfinite(self.max_inflation) and self.max_inflation >= 0):
            raise ValueError(
                f"max_inflation must be a finite distance >= 0, got {self.max_inflation!r}"
            )
        h = int(self.sampling.horizon)
        self.scores_: list[deque[float]] = [deque(maxlen=int(self.window)) for _ in range(h)]
        self.n_scored_ = 0
        self.n_unscored_ = 0
        # stored predictions: (time made, ids, (M, H, 2) positions at the plan steps,
        # first step not yet scored)
        self._pending: list[tuple[float, np.ndarray, np.ndarray, int]] = []
        self._sorted: tuple[np.ndarray, ...] = tuple(np.zeros(0) for _ in range(h))
        self._scored = (np.zeros(0, dtype=np.int64), np.zeros(0))
        self._snapshot: tuple[np.ndarray, ...] = self._sorted
        self._infl_lam: float | None = None
        self._infl = np.zeros(h)
        self._first_infl = np.zeros(h)
        self._first_set = False

    def stats(self) -> dict[str, float]:
        return {**super().stats(), "n_scored": self.n_scored_, "n_unscored": self.n_unscored_}

    # ------------------------------------------------------------------ sampling time
    def _score(self, observation: PredictionQuery) -> tuple[np.ndarray, np.ndarray]:
        """Errors of the stored predictions whose targets have passed: (steps, errors).

        Vectorised over the agents of a stored prediction (the same arithmetic, element by
        element, as one agent at a time: the interpolation and ``numpy.hypot``), in the
        order (prediction, step, agent)."""
        steps: list[np.ndarray] = []
        errors: list[np.ndarray] = []
        hist = observation.history
        span = (hist.shape[1] - 1) * observation.dt
        row = {int(i): r for r, i in enumerate(np.asarray(observation.ids).tolist())}
        keep = []
        n_scored = 0
        for t_made, ids, pred, first in self._pending:
            h = first
            rows: np.ndarray | None = None
            while h <= pred.shape[1]:
                target = t_made + h * self.sampling.dt_plan
                back = observation.t - target
                if back < -1e-9:
                    break
                if back > span + 1e-9:  # older than the history: cannot be scored
                    self.n_unscored_ += len(ids)
                    h += 1
                    continue
                if rows is None:  # the agents' rows in this history (-1: left the sensor)
                    rows = np.array([row.get(a, -1) for a in ids.tolist()], dtype=np.int64)
                    seen = np.flatnonzero(rows >= 0)
                    rs = rows[seen]
                f = back / observation.dt
                k0 = math.floor(f + 1e-9)
                w = max(f - k0, 0.0)
                c0 = hist.shape[1] - 1 - k0
                c1 = max(c0 - 1, 0)
                p = hist[rs, c0] if w == 0.0 else hist[rs, c0] + w * (hist[rs, c1] - hist[rs, c0])
                ok = np.isfinite(p).all(axis=1)
                self.n_unscored_ += len(ids) - int(ok.sum())
                d = p[ok] - pred[seen[ok], h - 1]
                steps.append(np.full(d.shape[0], h, dtype=np.int64))
                errors.append(np.hypot(d[:, 0], d[:, 1]))
                n_scored += d.shape[0]
                h += 1
            if h <= pred.shape[1]:
                keep.append((t_made, ids, pred, h))
        self._pending = keep
        self.n_scored_ += n_scored
        if not steps:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        return np.concatenate(steps), np.concatenate(errors).astype(float)

    def _add_scores(self, steps: np.ndarray, errors: np.ndarray) -> None:
        """Append the errors to their steps' windows and keep each window's sorted copy
        (``_sorted``) up to date: the errors leaving the window removed from it and the new
        ones inserted (the same array as sorting the window afresh, without re-sorting
        2,000 errors per step at every sampling time). A window whose length is no longer
        that of its sorted copy (filled from outside, as ``benchmarks/bench_mpc.py`` seeds
        it) or a non-finite error is sorted afresh."""
        sorted_ = list(self._sorted)
        for h in range(len(self.scores_)):
            new = errors[steps == h + 1]
            if not new.size:
                continue
            win = self.scores_[h]
            old = sorted_[h]
            cap = int(self.window)
            gone = max(len(win) + new.size - cap, 0)
            fresh = (
                old.size != len(win)
                or gone > len(win)
                or not np.isfinite(new).all()
                or bool(old.size and np.isnan(old[-1]))
            )
            if not fresh and gone:
                out = np.sort(np.fromiter(itertools.islice(win, gone), float, count=gone))
                at = np.searchsorted(old, out, "left")
                at += np.arange(gone) - np.searchsorted(out, out, "left")  # repeated values
                old = np.delete(old, at)
            win.extend(new.tolist())
            if fresh:
                sorted_[h] = np.sort(np.fromiter(win, float))
            else:
                add = np.sort(new)
                sorted_[h] = np.insert(old, np.searchsorted(old, add, "left"), add)
        self._sorted = tuple(sorted_)

    def begin_interval(self, observation: PredictionQuery) -> None:
        steps, errors = self._score(observation)
        self._snapshot = self._sorted
        self._scored = (steps, errors)
        self._add_scores(steps, errors)
        self._infl_lam = None
        self._first_infl = np.zeros(int(self.sampling.horizon))
        self._first_set = False
        super().begin_interval(observation)
        if observation.n_agents:
            times = self.sampling.dt_plan * np.arange(1, int(self.sampling.horizon) + 1)
            self._pending.append(
                (
                    float(observation.t),
                    np.asarray(observation.ids).copy(),
                    self.predicted_at(times),
                    1,
                )
            )

    # ------------------------------------------------------------------ the knob
    def inflation(self, lam: float) -> np.ndarray:
        """Inflation at each plan step (m): ``min(C^h(lambda), max_inflation)``, 0 for an
        empty region."""
        if self._infl_lam != lam:
            radii = region_radii(self._sorted, lam)
            self._infl = np.clip(np.where(np.isnan(radii), 0.0, radii), 0.0, self.max_inflation)
            self._infl_lam = lam
        return self._infl

    def safe_radius(self, lam: float) -> np.ndarray:
        """``d_c + margin + min(C^h(lambda), max_inflation)`` at each plan step (m)."""
        infl = self.inflation(lam)
        if not self._first_set:
            self._first_infl, self._first_set = infl.copy(), True
        out: np.ndarray = np.maximum(float(self.d_c) + float(self.margin) + infl, 0.0)
        return out

    def interval_record(self) -> ACPMPCIntervalRecord:
        base = super().interval_record()
        fields = {k: getattr(base, k) for k in base.__dataclass_fields__}
        return ACPMPCIntervalRecord(
            **fields,
            scored_step=self._scored[0].copy(),
            scored_error=self._scored[1].copy(),
            sorted_scores=self._snapshot,
            inflation=self._first_infl.copy(),
        )


class PlanMiscoverageLoss(Loss[ACPMPCIntervalRecord, Any]):
    """Miscoverage of the acp_mpc regions: the fraction of the prediction errors scored at
    the interval's start that fell outside their plan step's region.

    l_k(lambda) = mean over scored (agent, step h) pairs of 1{ error > C^h(lambda) }, with
    C^h(lambda) the conformal quantile at level 1 - lambda of the step's errors known
    before (infinite for lambda <= 0, empty for lambda >= 1). In [0, 1], non-decreasing in
    lambda; target: the ``aci`` rule's alpha. No scored pair: no loss. The truth argument is
    not used (the errors were scored from the sensor's histories).
    """

    bounds = (0.0, 1.0)

    def __init__(self) -> None:
        pass

    @classmethod
    def _unit_test_inputs(cls) -> list[tuple[ACPMPCIntervalRecord, Any]]:
        """Errors of three steps against 40 past errors each; none scored; no past errors."""
        rng = np.random.default_rng(0)
        scores = tuple(np.sort(np.abs(rng.normal(0.0, 0.3 * (h + 1), 40))) for h in range(3))
        steps = np.array([1, 1, 2, 3, 3, 3])
        errors = np.abs(rng.normal(0.0, 0.5, steps.size))

        def record(st: np.ndarray, er: np.ndarray, sc: tuple[np.ndarray, ...]) -> Any:
            return ACPMPCIntervalRecord(
                ids=np.arange(2),
                x_ego=np.zeros((1, 2)),
                v_ego=np.zeros((1, 2)),
                x_pred=np.zeros((1, 2, 2)),
                v_pred=np.zeros((1, 2, 2)),
                lam_applied=np.zeros(1),
                status=["optimal"],
                scored_step=st,
                scored_error=er,
                sorted_scores=sc,
                inflation=np.zeros(3),
            )

        empty = tuple(np.zeros(0) for _ in range(3))
        none = (np.zeros(0, dtype=np.int64), np.zeros(0))
        return [
            (record(steps, errors, scores), None),
            (record(*none, scores), None),
            (record(steps, errors, empty), None),
        ]

    def _misses(self, record: ACPMPCIntervalRecord, lam: float) -> np.ndarray:
        radii = region_radii(tuple(record.sorted_scores), lam)
        r = radii[np.asarray(record.scored_step, dtype=np.int64) - 1]
        out: np.ndarray = np.asarray(record.scored_error, dtype=float) > r
        return out

    def __call__(self, record: ACPMPCIntervalRecord, truth: Any, lam: float) -> float | None:
        lam = check_lambda(lam)
        if record.scored_error.size == 0:
            return None
        return float(self._misses(record, lam).mean())

    def diagnostics(self, record: ACPMPCIntervalRecord, truth: Any, lam: float) -> dict[str, float]:
        lam = check_lambda(lam)
        if record.scored_error.size == 0:
            return {}
        return {
            "n_pairs": int(record.scored_error.size),
            "n_missed": int(self._misses(record, lam).sum()),
            "max_error": float(record.scored_error.max()),
            "mean_inflation": float(np.mean(record.inflation)) if record.inflation.size else 0.0,
        }
