"""Conformalized distance fields in the sampling MPC (the ``fcp_mpc`` family).

FCP-MPC ("From Prediction Uncertainty to Conformalized Distance Fields for Safe Motion
Planning", CORE-SNU/FCP-MPC, 2026; ``controllers/func_cp_mpc.py`` and
``planar/sims/sim_func_cp.py``, read, not used) plans against a **lower bound of the
distance** to the nearest pedestrian: at a candidate position x of plan step h,

    d_lower(x) = max(d_nom(x) - U_h(x), 0)

with ``d_nom(x)`` the distance from x to the nearest *predicted* pedestrian at that step and
``U_h`` the calibrated upper envelope of the distance field's error
(:mod:`~conformal_control.families.mpc.fieldcp`). Two ways to use it:

* ``mode="hard"`` (FCP-MPC (hard)): a candidate is safe when ``d_lower >= r_h`` at every
  step, with ``r_h = max(d_c + margin - 0.5 v_max omega_max (h - 1)^2 dt^2, 0)``: the
  published code relaxes the required clearance of later steps by the lateral displacement a
  unicycle can still realise before then (``relax=True``; the first step keeps the full
  distance, and steps whose ``r_h`` reaches 0 do not constrain). It is the kernel's per-
  candidate safe distance ``U_h(x) + r_h`` where ``r_h > 0``;
* ``mode="soft"`` (FCP-MPC (soft)): no candidate is excluded; the cost gains
  ``w_safety sum_h max(r_h - d_lower, 0)^2``.

Both check step ends (``continuous=False`` by default here, as published).

**Calibration.** With ``envelope`` given (a :class:`~conformal_control.families.mpc.fieldcp.
FunctionalEnvelope`: the published runs calibrate offline on the recording's prediction
file), the family uses it as it is. Without, it calibrates online from its own past: at each
sampling time it pairs the positions it predicted h plan steps ago with the positions now
observed (the pedestrians in both), keeps the last ``calibration__window`` pairs per step,
and fits the envelopes (:func:`~conformal_control.families.mpc.fieldcp.fit_envelope`) on a grid
around
the robot's first position and goal every ``calibration__refit_every`` sampling times once
a step has ``calibration__min_pairs`` pairs. A step without an envelope, and any position
outside the grid, takes ``constraint__outside`` (m) as its envelope value (the published
code's value outside its grid).

**The knob.** lambda sets the multiplier ``s = 1 - lambda`` of the envelope's radii (the
scalar the published online adaptation moves, ``CPOnlineAdapter``): a larger lambda =
smaller envelope = less conservative, the toolkit's convention; lambda = 0 is the envelope
as calibrated. The loss (:class:`FieldMiscoverageLoss`, ``field_miscoverage``) is the
published adaptation's violation: for every step h matured at the interval's start, whether
the realised residual field exceeded the envelope at any of the grid's anchors
(:meth:`~conformal_control.families.mpc.fieldcp.FieldGrid.anchors`) at the interval's lambda. With
the
fixed-eta rule (ACI's update, ``epsilon = 0.1``, step 0.05, the adapter's settings) lambda
moves as the published ``scale`` does; lambda in [-4, 0.8] is the adapter's clip of ``s`` to
[0.2, 5].

Where this differs from the published FCP-MPC: one multiplier for all plan steps (the
adapter keeps one per step); the realised field of a step is scored over the pedestrians
predicted and observed (the adapter compares all predicted with all observed positions); the
step ends' distances are computed in float64; the published rows of the ETH/UCY table run
*without* adaptation (``learn=False`` here), with ``w_safety = 100`` for the soft rows (the
default here; the class default of the published weights is 50).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...core.base import Loss, Settings
from ...core.losses import check_lambda
from ...predictors.base import PredictionQuery, Predictor
from ..cbf.controller import ControlState
from ..cbf.roles import Dynamics, ReferenceController
from .controller import MPCIntervalRecord, Plan, PlanInputs, SamplingMPC
from .fieldcp import (
    FieldGrid,
    FunctionalEnvelope,
    check_calibration,
    fit_envelope,
    step_distances,
)
from .settings import Costs, Limits, Sampling

__all__ = [
    "FCPMPC",
    "MODES",
    "FCPMPCIntervalRecord",
    "FieldCalibration",
    "FieldConstraint",
    "FieldMiscoverageLoss",
]

#: How the envelope enters the plan (see the module docstring).
MODES = ("hard", "soft")


@dataclass(frozen=True)
class FieldCalibration(Settings):
    """How ``fcp_mpc`` calibrates its envelopes (the published settings as defaults).

    Parameters
    ----------
    miscoverage : float
        alpha of the envelopes, in (0, 1) (published: 0.1).
    n_components : int
        Principal components of the residual fields (published: 5).
    n_mixtures : int
        Gaussian mixture components (published: 7).
    calibration_share : float
        Share of the fields held out to calibrate the level, in (0, 1) (published: 0.3).
    grid_size : int
        Grid points per side of an online calibration (published: 128).
    grid_margin : float
        Margin (m) around the robot's start, its goal and the pedestrians first seen, of an
        online calibration's grid (published: 2 m around a scenario's points).
    slack : {"upper", "published"}
        How the projection slack is measured (:mod:`~conformal_control.families.mpc.fieldcp`).
    window : int
        Online: pairs kept per plan step (the most recent).
    min_pairs : int
        Online: pairs a step needs before its envelope is fitted (>= 4).
    refit_every : int
        Online: sampling times between fits.
    random_state : int
        Seed of the split and the mixtures (published: 0).
    """

    miscoverage: float = 0.1
    n_components: int = 5
    n_mixtures: int = 7
    calibration_share: float = 0.3
    grid_size: int = 128
    grid_margin: float = 2.0
    slack: str = "upper"
    window: int = 100
    min_pairs: int = 20
    refit_every: int = 20
    random_state: int = 0


@dataclass(frozen=True)
class FieldConstraint(Settings):
    """How the conformalized distance enters the plan.

    Parameters
    ----------
    mode : {"hard", "soft"}
        Exclude candidates closer than the safe distance (``hard``) or penalise them in
        the cost (``soft``).
    w_safety : float
        Weight of the soft penalty (1/m^2, >= 0; the published soft rows: 100).
    relax : bool
        Relax later steps' required clearance by ``0.5 v_max omega_max ((h - 1) dt)^2``
        (published; needs a unicycle plant).
    outside : float
        The envelope's value (m) outside the grid and at uncalibrated steps (published:
        1.0 outside the grid).
    n_anchors : int
        About how many grid points score a realised field (published: 256).
    """

    mode: str = "hard"
    w_safety: float = 100.0
    relax: bool = True
    outside: float = 1.0
    n_anchors: int = 256


@dataclass
class FCPMPCIntervalRecord(MPCIntervalRecord):
    """The MPC record plus the realised residual fields scored at the interval's start.

    Attributes
    ----------
    field_step : int ndarray of shape (P,)
        Plan step (1..H) of each field scored.
    field_needed : ndarray of shape (P,)
        For each, the largest lambda at which the envelope held the realised field at every
        anchor (``-inf``: none; ``inf``: any).
    """

    field_step: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    field_needed: np.ndarray = field(default_factory=lambda: np.zeros(0))


class FCPMPC(
    SamplingMPC,
    default_loss="field_miscoverage",
    lambda_unit="1",
    # the published adaptation: target violation 0.1, step 0.05, scale clipped to [0.2, 5]
    default_rule_params={"epsilon": 0.1, "eta": 0.05, "lambda_min": -4.0, "lambda_max": 0.8},
):
    """Sampling MPC planning against conformalized distance fields (FCP-MPC, 2026).

    See the module docstring. Run it with the fixed-eta rule (``epsilon`` 0.1, ``eta``
    0.05: the published adaptation) and the ``field_miscoverage`` loss, or without learning
    (lambda = 0: the published table's rows).

    Parameters
    ----------
    predictor, dynamics, reference, sampling, d_c, margin, limits, costs
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    fallback, substeps, random_state
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`.
    continuous : bool
        Check the whole of every plan step (True) or its end points (False, default: as
        published).
    envelope : FunctionalEnvelope, optional
        Envelopes calibrated offline (None: calibrated online from the episode's past).
    calibration : FieldCalibration, optional
        The calibration's settings (default ``FieldCalibration()``, the published ones).
    constraint : FieldConstraint, optional
        Hard or soft, and its settings (default ``FieldConstraint()``: hard).
    **grouped
        As for :class:`~conformal_control.families.mpc.controller.SamplingMPC`
        (``<group>__<field>``,
        e.g. ``constraint__mode="soft"``).
    """

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
        continuous: bool = False,
        substeps: int = 4,
        random_state: int = 0,
        envelope: FunctionalEnvelope | None = None,
        calibration: FieldCalibration | None = None,
        constraint: FieldConstraint | None = None,
        **grouped: Any,
    ) -> None:
        self.envelope = envelope
        self.calibration = FieldCalibration() if calibration is None else calibration
        self.constraint = FieldConstraint() if constraint is None else constraint
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
            **grouped,
        )

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        base = super()._unit_test_params()[0]
        sampling = base["sampling"].replace(dt_plan=0.4, horizon=4)
        online = FieldCalibration(grid_size=16, min_pairs=4, refit_every=2, n_mixtures=2)
        return [
            {**base, "sampling": sampling, "calibration": online},
            {
                **base,
                "sampling": sampling,
                "calibration": online,
                "constraint": FieldConstraint(mode="soft", outside=0.5),
            },
        ]

    # ------------------------------------------------------------------ episode
    def _validate(self) -> None:
        super()._validate()
        cal, con = self.calibration, self.constraint
        if not isinstance(cal, FieldCalibration):
            raise ValueError(f"calibration must be a FieldCalibration, got {cal!r}")
        if not isinstance(con, FieldConstraint):
            raise ValueError(f"constraint must be a FieldConstraint, got {con!r}")
        check_calibration(
            cal.miscoverage, cal.n_components, cal.n_mixtures, cal.calibration_share, cal.slack
        )
        for name in ("grid_size", "window", "min_pairs", "refit_every", "n_anchors"):
            group = con if name == "n_anchors" else cal
            v = getattr(group, name)
            low = 4 if name == "min_pairs" else (2 if name == "grid_size" else 1)
            if isinstance(v, bool) or int(v) != v or v < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")
        for name, w in (("grid_margin", cal.grid_margin), ("w_safety", con.w_safety)):
            if not (math.isfinite(w) and w >= 0.0):
                raise ValueError(f"{name} must be a finite number >= 0, got {w!r}")
        if not math.isfinite(con.outside):
            raise ValueError(f"outside must be a finite distance, got {con.outside!r}")
        if con.mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {con.mode!r}")
        env = self.envelope
        if env is not None and not isinstance(env, FunctionalEnvelope):
            raise ValueError(f"envelope must be a FunctionalEnvelope or None, got {env!r}")

    def reset(self) -> None:
        super().reset()
        self._m = 0  # sampling periods per plan step (set at the first interval)
        h = int(self.sampling.horizon)
        self._past: deque[dict[str, Any]] = deque(maxlen=h * 64 + 2)
        self._pairs: list[deque[tuple[np.ndarray, np.ndarray]]] = [
            deque(maxlen=int(self.calibration.window)) for _ in range(h)
        ]
        self.envelope_: FunctionalEnvelope | None = self.envelope
        self._grid: FieldGrid | None = None if self.envelope is None else self.envelope.grid
        self._set_anchors()
        self._since_fit = 0
        self._first_seen = np.zeros((0, 2))
        self._scored = (np.zeros(0, dtype=np.int64), np.zeros(0))
        self._penalty: np.ndarray | None = None
        self.n_fits_ = 0
        self.n_fields_scored_ = 0

    def _set_anchors(self) -> None:
        """The grid points a realised field is scored at, and where they are (m)."""
        if self._grid is None:
            self._anchors, self._anchor_xy = np.zeros(0, dtype=np.int64), np.zeros((0, 2))
        else:
            self._anchors = self._grid.anchors(int(self.constraint.n_anchors))
            self._anchor_xy = self._grid.points(self._anchors)

    def stats(self) -> dict[str, float]:
        return {
            **super().stats(),
            "n_envelope_fits": self.n_fits_,
            "n_fields_scored": self.n_fields_scored_,
        }

    # ------------------------------------------------------------------ sampling time
    def _steps_per_plan_step(self, observation: PredictionQuery) -> int:
        tau = float(observation.horizon) * float(observation.dt)
        m = self.sampling.dt_plan / tau
        if abs(m - round(m)) > 1e-6 or round(m) < 1:
            raise ValueError(
                f"fcp_mpc needs plan steps of whole sampling periods: dt_plan = "
                f"{self.sampling.dt_plan:g} s, sampling period {tau:g} s"
            )
        return round(m)

    def begin_interval(self, observation: PredictionQuery) -> None:
        m = self._steps_per_plan_step(observation)
        if self._m and m != self._m:
            raise ValueError("the sampling period changed during the episode")
        self._m = m
        super().begin_interval(observation)
        h = int(self.sampling.horizon)
        ids = np.asarray(self._ids).astype(np.int64)
        cur = np.asarray(observation.current, dtype=float)[: ids.size]
        if self._first_seen.shape[0] == 0 and cur.shape[0]:
            self._first_seen = cur.copy()
        pred = (
            self.predicted_at(self.sampling.dt_plan * np.arange(1, h + 1))
            if ids.size
            else np.zeros((0, h, 2))
        )
        self._past.append({"ids": ids, "cur": cur, "pred": pred})
        steps, pred_m, obs_m = self._matured_rows()
        self._scored = self._score_rows(steps, pred_m, obs_m)
        if self.envelope is None:
            for k, pair in _split_pairs(steps, pred_m, obs_m):
                self._pairs[k - 1].append(pair)
            self._since_fit += 1
            self._maybe_fit()

    def _matured_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The pairs of every plan step whose prediction is for now, one row per pedestrian
        predicted then and observed now: ``(step (P,), predicted (P, 2), observed (P, 2))``,
        by step, then in the order of the prediction's pedestrians (an id observed twice: its
        first row). All steps in one lookup (it was one per step: ~12 x 8 numpy calls per
        interval; the same rows)."""
        past, now = self._past, self._past[-1]
        none = (np.zeros(0, dtype=np.int64), np.zeros((0, 2)), np.zeros((0, 2)))
        order = np.argsort(now["ids"], kind="stable")
        sorted_ids = now["ids"][order]
        if not sorted_ids.size:
            return none
        hs = [h for h in range(1, int(self.sampling.horizon) + 1) if h * self._m < len(past)]
        made = [past[-1 - h * self._m] for h in hs]
        if not made:
            return none
        ids = np.concatenate([e["ids"] for e in made])
        if not ids.size:
            return none
        k = np.minimum(np.searchsorted(sorted_ids, ids), sorted_ids.size - 1)
        rows = np.flatnonzero(sorted_ids[k] == ids)
        pred = np.concatenate([e["pred"][:, h - 1] for e, h in zip(made, hs, strict=True)])
        step = np.repeat(np.array(hs, dtype=np.int64), [e["ids"].size for e in made])
        return step[rows], pred[rows], now["cur"][order[k[rows]]]

    def _score_rows(
        self, step: np.ndarray, pred: np.ndarray, obs: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per matured step with an envelope: the largest lambda that held its field
        (:meth:`_matured_rows`' rows, scored in one compiled call)."""
        env = self.envelope_
        if env is None or not step.size:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        has = np.array([s is not None for s in env.steps], dtype=np.bool_)
        keep = step <= has.size
        keep[keep] = has[step[keep] - 1]
        if not keep.all():
            step, pred, obs = step[keep], pred[keep], obs[keep]
        if not step.size:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        cut = np.flatnonzero(np.diff(step)) + 1
        bounds = np.concatenate([[0], cut, [step.size]]).astype(np.int64)
        steps = step[bounds[:-1]]
        needed = 1.0 - env.scales_of_rows(steps, bounds, pred, obs, self._anchors, self._anchor_xy)
        self.n_fields_scored_ += steps.size
        return steps, needed

    def _maybe_fit(self) -> None:
        cal = self.calibration
        if self._grid is None or (self._since_fit < int(cal.refit_every) and self.n_fits_):
            return
        if not any(len(p) >= int(cal.min_pairs) for p in self._pairs):
            return
        pairs = [list(p) if len(p) >= int(cal.min_pairs) else [] for p in self._pairs]
        self.envelope_ = fit_envelope(
            pairs,
            self._grid,
            cal.miscoverage,
            int(cal.n_components),
            int(cal.n_mixtures),
            cal.calibration_share,
            int(cal.random_state),
            cal.slack,
        )
        self._since_fit = 0
        self.n_fits_ += 1

    # ------------------------------------------------------------------ the knob
    def required_clearance(self, lam: float) -> np.ndarray:
        """``r_h`` (m) at plan steps 1..H: ``d_c + margin``, relaxed on later steps (see
        the module docstring)."""
        h = int(self.sampling.horizon)
        base = float(self.d_c) + float(self.margin)
        r = np.full(h, base)
        if self.constraint.relax and self._box is not None:  # a unicycle: (v, omega) box
            v_max, w_max = (float(v) for v in self._box[1])
            t = np.arange(h) * float(self.sampling.dt_plan)
            r = base - 0.5 * v_max * w_max * t**2
        out: np.ndarray = np.maximum(r, 0.0)
        return out

    def envelope_at(self, positions: np.ndarray, lam: float) -> np.ndarray:
        """U_h at the candidates' positions (m), shape (N, H), with radii scaled by ``1 -
        lambda``."""
        env, outside = self.envelope_, float(self.constraint.outside)
        if env is None:
            return np.full(positions.shape[:2], outside)
        return env.at(positions, 1.0 - float(lam), outside)

    def plan_radius(self, lam: float, positions: np.ndarray) -> np.ndarray:
        r = self.required_clearance(lam)
        if self.constraint.mode == "soft":
            return np.zeros(positions.shape[:2])
        # the envelope is read only up to the last step that constrains (r_h > 0; r_h does
        # not grow with h): the later steps are -inf whatever it is (at the published
        # settings 5 of 12 steps constrain; the same numbers)
        live = np.flatnonzero(r > 0.0)
        p = int(live[-1]) + 1 if live.size else 0
        out: np.ndarray = np.full(positions.shape[:2], -np.inf)
        if p:
            u = self.envelope_at(positions[:, :p], lam)
            out[:, :p] = np.where(r[None, :p] > 0.0, u + r[None, :p], -np.inf)
        return out

    def _update_grid(self, state: ControlState) -> None:
        if self._grid is not None:
            return
        pts = [np.asarray(state.x[:2], float)[None], np.asarray(state.goal, float)[None]]
        pts.append(self._first_seen.reshape(-1, 2))
        cal = self.calibration
        self._grid = FieldGrid.around(
            np.concatenate(pts), margin=float(cal.grid_margin), size=int(cal.grid_size)
        )
        self._set_anchors()
        self._maybe_fit()

    def plan_begin(self, state: ControlState, lam: float) -> PlanInputs:
        if self.envelope is None:
            self._update_grid(state)
        todo = super().plan_begin(state, lam)
        self._penalty = None
        if self.constraint.mode == "soft" and self._ids.size:
            pred = todo.problem[3]
            d_nom = step_distances(todo.positions, pred)
            d_lower = np.maximum(d_nom - self.envelope_at(todo.positions, lam), 0.0)
            short = np.maximum(self.required_clearance(lam)[None, :] - d_lower, 0.0)
            self._penalty = float(self.constraint.w_safety) * (short**2).sum(axis=1)
        return todo

    def plan_end(
        self, todo: PlanInputs, cost: np.ndarray, clear: np.ndarray, viol: np.ndarray
    ) -> Plan:
        if self._penalty is not None:
            cost = cost + self._penalty
            self._penalty = None
        return super().plan_end(todo, cost, clear, viol)

    def interval_record(self) -> FCPMPCIntervalRecord:
        base = super().interval_record()
        fields = {k: getattr(base, k) for k in base.__dataclass_fields__}
        steps, needed = self._scored
        return FCPMPCIntervalRecord(**fields, field_step=steps.copy(), field_needed=needed.copy())


def _split_pairs(
    step: np.ndarray, pred: np.ndarray, obs: np.ndarray
) -> list[tuple[int, tuple[np.ndarray, np.ndarray]]]:
    """Rows of :meth:`FCPMPC._matured_rows` as ``(h, (predicted, observed))`` per step."""
    cut = np.flatnonzero(np.diff(step)) + 1
    return [
        (int(s[0]), (p, o))
        for s, p, o in zip(
            np.split(step, cut), np.split(pred, cut), np.split(obs, cut), strict=True
        )
        if s.size
    ]


class FieldMiscoverageLoss(Loss[FCPMPCIntervalRecord, Any]):
    """Field miscoverage of fcp_mpc: the fraction of the plan steps matured at the
    interval's start whose realised residual field exceeded the envelope at an anchor, at
    the interval's lambda (see :mod:`conformal_control.families.mpc.fcp`). In [0, 1], non-decreasing
    in lambda; target: the rule's epsilon (published 0.1). Nothing scored: no loss. The
    truth argument is not used (the fields were scored from the sensor's observations)."""

    bounds = (0.0, 1.0)

    def __init__(self) -> None:
        pass

    @classmethod
    def _unit_test_inputs(cls) -> list[tuple[FCPMPCIntervalRecord, Any]]:
        """Three steps held up to different lambdas; one held at any lambda; none scored."""

        def record(needed: list[float]) -> FCPMPCIntervalRecord:
            return FCPMPCIntervalRecord(
                ids=np.arange(1),
                x_ego=np.zeros((1, 2)),
                v_ego=np.zeros((1, 2)),
                x_pred=np.zeros((1, 1, 2)),
                v_pred=np.zeros((1, 1, 2)),
                lam_applied=np.zeros(1),
                status=["optimal"],
                field_step=np.arange(1, len(needed) + 1, dtype=np.int64),
                field_needed=np.array(needed, dtype=float),
            )

        return [
            (record([-0.5, 0.05, 0.6]), None),
            (record([math.inf]), None),
            (record([]), None),
        ]

    def __call__(self, record: FCPMPCIntervalRecord, truth: Any, lam: float) -> float | None:
        lam = check_lambda(lam)
        needed = np.asarray(record.field_needed, dtype=float)
        return float((lam > needed).mean()) if needed.size else None
