"""The paper's loss: the squashed gap between predicted and true CBF constraints."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.base import CompiledForm, KeyedLosses, Loss
from .constraint import ConformalConstraint
from .interp import interpolate_at_substeps
from .reciprocal import grown_constraint
from .records import CBFIntervalRecord, CBFTruth

__all__ = [
    "SHORTFALL_CAP",
    "CBFGapLoss",
    "CBFShortfallLoss",
    "CBFTruth",
    "GapLossForm",
    "gap_test_inputs",
    "lambda_columns",
]


@dataclass(frozen=True)
class GapLossForm(CompiledForm):
    """The gap loss as the compiled engine scores it: ``squash(max_gap + lambda)``.

    Attributes
    ----------
    scale : float
        The squashing's scale c (m/s).
    squash : callable
        The loss's own squashing ``s(r) = arctan(r / c) / pi`` (the same bits).
    """

    kernel = "cbf_gap"
    scale: float
    squash: Callable[[Any], Any]


class CBFGapLoss(
    Loss[CBFIntervalRecord, CBFTruth],
    compiled="cbf_gap",
    run_values={"constraint": "constraint", "scale": "loss_scale"},
):
    """l_k = max over sensed agents j and control instants t of s(gap_j(t) + lambda_k).

    gap_j(t) = [dh^/dx_i . v_i + dh^/dx_j . v^_j + a h^] - [dh/dx_i . v_i + dh/dx_j . v_j + a h],
    the conformal constraint
    (:class:`~conformal_control.families.cbf.constraint.ConformalConstraint`)
    evaluated on the interpolated prediction (hats) minus the same constraint on the true
    trajectory interpolated and differentiated the same way; x_i is the ego position and
    v_i the velocity decision applied at t. With a perfect predictor gap = 0 and
    l_k = s(lambda_k) exactly. s(r) = arctan(r / c) / pi with the loss scale c (1/s).

    (agent, instant) pairs whose truth is missing (the agent vanished mid-interval) are
    left out of the max and counted in the diagnostics; an interval with no pair left has
    no loss (and lambda is not updated).

    In a multi-robot world the record says which agents are scored (``record.scored``:
    those whose rows lambda is the slack of) and, for a robot handled reciprocally, its
    share ``s_ij`` (``record.share``): the predicted constraint is then the partner's
    assumed part ``dh^/dx_j . v~_j + s_ij a h^`` and the true one its actual part
    ``dh/dx_j . v_j + a h`` (:mod:`~conformal_control.families.cbf.reciprocal`).

    Parameters
    ----------
    constraint : ConformalConstraint
        The constraint the controller uses (the same instance: same barrier, same a).
    scale : float
        Loss scale c in 1/s (the paper's numbers use 1 per frame = fps per second).
    """

    bounds = (-0.5, 0.5)

    def __init__(self, constraint: ConformalConstraint, scale: float = 1.0) -> None:
        self.constraint = constraint
        self.scale = scale

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        from .barriers import APFBarrier

        return [
            {"constraint": ConformalConstraint(APFBarrier())},
            {
                "constraint": ConformalConstraint(APFBarrier(convention="centre", d_c=0.6), a=2.0),
                "scale": 0.5,
            },
        ]

    @classmethod
    def _unit_test_inputs(cls) -> list[tuple[CBFIntervalRecord, CBFTruth]]:
        """Sample ``(record, truth)`` pairs for the contract kit (:func:`gap_test_inputs`)."""
        return gap_test_inputs()

    def compiled_state(self) -> GapLossForm:
        """The scale and the squashing, as the compiled engine scores the loss."""
        return GapLossForm(self.scale, self.squash)

    def squash(self, r: np.ndarray | float) -> np.ndarray | float:
        """s(r) = arctan(r / c) / pi, in (-1/2, 1/2)."""
        return np.arctan(np.asarray(r) / self.scale) / np.pi

    def level(self, epsilon: float) -> float:
        """The largest r with s(r) <= ``epsilon``: c tan(pi epsilon) (1/s).

        An agent whose largest gap plus lambda is at most this has a loss of at most
        epsilon (what the derived lambda_safe rests on,
        :func:`~conformal_control.families.cbf.safe_lambda.derive_lambda_safe`).

        Parameters
        ----------
        epsilon : float
            A target inside the loss's range (:attr:`bounds`).

        Raises
        ------
        ValueError
            If ``epsilon`` lies outside the open range (one line).
        """
        eps = float(epsilon)
        lo, hi = self.bounds
        if not lo < eps < hi:
            raise ValueError(
                f"epsilon must lie in ({lo:g}, {hi:g}) for the {type(self).__name__}, "
                f"got {epsilon!r}"
            )
        return float(self.scale * math.tan(math.pi * eps))

    def gaps(self, record: CBFIntervalRecord, truth: CBFTruth) -> np.ndarray:
        """gap_j(t) without lambda, shape (S, N) over the scored agents; NaN where the
        truth is missing."""
        cached: tuple[CBFIntervalRecord, CBFTruth, np.ndarray] | None = getattr(
            self, "_cache", None
        )
        if cached is not None and cached[0] is record and cached[1] is truth:
            return cached[2]
        gap = self._gaps(record, truth)
        self._cache = (record, truth, gap)
        return gap

    def _gaps(self, record: CBFIntervalRecord, truth: CBFTruth) -> np.ndarray:
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"loss scale must be a finite number > 0, got {self.scale!r}")
        s, n = record.n_steps, record.ids.size
        if s == 0 or n == 0:
            return np.zeros((s, n))
        x_true, v_true = interpolate_at_substeps(truth.samples, truth.dt, truth.substeps, s)
        x_ego = record.x_ego[:, None, :]
        v_ego = record.v_ego[:, None, :]
        pred = self.constraint.value(x_ego, v_ego, record.x_pred, record.v_pred, record.share)
        with np.errstate(invalid="ignore"):
            true = self.constraint.value(x_ego, v_ego, x_true, v_true)
        if record.margin is not None:  # agents (robots) with a larger collision distance
            margin = np.asarray(record.margin, dtype=float)
            share = None if record.share is None else np.asarray(record.share)
            for m in np.unique(margin[margin != 0.0]):
                c = margin == m
                con = grown_constraint(self.constraint, float(m))
                sh = None if share is None else share[c]
                pred[:, c] = con.value(x_ego, v_ego, record.x_pred[:, c], record.v_pred[:, c], sh)
                with np.errstate(invalid="ignore"):
                    true[:, c] = con.value(x_ego, v_ego, x_true[:, c], v_true[:, c])
        gap = pred - true
        valid = np.isfinite(x_true).all(-1) & np.isfinite(v_true).all(-1)
        gap = np.where(valid, gap, np.nan)
        if record.scored is not None:
            gap = gap[:, np.asarray(record.scored, dtype=bool)]
        return gap

    def __call__(self, record: CBFIntervalRecord, truth: CBFTruth, lam: float) -> float | None:
        if np.ndim(lam):  # one lambda per agent: the largest of the agents' terms
            comp = self.components(record, truth, lam)
            ok = np.isfinite(comp.values)
            return float(comp.values[ok].max()) if ok.any() else None
        if math.isnan(lam):
            raise ValueError("the loss needs a lambda that is a number, got nan")
        gap = self.gaps(record, truth)
        if gap.size == 0 or not np.isfinite(gap).any():
            return None
        return float(self.squash(np.nanmax(gap) + lam))

    def components(self, record: CBFIntervalRecord, truth: CBFTruth, lam: Any) -> KeyedLosses:
        """The loss per scored agent j: l_j = s(max_t gap_j(t) + lambda_j), NaN for an
        agent without truth; the interval's loss is their largest (``lam`` a number or
        an array with one entry per record agent, ``record.ids``'s order)."""
        lam_arr = lambda_columns(record, lam)
        gap = self.gaps(record, truth)
        keys = np.asarray(record.ids, dtype=np.int64)
        if record.scored is not None:
            scored = np.asarray(record.scored, dtype=bool)
            keys, lam_arr = keys[scored], lam_arr[scored]
        top = np.full(keys.size, np.nan)
        has = np.isfinite(gap).any(axis=0) if gap.size else np.zeros(keys.size, dtype=bool)
        if has.any():
            top[has] = np.nanmax(gap[:, has], axis=0)
        return self.keyed(keys, top, lam_arr)

    def keyed(self, keys: np.ndarray, top: np.ndarray, lam: np.ndarray) -> KeyedLosses:
        """The agents' losses from their largest gaps: l_j = s(top_j + lambda_j), NaN where
        ``top_j`` is (an agent without truth); what :meth:`components` returns, for an
        engine that computed the gaps itself.

        Parameters
        ----------
        keys : ndarray of shape (n,)
            The agents.
        top : ndarray of shape (n,)
            Each agent's largest gap (1/s; NaN: none).
        lam : ndarray of shape (n,)
            Each agent's lambda (1/s).
        """
        values = np.asarray(self.squash(top + lam), dtype=float)
        return KeyedLosses(keys, values, _AgentGapAt(self, top))

    def diagnostics(self, record: CBFIntervalRecord, truth: CBFTruth, lam: Any) -> dict[str, float]:
        gap = self.gaps(record, truth)
        if gap.size == 0 or not np.isfinite(gap).any():
            return {}
        if np.ndim(lam):  # per agent: each row's lambda is the applied one plus its offset
            lam_arr = lambda_columns(record, lam)
            ref = float(lam_arr.min())
            off = lam_arr - ref
            if record.scored is not None:
                off = off[np.asarray(record.scored, dtype=bool)]
            la = np.where(np.isfinite(record.lam_applied), record.lam_applied, ref)
            applied = float(self.squash(np.nanmax(gap + (la[:, None] + off[None, :]))))
        else:
            lam_applied = np.where(np.isfinite(record.lam_applied), record.lam_applied, lam)
            applied = float(self.squash(np.nanmax(gap + lam_applied[:, None])))
        return {
            "loss_applied": applied,
            "max_gap": float(np.nanmax(gap)),
            "n_pairs": int(np.isfinite(gap).sum()),
            "n_truth_missing": int((~np.isfinite(gap)).sum()),
        }


#: The shortfall loss's cap (in loss units, a shortfall of ``SHORTFALL_CAP`` times the
#: scale): with c = 30/s (one per frame at 30 fps) a shortfall up to 120/s is scored
#: linearly, which covers every gap within the derived bound G = 121/s of the crossing
#: suites (:func:`~conformal_control.families.cbf.safe_lambda.gap_bound`) at lambda <= 0.
SHORTFALL_CAP = 4.0


class CBFShortfallLoss(
    CBFGapLoss,
    compiled="cbf_gap",
    run_values={"constraint": "constraint", "scale": "loss_scale"},
):
    """The gap loss that grows with the shortfall: a big miss moves lambda by more than
    one step.

    With r = max_t gap_j(t) + lambda_j (agent j's term, as in :class:`CBFGapLoss`),
    ``l(r) = arctan(r / c) / pi`` for r <= 0 (the gap loss, unchanged) and
    ``l(r) = min(r / c, SHORTFALL_CAP)`` for r > 0. When agent j's row binds (the
    predicted constraint equals -lambda_j), r is by how much the true constraint fell
    short of 0 (true = predicted - gap = -(gap + lambda_j)); the gap loss saturates at 1/2
    however far it fell short, so a fixed-eta step moves lambda by at most eta (1/2 -
    epsilon). Here a shortfall r moves it by eta (r / c - epsilon): with eta = c (the
    benchmark's one per frame) by the shortfall itself, in one interval.

    The loss is continuous and increasing in r (slope 1/(pi c) below 0, 1/c above), in
    ``bounds = (-1/2, SHORTFALL_CAP)``. Every statement that needs only an increasing loss
    holds: the fixed-eta identity, Theorem 2 with the loss's range, and the derived
    lambda_safe of :func:`~conformal_control.families.cbf.safe_lambda.derive_lambda_safe`
    with this loss's :meth:`level` (equal to the gap loss's for epsilon <= 0). Compiled
    like the gap loss (``cbf_gap``: the engine computes the largest gaps and applies
    this loss's own :meth:`squash`).

    Parameters
    ----------
    constraint : ConformalConstraint
        The constraint the controller uses (the same instance: same barrier, same a).
    scale : float
        Loss scale c in 1/s.
    """

    bounds = (-0.5, SHORTFALL_CAP)

    def squash(self, r: np.ndarray | float) -> np.ndarray | float:
        """l(r): arctan(r / c) / pi for r <= 0, min(r / c, SHORTFALL_CAP) above."""
        x = np.asarray(r, dtype=float) / self.scale
        with np.errstate(invalid="ignore"):
            out = np.where(x > 0.0, np.minimum(x, SHORTFALL_CAP), np.arctan(x) / np.pi)
        return float(out) if out.ndim == 0 else out

    def level(self, epsilon: float) -> float:
        """The largest r with l(r) <= ``epsilon``: c tan(pi epsilon) for epsilon <= 0,
        c epsilon above (1/s).

        Parameters
        ----------
        epsilon : float
            A target in (-1/2, SHORTFALL_CAP).

        Raises
        ------
        ValueError
            If ``epsilon`` lies outside that range (one line).
        """
        eps = float(epsilon)
        if eps <= 0.0:
            return super().level(eps)
        lo, hi = self.bounds
        if not lo < eps < hi:
            raise ValueError(
                f"epsilon must lie in ({lo:g}, {hi:g}) for the {type(self).__name__}, "
                f"got {epsilon!r}"
            )
        return float(self.scale * eps)


class _AgentGapAt:
    """Agent i's gap loss at another lambda: s(max_t gap_i(t) + lambda) (picklable)."""

    def __init__(self, loss: CBFGapLoss, top: np.ndarray) -> None:
        self.loss, self.top = loss, top

    def __call__(self, i: int, lam: float) -> float | None:
        top = float(self.top[i])
        return None if math.isnan(top) else float(self.loss.squash(top + lam))


def lambda_columns(record: CBFIntervalRecord, lam: Any) -> np.ndarray:
    """lambda per record column: ``lam`` an array with one entry per record agent
    (``record.ids``'s order), or a number for every agent.

    Parameters
    ----------
    record : CBFIntervalRecord
        The interval's record (its ``ids`` give the columns).
    lam : float or array_like
        lambda, one number or one per agent.

    Raises
    ------
    ValueError
        For an array of another length, or a NaN entry (one line).
    """
    n = record.ids.size
    lam_arr = np.asarray(lam, dtype=float)
    if lam_arr.ndim == 0:
        lam_arr = np.full(n, float(lam_arr))
    if lam_arr.shape != (n,):
        raise ValueError(f"lambda per agent has shape {lam_arr.shape}; the record has {n} agents")
    if np.isnan(lam_arr).any():
        raise ValueError("the loss needs a lambda that is a number, got nan")
    return lam_arr


def gap_test_inputs() -> list[tuple[CBFIntervalRecord, CBFTruth]]:
    """Sample ``(record, truth)`` pairs for the contract kit: a perfect and a noisy
    prediction, an agent whose truth goes missing mid-interval, nothing sensed."""
    rng = np.random.default_rng(0)
    dt, substeps, n_samples, n = 0.4, 4, 3, 3
    s = n_samples * substeps
    t = np.arange(n_samples + 1) * dt
    start = rng.uniform(-3.0, 3.0, size=(n, 2))
    vel = rng.uniform(-1.0, 1.0, size=(n, 2))
    true = start[:, None, :] + vel[:, None, :] * t[None, :, None]
    x_ego = np.column_stack([np.linspace(0.0, 1.0, s), np.zeros(s)])
    v_ego = np.tile([0.8, 0.1], (s, 1))

    def record(samples: np.ndarray) -> CBFIntervalRecord:
        xp, vp = interpolate_at_substeps(samples, dt, substeps, s)
        return CBFIntervalRecord(
            ids=np.arange(samples.shape[0]),
            x_ego=x_ego.copy(),
            v_ego=v_ego.copy(),
            x_pred=xp,
            v_pred=vp,
            lam_applied=np.zeros(s),
            status=["optimal"] * s,
        )

    noisy = true + np.concatenate(
        [np.zeros((n, 1, 2)), rng.normal(0.0, 0.3, size=(n, n_samples, 2))], axis=1
    )
    missing = true.copy()
    missing[1, 2:] = np.nan
    empty = CBFIntervalRecord(
        ids=np.zeros(0, dtype=np.int64),
        x_ego=x_ego.copy(),
        v_ego=v_ego.copy(),
        x_pred=np.zeros((s, 0, 2)),
        v_pred=np.zeros((s, 0, 2)),
        lam_applied=np.zeros(s),
        status=["unconstrained"] * s,
    )
    return [
        (record(true), CBFTruth(true, dt, substeps)),
        (record(noisy), CBFTruth(true, dt, substeps)),
        (record(noisy), CBFTruth(missing, dt, substeps)),
        (empty, CBFTruth(np.zeros((0, n_samples + 1, 2)), dt, substeps)),
    ]
