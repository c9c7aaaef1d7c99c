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

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...core.base import Loss
from ...core.jit import kernel
from ...core.losses import check_lambda
from ...predictors.base import PredictionQuery, Predictor
from ..cbf.pyhypot import c_hypot
from ..cbf.roles import Dynamics, ReferenceController
from .controller import MPCIntervalRecord, SamplingMPC
from .settings import Costs, Limits, Sampling

__all__ = ["ACPMPC", "ACPMPCIntervalRecord", "PlanMiscoverageLoss"]

jit = kernel(cache=True, nogil=True)


@jit
def _score_kernel(
    t_made: np.ndarray,
    first: np.ndarray,
    off: np.ndarray,
    ids: np.ndarray,
    pred: np.ndarray,
    obs_ids: np.ndarray,
    obs_rows: np.ndarray,
    hist: np.ndarray,
    obs_t: float,
    obs_dt: float,
    span: float,
    dt_plan: float,
    steps_out: np.ndarray,
    err_out: np.ndarray,
    new_first: np.ndarray,
) -> tuple[int, int]:
    """The scoring of :meth:`ACPMPC._score_numpy`, compiled: the stored predictions ``p``
    (made at ``t_made[p]``, agents ``ids[off[p]:off[p + 1]]`` with their positions at the
    plan steps ``pred[off[p]:off[p + 1]]``, first step not yet scored ``first[p]``) scored
    against the history, errors written in the order (prediction, step, agent); returns
    (errors written, pairs not scored) and each prediction's next unscored step in
    ``new_first``. The same IEEE operations in the same order as the vectorised form (the
    interpolation, ``numpy.hypot`` = the C library's ``hypot``); an agent's row is the
    last row of its id in the history (``obs_ids`` sorted stably, ``obs_rows`` their
    rows), as the vectorised form's dictionary keeps it."""
    n_cols = hist.shape[1]
    horizon = pred.shape[1]
    k = 0
    unscored = 0
    for p in range(t_made.shape[0]):
        a0, a1 = off[p], off[p + 1]
        m = a1 - a0
        h = first[p]
        while h <= horizon:
            back = obs_t - (t_made[p] + h * dt_plan)
            if back < -1e-9:
                break
            if back > span + 1e-9:  # older than the history: cannot be scored
                unscored += m
                h += 1
                continue
            f = back / obs_dt
            k0 = math.floor(f + 1e-9)
            w = max(f - k0, 0.0)
            c0 = n_cols - 1 - k0
            c1 = max(c0 - 1, 0)
            if c0 < 0:  # numpy's negative index
                c0 += n_cols
            for a in range(a0, a1):
                i = np.searchsorted(obs_ids, ids[a], side="right") - 1
                if i < 0 or obs_ids[i] != ids[a]:  # left the sensor
                    unscored += 1
                    continue
                r = obs_rows[i]
                if w == 0.0:
                    px = hist[r, c0, 0]
                    py = hist[r, c0, 1]
                else:
                    px = hist[r, c0, 0] + w * (hist[r, c1, 0] - hist[r, c0, 0])
                    py = hist[r, c0, 1] + w * (hist[r, c1, 1] - hist[r, c0, 1])
                if not (math.isfinite(px) and math.isfinite(py)):
                    unscored += 1
                    continue
                steps_out[k] = h
                err_out[k] = c_hypot(px - pred[a, h - 1, 0], py - pred[a, h - 1, 1])
                k += 1
            h += 1
        new_first[p] = h
    return k, unscored


@jit
def _merge_windows(
    old: np.ndarray,
    old_off: np.ndarray,
    ring: np.ndarray,
    start: np.ndarray,
    count: np.ndarray,
    new: np.ndarray,
    new_off: np.ndarray,
    move: np.ndarray,
    out_off: np.ndarray,
) -> np.ndarray:
    """Every step's sorted window after its new errors: for each step h with ``move[h]``,
    the oldest errors leaving the window (the ring ``ring[h]``, oldest at ``start[h]``,
    ``count[h]`` of them; updated in place with the new errors) removed from its sorted
    copy ``old[old_off[h]:old_off[h + 1]]``, and the new ones
    ``new[new_off[h]:new_off[h + 1]]`` merged in; the other steps copied. Written into a
    new array at ``out_off``. The same array as ``numpy.delete`` of the leftmost copies of
    the errors leaving and ``numpy.insert`` of the new ones, sorted, before their equals
    (the form this replaces): finite errors, in one pass. A step whose errors leaving are
    not all in its sorted copy (the window changed from outside) is not written and its
    ``move[h]`` set to False, for the caller to sort it afresh."""
    cap = ring.shape[1]
    out = np.empty(out_off[-1])
    for h in range(old_off.shape[0] - 1):
        src = old[old_off[h] : old_off[h + 1]]
        dst = out[out_off[h] : out_off[h + 1]]
        if not move[h]:
            for t in range(src.shape[0]):
                dst[t] = src[t]
            continue
        add = np.sort(new[new_off[h] : new_off[h + 1]])
        k = add.shape[0]
        gone = max(count[h] + k - cap, 0)
        leave = np.empty(gone)
        for i in range(gone):
            leave[i] = ring[h, (start[h] + i) % cap]
        leave = np.sort(leave)
        n = src.shape[0]
        cut = np.empty(gone, dtype=np.int64)  # where the leaving errors are (leftmost copies)
        for i in range(gone):
            if i > 0 and leave[i] == leave[i - 1]:
                cut[i] = cut[i - 1] + 1
            else:
                cut[i] = np.searchsorted(src, leave[i], side="left")
        found = True
        for i in range(gone):
            found = found and cut[i] < n and src[cut[i]] == leave[i]
        if not found:  # the sorted copy is not the window's (changed from outside)
            move[h] = False
            continue
        put = np.searchsorted(src, add, side="left")  # a new error before its equals
        o = 0
        s = 0
        i = 0
        a = 0
        while True:  # copy the runs between the events
            nd = cut[i] if i < gone else n
            na = put[a] if a < k else n
            stop = min(nd, na)
            for t in range(s, stop):
                dst[o] = src[t]
                o += 1
            s = stop
            if a < k and na <= nd:
                dst[o] = add[a]
                o += 1
                a += 1
            elif i < gone:
                s += 1
                i += 1
            else:
                break
        start[h] = (start[h] + gone) % cap
        count[h] -= gone
        for i in range(k):
            ring[h, (start[h] + count[h] + i) % cap] = new[new_off[h] + i]
        count[h] += k
    return out


def _region_radii(sorted_scores: tuple[np.ndarray, ...], lam: float) -> np.ndarray:
    """:func:`~conformal_control.families.cbf.acp.region_radii` for all steps at once: the
    conformal radius of each step's sorted errors at level ``1 - lam`` (``inf``: everything,
    ``-inf``: empty), the same numbers as
    :func:`~conformal_control.core.losses.conformal_radius` step by step (the rank
    ``ceil((n + 1)(1 - lam))`` in the same float arithmetic)."""
    h_n = len(sorted_scores)
    if lam >= 1.0:
        return np.full(h_n, -math.inf)
    out = np.full(h_n, math.inf)
    if lam <= 0.0:
        return out
    n = np.fromiter(map(len, sorted_scores), np.int64, h_n)
    k = np.ceil((n + 1) * (1.0 - lam)).astype(np.int64)
    for h in np.flatnonzero((n > 0) & (k <= n)).tolist():
        out[h] = sorted_scores[h][max(int(k[h]), 1) - 1]
    return out


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
        # each step's window as a ring of floats (arrival order, oldest at _start[h]; the
        # same errors as scores_[h] while len(scores_[h]) is the sorted copy's length)
        self._ring = np.zeros((h, int(self.window)))
        # the sorted copies, one after the other (_sorted[h] = _buf[_off[h]:_off[h + 1]])
        self._buf = np.zeros(0)
        self._off = np.zeros(h + 1, dtype=np.int64)
        self._made = self._sorted
        self._start = np.zeros(h, dtype=np.int64)
        self._count = np.zeros(h, dtype=np.int64)
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
        """Errors of the stored predictions whose targets have passed: (steps, errors), in
        the order (prediction, step, agent).

        Compiled (:func:`_score_kernel`) for integer ids and float64 histories and
        predictions; otherwise :meth:`_score_numpy`. Both give the same arrays, bit for
        bit, and the same counters."""
        pending = self._pending
        hist = observation.history
        obs_ids = np.asarray(observation.ids)
        if not pending:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        if (
            obs_ids.dtype.kind != "i"
            or hist.dtype != np.float64
            or any(e[1].dtype.kind != "i" or e[2].dtype != np.float64 for e in pending)
            or len({e[2].shape[1] for e in pending}) != 1
        ):
            return self._score_numpy(observation)
        horizon = pending[0][2].shape[1]
        sizes = np.array([e[1].shape[0] for e in pending], dtype=np.int64)
        off = np.zeros(sizes.size + 1, dtype=np.int64)
        np.cumsum(sizes, out=off[1:])
        first = np.array([e[3] for e in pending], dtype=np.int64)
        order = np.argsort(obs_ids, kind="stable")
        room = int((sizes * np.maximum(horizon - first + 1, 0)).sum())
        steps = np.empty(room, dtype=np.int64)
        errors = np.empty(room)
        new_first = np.empty(sizes.size, dtype=np.int64)
        n, unscored = _score_kernel(
            np.array([e[0] for e in pending], dtype=np.float64),
            first,
            off,
            np.concatenate([e[1] for e in pending]).astype(np.int64, copy=False),
            np.concatenate([e[2] for e in pending]).reshape(-1, horizon, 2),
            np.ascontiguousarray(obs_ids[order], dtype=np.int64),
            order.astype(np.int64, copy=False),
            np.ascontiguousarray(hist),
            float(observation.t),
            float(observation.dt),
            float((hist.shape[1] - 1) * observation.dt),
            float(self.sampling.dt_plan),
            steps,
            errors,
            new_first,
        )
        self._pending = [
            (e[0], e[1], e[2], int(h))
            for e, h in zip(pending, new_first.tolist(), strict=True)
            if h <= horizon
        ]
        self.n_unscored_ += int(unscored)
        self.n_scored_ += int(n)
        return steps[:n], errors[:n]

    def _score_numpy(self, observation: PredictionQuery) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_score` vectorised over the agents of a stored prediction (the same
        arithmetic, element by element, as one agent at a time: the interpolation and
        ``numpy.hypot``); for ids or arrays the compiled form does not take."""
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
        ones merged in (:func:`_merge_windows`, compiled: the same array as sorting the
        window afresh, without re-sorting 2,000 errors per step at every sampling time). A
        window whose length is no longer that of its sorted copy (filled from outside, as
        ``benchmarks/bench_mpc.py`` seeds it), more new errors than the window holds, or a
        non-finite error is sorted afresh."""
        if not steps.size:
            return
        n_steps = len(self.scores_)
        cap = int(self.window)
        order = np.argsort(steps, kind="stable")  # each step's errors in arrival order
        grouped = np.ascontiguousarray(errors[order], dtype=np.float64)
        by_step = steps[order]
        new_off = np.searchsorted(by_step, np.arange(1, n_steps + 2), "left").astype(np.int64)
        counts = np.diff(new_off)
        if self._sorted is not self._made:  # not the copies made here: lay them out again
            self._buf = np.concatenate(self._sorted) if n_steps else np.zeros(0)
            self._off = np.zeros(n_steps + 1, dtype=np.int64)
            np.cumsum([x.size for x in self._sorted], out=self._off[1:])
        buf, off = self._buf, self._off
        sizes = np.diff(off)
        lengths = np.fromiter(map(len, self.scores_), np.int64, n_steps)
        last = buf[np.maximum(off[1:] - 1, 0)] if buf.size else np.zeros(n_steps)
        stale = (sizes != lengths) | (counts > cap) | ((sizes > 0) & np.isnan(last))
        fresh = (counts > 0) & stale
        finite = np.isfinite(grouped)
        if not finite.all():
            fresh |= np.bincount(by_step[~finite] - 1, minlength=n_steps) > 0
        move = (counts > 0) & ~fresh
        listed = grouped.tolist()
        for h in np.flatnonzero(counts).tolist():
            self.scores_[h].extend(listed[new_off[h] : new_off[h + 1]])
        out_off = np.zeros(n_steps + 1, dtype=np.int64)
        np.cumsum(np.where(move, np.minimum(sizes + counts, cap), sizes), out=out_off[1:])
        moving = move.copy()
        merged = _merge_windows(
            buf, off, self._ring, self._start, self._count, grouped, new_off, move, out_off
        )
        fresh |= moving & ~move  # the window changed from outside: sorted afresh
        if fresh.any():
            rows = [merged[out_off[h] : out_off[h + 1]] for h in range(n_steps)]
            for h in np.flatnonzero(fresh).tolist():
                window = np.fromiter(self.scores_[h], float)
                rows[h] = np.sort(window)
                self._ring[h, : window.size] = window
                self._start[h] = 0
                self._count[h] = window.size
            merged = np.concatenate(rows)
            np.cumsum([x.size for x in rows], out=out_off[1:])
        self._buf, self._off = merged, out_off
        self._sorted = self._made = tuple(
            merged[a:b] for a, b in zip(out_off[:-1].tolist(), out_off[1:].tolist(), strict=True)
        )

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
            radii = _region_radii(self._sorted, lam)
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
        radii = _region_radii(tuple(record.sorted_scores), lam)
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
