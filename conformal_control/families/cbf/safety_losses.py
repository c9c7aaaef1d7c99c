"""Safety losses for the flagship: collision indicator and distance shortfall.

Both score an interval of the conformal CBF controller from what actually happened: the
ego positions at the executed control instants (``CBFIntervalRecord.x_ego``) and the
sensor's true trajectories of the agents sensed at the interval's start (``CBFTruth``),
interpolated at the control instants exactly as :class:`~conformal_control.families.cbf.CBFGapLoss`
does. They do not depend on lambda directly (only through the decisions taken), so a
rule's counterfactual evaluation at another lambda returns the same value. They are
non-decreasing in lambda in expectation (a larger lambda loosens every barrier
constraint), which is the toolkit's sign convention.

Agents that were not sensed at the interval's start are not in the truth and are not
scored (the same information the gap loss has); pairs whose truth is missing (agent left
the view) are left out and counted; an interval without any scored pair has no loss.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...core.base import KeyedLosses, Loss
from ...core.jit import kernel
from ...core.losses import check_lambda
from .controller import CBFIntervalRecord
from .interp import interpolate_at_substeps
from .loss import CBFTruth, gap_test_inputs

__all__ = ["CollisionLoss", "DistanceShortfallLoss", "min_distances", "smallest_distance"]


def min_distances(record: CBFIntervalRecord, truth: CBFTruth) -> np.ndarray:
    """Centre distance ego-agent at each control instant, shape (S, N) over the agents the
    record scores (``record.scored``, every agent by default); NaN if unknown."""
    s, n = record.n_steps, record.ids.size
    if s == 0 or n == 0:
        return np.zeros((s, n))
    x_true, _ = interpolate_at_substeps(truth.samples, truth.dt, truth.substeps, s)
    d: np.ndarray = np.linalg.norm(x_true - record.x_ego[:, None, :], axis=-1)
    if record.scored is not None:
        d = d[:, np.asarray(record.scored, dtype=bool)]
    return d


def _nearest_numpy(
    samples: np.ndarray, dt: float, substeps: int, x_ego: np.ndarray
) -> tuple[float, bool]:
    s, n = x_ego.shape[0], samples.shape[0]
    if s == 0 or n == 0:
        return math.inf, False
    x_true, _ = interpolate_at_substeps(samples, dt, substeps, s)
    d = np.linalg.norm(x_true - x_ego[:, None, :], axis=-1)
    finite = bool(np.isfinite(d).any())
    return (float(np.nanmin(d)) if finite else math.inf), finite


@kernel(cache=True, nogil=True, python=_nearest_numpy)
def _nearest(
    samples: np.ndarray, dt: float, substeps: int, x_ego: np.ndarray
) -> tuple[float, bool]:  # pragma: no cover - compiled
    """``(numpy.nanmin(d), numpy.isfinite(d).any())`` of :func:`min_distances`' ``d`` (every
    agent scored), without forming it: the positions interpolated with
    :func:`~conformal_control.families.cbf.interp.interpolate_at_substeps`' operations
    (``frac = (s % substeps) / substeps``, ``p0 + frac * (p1 - p0)``), the distance as
    ``numpy.linalg.norm`` forms it for a pair (``sqrt(dx * dx + dy * dy)``), the smallest
    taken over the non-NaN ones (a minimum selects: the same float). The caller checks the
    shapes (``x_ego`` (S, 2) with ``S <= F * substeps``)."""
    best = math.inf
    finite = False
    for k in range(x_ego.shape[0]):
        i = k // substeps
        frac = (k % substeps) / substeps
        ex = x_ego[k, 0]
        ey = x_ego[k, 1]
        for a in range(samples.shape[0]):
            p0 = samples[a, i, 0]
            dx = (p0 + frac * (samples[a, i + 1, 0] - p0)) - ex
            p0 = samples[a, i, 1]
            dy = (p0 + frac * (samples[a, i + 1, 1] - p0)) - ey
            d = math.sqrt(dx * dx + dy * dy)
            if math.isfinite(d):
                finite = True
            if d < best:  # (False for NaN: skipped, as numpy.nanmin skips it)
                best = d
    return best, finite


def smallest_distance(record: CBFIntervalRecord, truth: CBFTruth) -> float | None:
    """The smallest centre distance ego-agent over the interval,
    ``numpy.nanmin(min_distances(record, truth))``, or None when no distance is finite (or
    there is none): what :class:`CollisionLoss` and :class:`DistanceShortfallLoss` score.
    Compiled when every agent is scored (the same number; ``min_distances`` otherwise).

    Parameters
    ----------
    record : CBFIntervalRecord
        The interval's record (``x_ego`` at the control instants, ``ids``, ``scored``).
    truth : CBFTruth
        The sensed agents' true trajectories.
    """
    x_ego, samples = record.x_ego, truth.samples
    if record.scored is None and isinstance(x_ego, np.ndarray) and isinstance(samples, np.ndarray):
        s = record.n_steps
        if (
            x_ego.shape == (s, 2)
            and samples.ndim == 3
            and samples.shape[2] == 2
            and samples.shape[0] == record.ids.size
            and x_ego.dtype == np.float64
            and samples.dtype == np.float64
        ):
            if s == 0 or samples.shape[0] == 0:
                return None
            if s > (samples.shape[1] - 1) * truth.substeps:
                interpolate_at_substeps(samples, truth.dt, truth.substeps, s)  # raises
            best, finite = _nearest(
                np.ascontiguousarray(samples),
                float(truth.dt),
                int(truth.substeps),
                np.ascontiguousarray(x_ego),
            )
            return float(best) if finite else None
    d = min_distances(record, truth)
    if d.size == 0 or not np.isfinite(d).any():
        return None
    return float(np.nanmin(d))


class CollisionLoss(
    Loss[CBFIntervalRecord, CBFTruth],
    compiled="collision",
    run_values={"d_c": "collision_distance"},
):
    """l_k = 1 if the ego came closer than ``d_c`` to a sensed agent during I_k, else 0.

    Parameters
    ----------
    d_c : float
        Collision distance between centres (m); the paper's 0.5 m + 0.5 m.
    """

    bounds = (0.0, 1.0)

    def __init__(self, d_c: float = 1.0) -> None:
        self.d_c = d_c

    @classmethod
    def _unit_test_inputs(cls) -> list[tuple[CBFIntervalRecord, CBFTruth]]:
        return gap_test_inputs()

    def __call__(self, record: CBFIntervalRecord, truth: CBFTruth, lam: float) -> float | None:
        check_lambda(lam)
        if not (math.isfinite(self.d_c) and self.d_c > 0):
            raise ValueError(f"d_c must be a finite distance > 0, got {self.d_c!r}")
        d_min = smallest_distance(record, truth)
        if d_min is None:
            return None
        return float(d_min < self.d_c)

    def diagnostics(
        self, record: CBFIntervalRecord, truth: CBFTruth, lam: float
    ) -> dict[str, float]:
        d = min_distances(record, truth)
        if d.size == 0 or not np.isfinite(d).any():
            return {}
        return {"d_min": float(np.nanmin(d)), "n_truth_missing": int((~np.isfinite(d)).sum())}


class DistanceShortfallLoss(
    Loss[CBFIntervalRecord, CBFTruth],
    compiled="distance_shortfall",
    run_values={"d_c": "collision_distance", "d_safe": "safe_distance"},
):
    """l_k = clip((d_safe - d_min,k) / (d_safe - d_c), 0, 1): how far inside the margin.

    0 when the ego kept at least ``d_safe`` from every sensed agent during I_k, 1 at or
    below the collision distance ``d_c``, linear in between (the CDT paper's SDD
    experiment scores the robot by how much it intrudes into a safety distance; this is
    that idea normalised to [0, 1]).

    Parameters
    ----------
    d_safe : float
        Safety distance between centres (m), > d_c.
    d_c : float
        Collision distance (m), >= 0.
    """

    bounds = (0.0, 1.0)

    def __init__(self, d_safe: float = 2.0, d_c: float = 1.0) -> None:
        self.d_safe = d_safe
        self.d_c = d_c

    @classmethod
    def _unit_test_inputs(cls) -> list[tuple[CBFIntervalRecord, CBFTruth]]:
        return gap_test_inputs()

    def __call__(self, record: CBFIntervalRecord, truth: CBFTruth, lam: float) -> float | None:
        check_lambda(lam)
        if not (math.isfinite(self.d_safe) and math.isfinite(self.d_c)):
            raise ValueError("d_safe and d_c must be finite")
        if not (0 <= self.d_c < self.d_safe):
            raise ValueError(f"need 0 <= d_c < d_safe, got d_c={self.d_c}, d_safe={self.d_safe}")
        d_min = smallest_distance(record, truth)
        if d_min is None:
            return None
        shortfall = (self.d_safe - d_min) / (self.d_safe - self.d_c)
        return float(min(max(shortfall, 0.0), 1.0))

    def components(self, record: CBFIntervalRecord, truth: CBFTruth, lam: Any) -> KeyedLosses:
        """Each scored agent's shortfall (its own nearest approach; NaN without truth):
        the interval's loss is their largest. ``lam`` enters only through the decisions."""
        for x in np.ravel(np.asarray(lam, dtype=float)).tolist():
            check_lambda(x)
        keys = np.asarray(record.ids, dtype=np.int64)
        if record.scored is not None:
            keys = keys[np.asarray(record.scored, dtype=bool)]
        d = min_distances(record, truth)
        near = np.full(keys.size, np.nan)
        has = np.isfinite(d).any(axis=0) if d.size else np.zeros(keys.size, dtype=bool)
        if has.any():
            near[has] = np.nanmin(d[:, has], axis=0)
        values = np.clip((self.d_safe - near) / (self.d_safe - self.d_c), 0.0, 1.0)
        return KeyedLosses(keys, values, lambda i, _lam: _finite_or_none(values[i]))


def _finite_or_none(x: float) -> float | None:
    return None if math.isnan(x) else float(x)
