"""A loss that makes the conformal MPC's lambda follow the predictor's error
(``margin_miscoverage``).

The conformal controller of conformal decision theory on the sampling MPC (``cc_mpc``) learns
its safe distance ``d_c + margin - lambda`` from the *distance shortfall*: how far the robot
came inside a safety distance. That loss measures encounters, not predictions: a robot that
meets a pedestrian is scored the same whether the forecast saw the pedestrian coming or not,
and lambda follows the update rule's asymmetry (a small step up per quiet interval, a large
step down per encounter) more than the predictor.

This loss asks instead whether the margin covered the prediction's error where it mattered.
The plan keeps the robot's *predicted* clearance ``min_j |x - y^_j|`` at least ``d_c +
margin - lambda``; the true clearance ``min_j |x - y_j|`` then stays at least ``d_c`` exactly
when the **clearance error**

    e(s) = min_j |x(s) - y^_j(s)| - min_j |x(s) - y_j(s)|

(how much the prediction overestimated the distance to the nearest pedestrian, at the
robot's own position at control instant s) is at most ``margin - lambda``. The loss of an
interval is 1 when the largest error over its *relevant* instants (the nearest pedestrian,
predicted or true, within ``d_safe``) exceeds ``margin - lambda``, 0 when it does not, and
there is no loss (no update) when no instant was relevant. It is non-decreasing in lambda.

With the fixed-eta rule and target ``epsilon``, lambda converges to where the margin
``margin - lambda`` is the ``1 - epsilon`` quantile of the relevant intervals' clearance
errors: a predictor that errs more (a delayed forecast) gets a larger margin, an accurate
one a smaller one, and intervals far from everybody do not move lambda at all.

**Per pedestrian** (``lambda_per="agent"``, loss ``margin_miscoverage_agent``):
pedestrian j's safe distance is ``d_c + margin - lambda_j`` and its loss asks the same
question of its own forecast: the largest of ``|x(s) - y^_j(s)| - |x(s) - y_j(s)|`` over the
instants where j (predicted or true) is within ``d_safe``, against ``margin - lambda_j``
(:func:`agent_clearance_errors`). A badly forecast pedestrian gets a larger margin without
widening it for the well-forecast ones. With one pedestrian the two losses are the same
number.

The record's predictions at the control instants are the interval's forecast (made at its
start); the truth is the sensor's. The error is therefore that of the forecast up to one
sampling period ahead, the part of the plan that is executed before the next plan.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...core.base import KeyedLosses, Loss
from ...core.losses import check_lambda
from ..cbf.controller import CBFIntervalRecord
from ..cbf.interp import interpolate_at_substeps
from ..cbf.loss import CBFTruth, gap_test_inputs, lambda_columns

__all__ = [
    "AgentMarginMiscoverageLoss",
    "MarginMiscoverageLoss",
    "agent_clearance_errors",
    "clearance_errors",
]


def _distances(
    record: CBFIntervalRecord, truth: CBFTruth
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The robot's true and predicted distance to every scored agent at every control
    instant, shape (S, n) each, and where both positions are known (a NaN position's
    distance is to the origin's stand-in: read it only where ``both``)."""
    s = record.n_steps
    y, _ = interpolate_at_substeps(truth.samples, truth.dt, truth.substeps, s)  # (S, N, 2)
    yhat = np.asarray(record.x_pred, dtype=float)
    if record.scored is not None:
        keep = np.asarray(record.scored, dtype=bool)
        y, yhat = y[:, keep], yhat[:, keep]
    x = np.asarray(record.x_ego, dtype=float)[:, None, :]
    both = np.isfinite(y).all(axis=-1) & np.isfinite(yhat).all(axis=-1)  # (S, n)
    d_true = np.linalg.norm(x - np.nan_to_num(y), axis=-1)
    d_pred = np.linalg.norm(x - np.nan_to_num(yhat), axis=-1)
    return d_true, d_pred, both


def clearance_errors(
    record: CBFIntervalRecord, truth: CBFTruth, d_safe: float = math.inf
) -> np.ndarray:
    """The clearance error ``e(s)`` (m) at every relevant control instant of the interval.

    Parameters
    ----------
    record : CBFIntervalRecord
        The interval's ego positions and the forecast at the control instants.
    truth : CBFTruth
        The sensor's true positions.
    d_safe : float
        An instant is relevant when the nearest pedestrian, predicted or true, is within
        this distance (m).

    Returns
    -------
    ndarray of shape (R,)
        One error per relevant instant with a pedestrian known both ways.
    """
    if record.n_steps == 0 or record.ids.size == 0:
        return np.zeros(0)
    d_true, d_pred, both = _distances(record, truth)
    d_true, d_pred = np.where(both, d_true, np.inf), np.where(both, d_pred, np.inf)
    near_true, near_pred = d_true.min(axis=1), d_pred.min(axis=1)
    relevant = np.isfinite(near_true) & (np.minimum(near_true, near_pred) <= d_safe)
    out: np.ndarray = near_pred[relevant] - near_true[relevant]
    return out


def agent_clearance_errors(
    record: CBFIntervalRecord, truth: CBFTruth, d_safe: float = math.inf
) -> tuple[np.ndarray, np.ndarray]:
    """Each scored agent's largest clearance error (m) over its relevant instants.

    Agent j's error at control instant s is ``|x(s) - y^_j(s)| - |x(s) - y_j(s)|`` (how much
    its forecast overestimated its distance to the robot); an instant is relevant for j when
    j, predicted or true, is within ``d_safe``.

    Parameters
    ----------
    record : CBFIntervalRecord
        The interval's ego positions and the forecast at the control instants.
    truth : CBFTruth
        The sensor's true positions.
    d_safe : float
        Relevance distance (m).

    Returns
    -------
    (ndarray of shape (n,), ndarray of shape (n,))
        The scored agents' keys (int64) and their largest error (NaN: no relevant instant
        with the agent known both ways).
    """
    keys = np.asarray(record.ids, dtype=np.int64)
    s = record.n_steps
    if record.scored is not None:
        keys = keys[np.asarray(record.scored, dtype=bool)]
    top = np.full(keys.size, np.nan)
    if s == 0 or keys.size == 0:
        return keys, top
    d_true, d_pred, both = _distances(record, truth)
    relevant = both & (np.minimum(d_true, d_pred) <= d_safe)
    has = relevant.any(axis=0)
    if has.any():
        err = np.where(relevant, d_pred - d_true, -np.inf)
        top[has] = err[:, has].max(axis=0)
    return keys, top


class MarginMiscoverageLoss(
    Loss[CBFIntervalRecord, CBFTruth], run_values={"d_safe": "safe_distance"}
):
    """l_k(lambda) = 1 if the interval's largest clearance error at a relevant instant
    exceeded the margin ``margin - lambda``, else 0 (see
    :mod:`conformal_control.families.mpc.margin`).

    In {0, 1}, non-decreasing in lambda; no relevant instant: no loss. Target: the rule's
    epsilon, the rate at which the margin may be exceeded.

    Parameters
    ----------
    margin : float
        The family's fixed margin (m): its safe distance is ``d_c + margin - lambda``.
    d_safe : float
        Instants with the nearest pedestrian (predicted or true) within this distance count
        (m, > 0).
    """

    bounds = (0.0, 1.0)

    def __init__(self, margin: float = 0.0, d_safe: float = 2.0) -> None:
        self.margin = margin
        self.d_safe = d_safe

    @classmethod
    def _unit_test_inputs(cls) -> list[tuple[CBFIntervalRecord, CBFTruth]]:
        return gap_test_inputs()

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, float]]:
        return [{}, {"margin": 0.2, "d_safe": 5.0}]

    def _check(self) -> None:
        if not math.isfinite(self.margin):
            raise ValueError(f"margin must be a finite distance, got {self.margin!r}")
        if not (math.isfinite(self.d_safe) and self.d_safe > 0):
            raise ValueError(f"d_safe must be a finite distance > 0, got {self.d_safe!r}")

    def __call__(self, record: CBFIntervalRecord, truth: CBFTruth, lam: float) -> float | None:
        lam = check_lambda(lam)
        self._check()
        e = clearance_errors(record, truth, self.d_safe)
        if e.size == 0:
            return None
        return 1.0 if float(e.max()) > float(self.margin) - lam else 0.0

    def diagnostics(
        self, record: CBFIntervalRecord, truth: CBFTruth, lam: float
    ) -> dict[str, float]:
        self._check()
        e = clearance_errors(record, truth, self.d_safe)
        return {"clearance_error": float(e.max())} if e.size else {}


class AgentMarginMiscoverageLoss(MarginMiscoverageLoss):
    """The margin miscoverage loss per pedestrian (``margin_miscoverage_agent``): pedestrian
    j's term is 1 if its own largest clearance error at its relevant instants exceeded
    ``margin - lambda_j``, else 0 (:func:`agent_clearance_errors`); the interval's loss is the
    largest term. For lambda run per pedestrian (``lambda_per="agent"``), where pedestrian j's
    safe distance is ``d_c + margin - lambda_j``.

    With a scalar lambda it differs from ``margin_miscoverage``, which scores the error of the
    *nearest* pedestrian's distance (min over predictions minus min over truths): a
    pedestrian predicted farther than a nearer one hides its error there, not here. With one
    pedestrian the two are the same number.

    Parameters
    ----------
    margin : float
        The family's fixed margin (m): pedestrian j's safe distance is
        ``d_c + margin - lambda_j``.
    d_safe : float
        Instants with pedestrian j (predicted or true) within this distance count for j
        (m, > 0).
    """

    def __call__(self, record: CBFIntervalRecord, truth: CBFTruth, lam: Any) -> float | None:
        if not np.ndim(lam):
            check_lambda(lam)
        comp = self.components(record, truth, lam)
        ok = np.isfinite(comp.values)
        return float(comp.values[ok].max()) if ok.any() else None

    def diagnostics(self, record: CBFIntervalRecord, truth: CBFTruth, lam: Any) -> dict[str, float]:
        self._check()
        _, top = agent_clearance_errors(record, truth, self.d_safe)
        ok = np.isfinite(top)
        return {"clearance_error": float(top[ok].max())} if ok.any() else {}

    def components(self, record: CBFIntervalRecord, truth: CBFTruth, lam: Any) -> KeyedLosses:
        """Pedestrian j's loss: 1 if its largest clearance error at its relevant instants
        exceeded ``margin - lambda_j``, else 0; NaN without a relevant instant
        (:func:`agent_clearance_errors`). ``lam`` is a number or one entry per record agent
        (``record.ids``'s order)."""
        self._check()
        lam_arr = lambda_columns(record, lam)
        if record.scored is not None:
            lam_arr = lam_arr[np.asarray(record.scored, dtype=bool)]
        keys, top = agent_clearance_errors(record, truth, self.d_safe)
        values = np.where(np.isnan(top), np.nan, (top > self.margin - lam_arr).astype(float))
        return KeyedLosses(keys, values, _AgentMarginAt(self.margin, top))


class _AgentMarginAt:
    """Agent i's margin loss at another lambda (picklable)."""

    def __init__(self, margin: float, top: np.ndarray) -> None:
        self.margin, self.top = margin, top

    def __call__(self, i: int, lam: float) -> float | None:
        top = float(self.top[i])
        return None if math.isnan(top) else (1.0 if top > self.margin - lam else 0.0)
