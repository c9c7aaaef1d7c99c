"""Algorithm 1: the conformal CBF-based safe controller (a decision family)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from ...core.base import CompiledForm, DecisionFamily, Environment, first_test_instance
from ...core.spec import parameter_info
from ...data.synthetic import crossing_scene
from ...predictors.base import Forecast, PredictionQuery, Predictor
from .barriers import APFBarrier, APFForm
from .constraint import ConformalConstraint
from .dynamics import VelocityTrackingDoubleIntegrator
from .feasibility import robot_speed_bound, row_floors
from .filters.base import VelocityFilter
from .filters.exact2d import Exact2DSafetyFilter
from .interp import forward_fill, interpolate_at_substeps
from .kernels2d import RECORD_FIELDS
from .reciprocal import (
    FLOOR_CORE,
    FLOOR_LOOKAHEAD_S,
    FLOOR_ROW,
    PEDESTRIAN_ROW,
    ROBOT_ROW,
    YIELD_HOLD_S,
    Reciprocity,
    calm_ahead_pairs,
    calm_pairs,
    check_peer_view,
    floor_rows,
    lexicographic_search,
    pair_directions,
    parked_shares,
    peer_rows,
    priority_relax,
    reference_velocities,
    robot_escape,
    sidestep,
)
from .records import CBFIntervalRecord, CBFTruth, ControlState
from .reference import AttractiveField
from .roles import EscapeRows, FilterResult, ReferenceController, SafetyFilter

__all__ = [
    "CBFIntervalForm",
    "CBFIntervalRecord",
    "ConformalCBFController",
    "ControlState",
    "CrossingTestbed",
    "PeerStepForm",
    "PredictorError",
    "merge_forecast_info",
]

#: Messages kept per key in ``forecast_info_`` (the rest are counted, not stored).
MAX_MESSAGES = 50

#: Status recorded for the result codes of the compiled step (``kernels2d``); code 2 (an
#: infeasible step the Python fallback decided) records the fallback's own name; code 7 is
#: the lexicographic search that had to relax the hard rows too (``kernels_peers``), code
#: 8 the edge rule deciding alone (``kernels2d.ESCAPED``).
_CODE_STATUS = (
    "unconstrained",
    "optimal",
    "",
    "lambda_search",
    "lambda_search",
    "",
    "",
    "lambda_search",
    "escape",
)


class PredictorError(RuntimeError):
    """The predictor raised; the message names the predictor, scene, frame and agents."""


def merge_forecast_info(total: dict[str, Any], info: dict[str, Any]) -> None:
    """Accumulate a forecast's ``info`` into ``total``: numbers are summed, messages
    (strings or lists of strings) concatenated (the first :data:`MAX_MESSAGES` kept,
    the others counted under ``<key>_dropped``)."""
    for key, value in info.items():
        if isinstance(value, bool):
            total[key] = total.get(key, 0) + int(value)
        elif isinstance(value, (int, float, np.integer, np.floating)):
            total[key] = total.get(key, 0) + (value.item() if hasattr(value, "item") else value)
        elif isinstance(value, (str, list, tuple)):
            items = [value] if isinstance(value, str) else [str(v) for v in value]
            kept = total.setdefault(key, [])
            room = max(MAX_MESSAGES - len(kept), 0)
            kept.extend(items[:room])
            if len(items) > room:
                total[f"{key}_dropped"] = total.get(f"{key}_dropped", 0) + len(items) - room


@dataclass(frozen=True)
class CBFIntervalForm(CompiledForm):
    """What the compiled engine reads of a conformal CBF controller at a sampling time,
    after its ``begin_interval``: the agents' predictions interpolated at the interval's
    control instants (views, valid until the next ``begin_interval``).

    Attributes
    ----------
    xp, vp : ndarray
        Predicted positions and velocities, ``(instants, agents, 2)`` (m, m/s).
    """

    kernel = "cbf"
    xp: np.ndarray
    vp: np.ndarray


@dataclass(frozen=True)
class PeerStepForm:
    """What a lockstep engine of fleets reads of a conformal CBF controller at a sampling
    time, after its ``begin_interval``, to call the compiled step with robot rows
    (:func:`~conformal_control.families.cbf.kernels_peers.apf_control_peers`) itself, as
    :meth:`ConformalCBFController.decide` calls it (views of the controller's own arrays:
    valid until its next ``begin_interval`` or until a decision it makes itself grows
    them).

    Attributes
    ----------
    pv, col, buf, rec : ndarray
        The kernel's ``pv``, ``col``, ``buf`` and ``rec``.
    turn, floor : ndarray
        The kernel's ``turn`` and ``floor``.
    peer_ids : ndarray
        The peers' ids, in the order of ``pv``'s peer columns.
    npred : int
        The predicted agents (``pv``'s first columns).
    n : int
        The record's next row.
    k_att, v_max : float
        The attractive field's gain and speed limit (the nominal velocity).
    """

    pv: np.ndarray
    col: np.ndarray
    buf: np.ndarray
    rec: np.ndarray
    turn: np.ndarray
    floor: np.ndarray
    peer_ids: np.ndarray
    npred: int
    n: int
    k_att: float
    v_max: float


class ConformalCBFController(
    DecisionFamily[PredictionQuery, ControlState, np.ndarray, CBFIntervalRecord],
    compiled="cbf",
    run_values={
        "predictor": "predictor",
        "constraint": "constraint",
        "safety_filter": "safety_filter",
        "reference": "reference",
        "substeps": "substeps",
    },
):
    """Conformal CBF controller (Huriot & Sibai, Algorithm 1).

    At each sampling time it asks its predictor for the sensed agents' trajectories over
    the interval; at each control instant t it reads their predicted position and
    velocity at t, builds one conformal constraint per agent::

        dh/dx_ego . v + dh/dx_agent . v_pred + a h(x_ego, x_pred) + lambda >= 0

    (:class:`~conformal_control.families.cbf.constraint.ConformalConstraint`) and asks the safety
    filter for the velocity closest to the reference that satisfies them. Smaller lambda
    is more conservative.

    Predictions are sanitised here, with counters: a forecast of the wrong shape is an
    error; non-finite predicted samples are replaced by the last finite sample before them
    (the agent is held still from there; ``n_nonfinite_predictions_`` counts affected
    agent-intervals). A predictor that raises stops the run with a :class:`PredictorError`
    naming the predictor, the scene, the frame and the number of agents.

    With the APF barrier and the exact 2-D filter (fallback ``lambda_search``, ``brake`` or
    ``hold``) each control step is one compiled call fusing barrier, rows, feasibility check,
    projection, lambda search and the interval's record
    (:meth:`Exact2DSafetyFilter.step_apf_record`); it returns what the generic path
    (``constraint.rows`` then ``safety_filter.solve``) returns, to round-off. The
    :class:`~conformal_control.families.cbf.reference.AttractiveField` reference is then evaluated
    on Python floats (:meth:`~conformal_control.families.cbf.reference.AttractiveField.velocity`,
    the
    same bits), and the decision is a row of the interval's record (a fresh array every
    interval; ``interval_record`` returns copies). Every other combination takes the generic path.

    Parameters
    ----------
    predictor : Predictor
        Black-box trajectory predictor, called at every sampling time.
    constraint : ConformalConstraint
        The barrier h and the slope a of alpha(h) = a h (the loss must use the same one).
    safety_filter : SafetyFilter
        Solves for the safe velocity.
    reference : ReferenceController
        Nominal controller (called with the environment's current goal).
    substeps : int
        Control instants per prediction sample.
    reciprocity : Reciprocity, optional
        How the agents the sensor reports as robots are treated, and which rows lambda is
        the slack of (:mod:`~conformal_control.families.cbf.reciprocal`). None (default) treats
        every agent alike, as a predicted pedestrian with ``+ lambda``.

    Notes
    -----
    With ``reciprocity`` in ``"reciprocal"`` mode, the robots of a query are not handed
    to the predictor: at each control instant ``state.peers`` (the world's
    :class:`~conformal_control.families.cbf.reciprocal.PeerView` of the robots sensed at the
    sampling time) gives their rows. In ``"ignore"`` mode they get no row (a robot that
    does not comply). The compiled step handles these rows too
    (:meth:`Exact2DSafetyFilter.step_apf_record_peers`).
    """

    def __init__(
        self,
        predictor: Predictor,
        constraint: ConformalConstraint,
        safety_filter: SafetyFilter,
        reference: ReferenceController,
        substeps: int = 4,
        reciprocity: Reciprocity | None = None,
    ) -> None:
        self.predictor = predictor
        self.constraint = constraint
        self.safety_filter = safety_filter
        self.reference = reference
        self.substeps = substeps
        self.reciprocity = reciprocity

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        from ...predictors.constant_velocity import ConstantVelocityPredictor
        from .barriers import APFBarrier
        from .filters.piqp import QPSafetyFilter
        from .reference import AttractiveField

        barrier = APFBarrier(K_rep=0.5, rho0=5.0, d_c=0.7)
        return [
            {
                "predictor": ConstantVelocityPredictor(),
                "constraint": ConformalConstraint(barrier, a=2.0),
                "safety_filter": QPSafetyFilter(),
                "reference": AttractiveField(K_att=1.0),
                "substeps": 2,
            }
        ]

    @classmethod
    def _unit_test_environment(cls) -> CrossingTestbed:
        return CrossingTestbed()

    def reset(self) -> None:
        self.constraint.validate()
        top = int(parameter_info("substeps").high)
        if int(self.substeps) != self.substeps or not 1 <= self.substeps <= top:
            raise ValueError(f"substeps must be an integer from 1 to {top}, got {self.substeps!r}")
        if self.reciprocity is not None:
            if not isinstance(self.reciprocity, Reciprocity):
                raise ValueError(
                    f"reciprocity must be a Reciprocity or None, got {self.reciprocity!r}"
                )
            self.reciprocity.validate()
            self._robot_constraint = self.reciprocity.robot_constraint(self.constraint)
            self._turn = self.reciprocity.turn()
            self._robot_dc = float(self._robot_constraint.barrier.get_params().get("d_c", 0.0))
            # the floor rows of the compiled step: the robots' d_c and the floor margin
            self._floor = np.array([self._robot_dc, float(self.reciprocity.floor_margin)])
        self.predictor.reset()
        self.safety_filter.reset()
        self.reference.reset()
        self.n_nonfinite_predictions_ = 0
        self.n_steps_ = 0
        # compiled-path steps left to the generic path (priority stages, edge rule with
        # robots); not a statistic of the run (the decisions are the generic path's)
        self.n_generic_steps_ = 0
        self._yield_until = -math.inf  # broadcast that it yields until then (s)
        self._stage = ""  # the stage priority_relax gave way at, last time
        self._t_now = 0.0
        self._fused = self._fused_apf()
        self._pv = np.zeros((2, 0, 0, 2))
        self.forecast_info_: dict[str, Any] = {}
        self._begin_empty()

    def _fused_apf(self) -> bool:
        """Whether decide() takes the compiled APF step (configured here) or the generic path."""
        me = type(self)
        if not (
            me.constraint_rows is ConformalCBFController.constraint_rows
            and me.slack is ConformalCBFController.slack
            and self._apf_parts()
        ):
            return False
        c = self.constraint
        form = c.barrier.compiled_state()
        assert isinstance(form, APFForm)  # an APFBarrier (_apf_parts)
        self.safety_filter.configure_apf(  # type: ignore[attr-defined]
            (form.K_rep, form.rho0, form.d_c, form.delta, form.surface),
            float(c.a),
            c.edge_settings(),
        )
        return True

    def _apf_parts(self) -> bool:
        """Whether the parts are those the compiled step computes: the APF barrier in a
        conformal constraint, the exact 2-D filter with its compiled step. A fallback the
        step does not decide itself (e.g. ``relax``) decides in Python on the compiled
        rows (:meth:`Exact2DSafetyFilter.step_apf_record`), except with robots (their hard
        and reciprocal rows are built by the generic path for such a fallback). With the
        robot rows giving way first (priority ``"pedestrians"``) the compiled step decides
        the plain steps and leaves the others (the priority stages, the edge rule with
        robots) to the generic path, step by step (``n_generic_steps_`` counts them)."""
        f, c = self.safety_filter, self.constraint
        rec = self.reciprocity
        return (
            type(c) is ConformalConstraint
            and type(c.barrier) is APFBarrier
            and isinstance(f, Exact2DSafetyFilter)
            and (f.fused or (f.compiled_step is True and rec is None))
        )

    def stats(self) -> dict[str, float]:
        return {
            "n_steps": self.n_steps_,
            "n_nonfinite_predictions": self.n_nonfinite_predictions_,
            **self.safety_filter.stats(),
        }

    def _begin_empty(self) -> None:
        self._ids = np.zeros(0, dtype=np.int64)  # the predicted agents (rows of _xp)
        self._query_ids = self._ids  # every sensed agent, in the query's order
        self._xp = np.zeros((0, 0, 2))
        self._vp = np.zeros((0, 0, 2))
        # multi-robot: peers (reciprocal rows), ignored robots, per-column weights
        self._typed = False
        self._peer_ids = self._ids
        self._ignored_x = np.zeros((0, 2))
        self._ignored_ids = self._ids
        # per column (predicted, peers): share of a h, 1 without lambda, distance added
        self._col = np.zeros((3, 0))
        self._scored = np.zeros(0, dtype=bool)  # per record column (ignored robots too)
        self._order: np.ndarray | None = None  # record columns -> query order
        self._special = False  # the compiled step with robot rows or hard rows
        self._valid_ids: np.ndarray | None = None  # the peer view's ids, once checked
        self._rec_px: list[np.ndarray] = []
        self._rec_pv: list[np.ndarray] = []
        self._rec_x: list[np.ndarray] = []
        self._rec_v: list[np.ndarray] = []
        self._rec_lam: list[float] = []
        self._rec_status: list[str] = []
        # the compiled step's interval: it records into _rec itself (see _record)
        self._fast = False
        self._n = 0
        # lambda per agent: the array last given, its smallest entry and the rows' offsets
        self._lam_src: np.ndarray | None = None
        self._lam_ref = 0.0
        self._lam_off = np.zeros(0)

    def _record(self, rows: int) -> None:
        """A fresh record for the compiled step (``kernels2d.apf_control``'s layout) of
        ``rows`` control instants, keeping the first ``_n`` rows of the current one.

        Fresh at every interval: decisions are returned as views of it, so one returned
        earlier is never overwritten.
        """
        n = self._n
        old = (self._rx[:n], self._rv[:n], self._rl[:n], self._rc[:n]) if n else ()
        if not n:
            self._names: dict[int, str] = {}
        self._rec = np.zeros(RECORD_FIELDS * rows)
        self._rows = rows
        self._views()
        for dst, src in zip((self._rx, self._rv, self._rl, self._rc), old, strict=False):
            dst[:n] = src

    def _views(self) -> None:
        """The record's blocks as views of ``_rec``: ego positions, decisions, lambda
        applied, result codes."""
        rec, rows = self._rec, self._rows
        self._rx: np.ndarray = rec[: 2 * rows].reshape(rows, 2)
        self._rv: np.ndarray = rec[2 * rows : 4 * rows].reshape(rows, 2)
        self._rl: np.ndarray = rec[4 * rows : 5 * rows]
        self._rc: np.ndarray = rec[5 * rows :]

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        for name in ("_rx", "_rv", "_rl", "_rc"):  # views of _rec, rebuilt
            state.pop(name, None)
        if state.get("_fast"):  # views of _pv
            state.pop("_xp", None)
            state.pop("_vp", None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        if "_rec" in state:
            self._views()
        if state.get("_fast"):
            n = self._ids.size
            self._xp, self._vp = self._pv[0, :, :n], self._pv[1, :, :n]

    # ------------------------------------------------------------------ sampling time
    def _predict(self, observation: PredictionQuery) -> Forecast:
        try:
            return self.predictor.predict(observation)
        except Exception as exc:
            raise PredictorError(
                f"predictor {type(self.predictor).__name__} failed on scene "
                f"{observation.scene or '?'} at frame {observation.frame} "
                f"(t = {observation.t:.2f} s, {observation.n_agents} sensed agents): "
                f"{type(exc).__name__}: {exc}"
            ) from exc

    def _split_robots(self, observation: PredictionQuery) -> PredictionQuery:
        """The agents to predict; robots apart as the reciprocity says (sets the columns'
        shares, slack and scoring)."""
        rec = self.reciprocity
        self._query_ids = np.asarray(observation.ids)
        if rec is None:
            return observation
        self._typed = True
        robot = observation.is_robot
        predicted = ~robot if rec.mode != "none" else np.ones(robot.size, dtype=bool)
        peers = robot if rec.mode == "reciprocal" else np.zeros(robot.size, dtype=bool)
        ignored = robot if rec.mode == "ignore" else np.zeros(robot.size, dtype=bool)
        self._peer_ids = self._query_ids[peers]
        self._ignored_ids = self._query_ids[ignored]
        self._ignored_x = np.array(observation.current[ignored], dtype=float).reshape(-1, 2)
        # record columns: predicted agents, peers, ignored robots (query order restored)
        cols = np.concatenate([np.flatnonzero(c) for c in (predicted, peers, ignored)])
        if not np.array_equal(cols, np.arange(cols.size)):
            self._order = np.argsort(cols, kind="stable")
        on_ped, on_rob = rec.lambda_on_pedestrians, rec.lambda_on_robots
        slack_on = np.where(robot, on_rob, on_ped)
        used = np.concatenate([np.flatnonzero(predicted), np.flatnonzero(peers)])
        col = np.zeros((3, used.size))
        col[0] = 1.0  # the peers' shares come with their view
        col[1] = ~slack_on[used]
        col[2, np.flatnonzero(peers[used])] = float(rec.robot_margin)
        self._col = col
        scored = slack_on & ~ignored
        self._scored = scored[cols]
        return observation if predicted.all() else observation.select(predicted)

    def begin_interval(self, observation: PredictionQuery) -> None:
        self._begin_empty()
        query = self._split_robots(observation)
        n = query.n_agents
        self._ids = np.asarray(query.ids)
        horizon = observation.horizon
        n_steps = horizon * int(self.substeps)
        k = self._peer_ids.size
        if n == 0 and k == 0:
            return
        if n:
            prediction = self._predict(query)
            merge_forecast_info(self.forecast_info_, prediction.info)
            pos = np.asarray(prediction.positions, dtype=float)
            if pos.ndim != 3 or pos.shape[0] != n or pos.shape[1] < horizon or pos.shape[2] != 2:
                raise ValueError(
                    f"predictor returned positions of shape {pos.shape}; expected "
                    f"({n}, >= {horizon}, 2) for {n} sensed agents and horizon {horizon}"
                )
            samples = np.concatenate([query.current[:, None, :], pos[:, :horizon]], axis=1)
            samples, had_bad = forward_fill(samples)
            self.n_nonfinite_predictions_ += int(had_bad.sum())
            xp, vp = interpolate_at_substeps(samples, query.dt, int(self.substeps), n_steps)
        else:
            xp = vp = np.zeros((n_steps, 0, 2))
        if not self._fused:
            self._xp, self._vp = xp, vp
            return
        # positions and velocities in one C-ordered array for the compiled step; the
        # peers' columns (after the predicted ones) are written at each control instant
        self._pv = pv = np.zeros((2, n_steps, n + k, 2))
        pv[0, :, :n] = xp
        pv[1, :, :n] = vp
        self._xp, self._vp = pv[0, :, :n], pv[1, :, :n]
        self._special = bool(k or self._col[1].any())
        if self._special and self.constraint.barrier.convention != "surface":  # type: ignore[attr-defined]
            if self._col[2].any():  # the compiled rows add distance on the disc gap only
                self._xp, self._vp = xp, vp
                return
        self._fast = True
        self._attract = (
            type(self.reference) is AttractiveField
            and type(self.reference.K_att) in (float, int)
            and type(self.reference.v_max) in (float, int)
        )
        self._record(max(n_steps, 1))

    # ------------------------------------------------------------------ control instant
    def _peer_view(self, state: ControlState) -> Any:
        view = state.peers
        if view is not None and view.ids is self._valid_ids:  # checked this interval
            return view
        view = check_peer_view(view, self._peer_ids)
        self._valid_ids = view.ids
        return view

    def constraint_rows(self, state: ControlState, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """The safety filter's rows ``A v + b + slack >= 0`` at this control instant.

        The family's hook for families built from the same parts that move the knob
        elsewhere (e.g. :class:`~conformal_control.families.cbf.acp.ACPController` inflates the
        agents with ``lam``); here ``lam`` does not enter the rows.
        """
        if not self._ids.size:
            return np.zeros((0, 2)), np.zeros(0)
        return self.constraint.rows(state.x[:2], self._xp[state.step], self._vp[state.step])

    def slack(self, lam: float) -> float:
        """The slack handed to the safety filter for ``lam``: ``lam`` itself (Algorithm 1)."""
        return lam

    def lambda_keys(self) -> np.ndarray | None:
        """The interval's sensed agents (``record.ids``, the query's order): lambda run per
        agent gives row j its own slack lambda_j. None for a subclass that moves the knob
        elsewhere (``constraint_rows`` or ``slack`` overridden, e.g. ACP's regions)."""
        me = type(self)
        if (
            me.constraint_rows is not ConformalCBFController.constraint_rows
            or me.slack is not ConformalCBFController.slack
        ):
            return None
        return self._query_ids

    def lambda_floors(self) -> np.ndarray | None:
        """Each sensed agent's own feasibility floor over the interval just decided
        (:func:`~conformal_control.families.cbf.feasibility.row_floors` on
        :meth:`interval_record`, with the radius of the safety filter's speed set), in
        :meth:`lambda_keys`' order; None when :meth:`lambda_keys` is None or the filter
        declares no ``v_max``."""
        if self.lambda_keys() is None:
            return None
        v_max = getattr(self.safety_filter, "v_max", None)
        if not isinstance(v_max, (int, float)):
            return None
        sides = int(getattr(self.safety_filter, "speed_sides", 16))
        return row_floors(self.constraint, self.interval_record(), robot_speed_bound(v_max, sides))

    def _per_agent(self, lam: np.ndarray) -> tuple[float, np.ndarray]:
        """lambda per agent as (the smallest entry, each row's offset above it): row j's
        slack is ``lam_j = ref + off_j``; the filter and its fallbacks see the scalar
        ``ref`` (the lambda search raises every row alike). Exactly 0 offset for the
        smallest entry, so one agent is the scalar path bit for bit."""
        if lam is self._lam_src:
            return self._lam_ref, self._lam_off
        if self._typed:
            raise ValueError("lambda per agent is not supported with several robots")
        if lam.shape != self._query_ids.shape:
            raise ValueError(
                f"lambda per agent has shape {lam.shape}; the interval has "
                f"{self._query_ids.size} agents (lambda_keys())"
            )
        ref = float(lam.min()) if lam.size else 0.0
        self._lam_src, self._lam_ref = lam, ref
        self._lam_off = np.ascontiguousarray(lam - ref, dtype=np.float64)
        return ref, self._lam_off

    def decide(self, state: ControlState, lam: float) -> np.ndarray:
        self._t_now = float(state.t)
        off: np.ndarray | None = None
        if isinstance(lam, np.ndarray):  # lambda per agent: one entry per lambda_keys()
            lam, off = self._per_agent(lam)
        if self._fast:
            return self._decide_compiled(state, lam, off)
        res = self._decide_generic(state, lam, off)
        self._rec_x.append(state.x[:2].copy())
        self._rec_v.append(res.decision)
        self._rec_lam.append(res.lambda_applied)
        self._rec_status.append(res.status if res.fallback is None else res.fallback)
        self.n_steps_ += 1
        return res.decision

    def _decide_generic(
        self, state: ControlState, lam: float, off: np.ndarray | None
    ) -> FilterResult:
        """The decision of the generic path (rows built in Python, the filter's ``solve``),
        not recorded."""
        x_ego = state.x[:2]
        v_ref = self.reference(state.x, state.t, state.goal)
        if self._peer_ids.size and self._turn[1]:
            v_ref = sidestep(v_ref, state.x, self._peer_view(state), self._turn, self._robot_dc)
        res: FilterResult
        if self._fused and self._ids.size and not self._special:
            res = self.safety_filter.step_apf(  # type: ignore[attr-defined]
                x_ego, self._xp[state.step], self._vp[state.step], v_ref, lam, off
            )
        else:
            A, b = self.constraint_rows(state, lam)
            if off is not None and b.size:
                b = b + off
            escape = self.escape_rows(state)
            ttc = self.contact_times(state, A.shape[0], v_ref)
            if self._typed:
                n = A.shape[0]
                A, b = self._with_robots(state, lam, A, b)
                ttc = np.r_[ttc, np.full(A.shape[0] - ttc.size, math.inf)]  # (peers: none)
                if self._peer_ids.size and self._turn[6]:
                    escape = self._robot_escape(state, n, escape)
            res = self._solve(v_ref, A, b, self.slack(lam), escape, ttc)
            if res.status == "fallback" and self._peer_ids.size:
                self._yield_until = state.t + YIELD_HOLD_S
        return res

    def yielding(self) -> bool:
        """Whether this robot says it yields to the other robots: its reciprocity's
        ``coordination="yield"``, and a decision with robot rows within the last
        :data:`~conformal_control.families.cbf.reciprocal.YIELD_HOLD_S` seconds fell back (not every
        row could be met; :mod:`~conformal_control.families.cbf.reciprocal`)."""
        rec = self.reciprocity
        return bool(
            rec is not None and rec.coordination == "yield" and self._t_now < self._yield_until
        )

    def escape_rows(self, state: ControlState) -> EscapeRows | None:
        """The edge rule's rows at this control instant: the predicted agents already
        within the collision distance (:meth:`ConformalConstraint.escape
        <conformal_control.families.cbf.constraint.ConformalConstraint.escape>`), or None."""
        if not self._ids.size:
            return None
        s = state.step
        return self.constraint.escape(state.x[:2], self._xp[s], self._vp[s])

    def _robot_escape(
        self, state: ControlState, n: int, escape: EscapeRows | None
    ) -> EscapeRows | None:
        """``escape`` with the peers already within the robots' collision distance added
        (people first: :func:`~conformal_control.families.cbf.reciprocal.robot_escape`), their
        barrier and floor rows (``n`` predicted rows before them) neutralised with them;
        ``escape`` itself when no command of the speed set closes in on none of them and
        the pedestrians inside (the pedestrians' edge rule first)."""
        con = self.constraint
        if con.edge_distance() is None:
            return escape  # the edge rule is off
        view = parked_shares(self._peer_view(state))
        margin = float(self.reciprocity.floor_margin)  # type: ignore[union-attr]
        # with a pedestrian inside, the edge rule may decide alone (without the floor
        # rows): the peers inside the floor cores join it, not only those inside d_c
        within = self._robot_dc + (0.0 if escape is None else FLOOR_CORE * margin)
        peers, U, c, push = robot_escape(
            state.x[:2], view, self._robot_dc, float(con.escape_gain), margin, within
        )
        if not peers.size:
            return escape
        f = self.safety_filter
        if escape is not None and hasattr(f, "min_lambda"):
            # people first, then the robots: when no command closes in on none of the
            # agents inside, the pedestrians coming at the robot are fled only as fast as
            # leaves a command toward neither them nor the robots (relaxed_approach)
            star, _ = f.min_lambda(np.r_[escape.U, U], np.r_[escape.c, c])
            if float(star) > 0.0:
                return escape
        k = view.n_peers
        rows = np.r_[n + peers, n + k + peers]
        if escape is None:
            return EscapeRows(rows, U, c, push)
        return EscapeRows(
            np.r_[escape.rows, rows],
            np.r_[escape.U, U],
            np.r_[escape.c, c],
            np.r_[escape.push, push],
        )

    def contact_times(self, state: ControlState, n: int, v_ref: np.ndarray) -> np.ndarray:
        """The predicted times to contact (s) of the ``n`` predicted agents' rows at this
        control instant, the robot moving at its nominal velocity ``v_ref``
        (:meth:`ConformalConstraint.contact_times
        <conformal_control.families.cbf.constraint.ConformalConstraint.contact_times>`), for a
        fallback that orders the rows by them.

        Parameters
        ----------
        state : ControlState
            The control instant.
        n : int
            The number of predicted agents' rows.
        v_ref : ndarray of shape (2,)
            The nominal velocity (m/s).
        """
        if not n or not self._ids.size:
            return np.full(n, math.inf)
        s = state.step
        return self.constraint.contact_times(state.x[:2], self._xp[s], self._vp[s], v_ref)

    def _solve(
        self,
        v_ref: np.ndarray,
        A: np.ndarray,
        b: np.ndarray,
        slack: float,
        escape: EscapeRows | None,
        ttc: np.ndarray | None = None,
    ) -> FilterResult:
        """The safety filter's decision on the rows, with the edge rule (``escape``) and,
        with robots, the lambda search that keeps the rows without slack, or (priority
        ``"pedestrians"``) that gives way with the robot rows first."""
        f = self.safety_filter
        first = bool(self._typed and self._peer_ids.size and self._turn[6])
        hard = first or (self._typed and bool(self._col[1].any()))
        if escape is None or not hard or not isinstance(f, VelocityFilter):
            res = f.solve_escaping(v_ref, A, b, slack, escape, ttc)
            if res.fallback == "lambda_search" and hard:
                res = self._keep_hard_rows(v_ref, A, b, slack, res, first)
            return res
        A, b = escape.neutralise(A, b, slack)
        counted = (f.n_infeasible_, f.n_fallback_, dict(f.fallback_counts_))
        with f.contact(ttc), f.escaping(v_ref, escape) as escaped:
            if escaped is not None:
                return escaped
            res = f.solve(v_ref, A, b, slack)
            if res.fallback != "lambda_search":
                return res
            fell = res
            res = self._keep_hard_rows(v_ref, A, b, slack, res, first, tally=not first)
        if not first:
            return res
        # people first, and a pair must not collide: when the robots' cores gave way
        # within the escape polygon, they come before the edge rule's push (a wish to move
        # out of the discs at a speed), never before its rule that no command closes in
        # on an agent inside its collision distance (non-closing rows kept)
        if self._stage == "robot_cores" and escape.push.any():
            calm = EscapeRows(escape.rows, escape.U, escape.c, np.zeros_like(escape.push))
            with f.contact(ttc), f.escaping(v_ref, calm) as escaped:
                if escaped is not None:
                    # the edge rule decides alone: its decision replaces the first one,
                    # whose infeasible step and fallback are not counted a second time
                    n_inf, n_fb, by_name = counted
                    f.n_infeasible_, f.n_fallback_ = n_inf + 1, n_fb + 1
                    f.fallback_counts_ = {**by_name, "escape": by_name.get("escape", 0) + 1}
                    return escaped
                f.count("escape_push_yielded")
                res = self._keep_hard_rows(v_ref, A, b, slack, fell, first, tally=False)
        if self._stage:
            f.count(f"{self._stage[:-1]}_rows_relaxed")
        return res

    def _with_robots(
        self, state: ControlState, lam: float, A: np.ndarray, b: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The predicted rows, hard where lambda is not their slack, and the peers' rows."""
        n = A.shape[0]
        hard = self._col[1] != 0.0
        sl = self.slack(lam)
        if hard[:n].any():
            b = np.where(hard[:n], b - sl, b)
        if not self._peer_ids.size:
            return A, b
        view = parked_shares(self._peer_view(state))
        self._col[0, n:] = view.shares
        Ar, br = peer_rows(self._robot_constraint, state.x[:2], view)
        if hard[n:].any():
            br = np.where(hard[n:], br - sl, br)
        if self._turn[6]:  # priority pedestrians: the robots' floor rows (no slack)
            a = float(self._robot_constraint.a)
            margin = float(self.reciprocity.floor_margin)  # type: ignore[union-attr]
            Af, bf = floor_rows(state.x[:2], view, self._robot_dc, a, margin)
            Ar, br = np.concatenate([Ar, Af]), np.concatenate([br, bf - sl])
            # the floor rows' margin bands (what may give way before their cores)
            band = (1.0 - FLOOR_CORE) * margin
            self._band = np.asarray(view.shares, dtype=float) * a * band
            # the floor rows whose cores hold before the pedestrians' rows give way
            which = self.reciprocity.floor_core  # type: ignore[union-attr]
            if which == "inside":
                self._cored = pair_directions(state.x[:2], view)[1] < self._robot_dc
            elif which == "calm":  # no pedestrian inside its collision distance of either
                peds = self._xp[state.step] if self._ids.size else np.zeros((0, 2))
                d_p = self.constraint.contact_distance()
                self._cored = calm_pairs(state.x[:2], view.positions, peds, d_p)
            elif which == "ahead":  # nor any predicted inside within the look-ahead
                s = state.step
                peds = self._xp[s] if self._ids.size else np.zeros((0, 2))
                vel = self._vp[s] if self._ids.size else np.zeros((0, 2))
                d_p = self.constraint.contact_distance()
                calm = calm_ahead_pairs(
                    state.x[:2], view.positions, peds, vel, d_p, FLOOR_LOOKAHEAD_S,
                    view.own_reference, view.reference,
                )  # fmt: skip
                # a pair within the floor distance keeps its core whatever is ahead:
                # released there, the pedestrians' rows squeeze it into contact
                near = pair_directions(state.x[:2], view)[1] < self._robot_dc + margin
                self._cored = calm | near
            else:
                self._cored = np.full(view.n_peers, which == "always")
        self._rec_px.append(np.array(view.positions, dtype=float))
        self._rec_pv.append(reference_velocities(view))
        return np.concatenate([A, Ar]), np.concatenate([b, br])

    def _keep_hard_rows(
        self,
        v_ref: np.ndarray,
        A: np.ndarray,
        b: np.ndarray,
        lam: float,
        res: FilterResult,
        first: bool = False,
        tally: bool = True,
    ) -> FilterResult:
        """The lambda search again, keeping the rows without slack
        (:func:`~conformal_control.families.cbf.reciprocal.lexicographic_search`), or with ``first``
        giving way with the robot rows first, row by row
        (:func:`~conformal_control.families.cbf.reciprocal.priority_relax`; ``tally``: count the
        stage it gave way at)."""
        f = self.safety_filter
        self._stage = ""
        if not all(hasattr(f, k) for k in ("project", "min_lambda", "search_margin", "v_max")):
            return res  # a filter without the primitives: its own search stands
        if first:  # rows: predicted agents, robots' barrier rows, their floor rows
            n, k = self._ids.size, self._peer_ids.size
            kind = np.full(A.shape[0], FLOOR_ROW)
            kind[:n] = PEDESTRIAN_ROW
            kind[n : n + k] = ROBOT_ROW
            band = np.zeros(A.shape[0])
            band[n + k :] = self._band
            cored = np.ones(A.shape[0], dtype=bool)
            cored[n + k :] = self._cored
            v, used, gave_way = priority_relax(f, v_ref, A, b, kind, lam, band, cored)
            self._stage = gave_way
            if gave_way and tally:
                f.count(f"{gave_way[:-1]}_rows_relaxed")  # type: ignore[attr-defined]
            return FilterResult(v, "fallback", used, "lambda_search")
        keep = self._turn[5] != 0.0
        v, used, relaxed = lexicographic_search(f, v_ref, A, b, self._col[1] != 0.0, lam, keep)
        if relaxed:
            f.count("hard_rows_relaxed")  # type: ignore[attr-defined]
        return FilterResult(v, "fallback", used, "lambda_search")

    def _decide_compiled(
        self, state: ControlState, lam: float, off: np.ndarray | None = None
    ) -> np.ndarray:
        """:meth:`decide` through the compiled step, which writes the record itself
        (``off``: the rows' offsets of lambda run per agent)."""
        i = self._n
        if i == self._rows:
            self._record(2 * i)
        x = state.x.tolist()
        x0 = x[0]
        x1 = x[1]
        if self._attract:
            g = state.goal.tolist()
            n0, n1 = self.reference.velocity(x0, x1, g[0], g[1])  # type: ignore[attr-defined]
        else:
            v_ref = self.reference(state.x, state.t, state.goal)
            n0 = float(v_ref[0])
            n1 = float(v_ref[1])
        res: FilterResult | None
        if self._special:
            got = self._compiled_with_robots(state, x0, x1, n0, n1, lam, i)
            if got is False:  # a step only the generic path decides (priority stages)
                self.n_generic_steps_ += 1
                res = self._decide_generic(state, lam, off)
                self._rx[i] = (x0, x1)
                self._rc[i] = 2  # its name in _names
            else:
                res = None if got is None else cast(FilterResult, got)
                if self._peer_ids.size and (self._rc[i] > 1 or res is not None):  # fell back
                    self._yield_until = state.t + YIELD_HOLD_S
        else:
            res = self.safety_filter.step_apf_record(  # type: ignore[attr-defined]
                x0, x1, n0, n1, lam, self._pv, state.step, self._rec, i, off
            )
        self._n = i + 1
        self.n_steps_ += 1
        if res is None:
            return self._rv[i]  # type: ignore[no-any-return]
        # a fallback decided in Python (brake, hold)
        self._rv[i] = res.decision
        self._rl[i] = res.lambda_applied
        self._names[i] = res.status if res.fallback is None else res.fallback
        return res.decision

    def peer_step_form(self) -> PeerStepForm | None:
        """The arrays of the open interval's compiled step with robot rows, or None when
        this interval's decisions do not all go through it as :meth:`decide` would take
        them (not the plain controller and exact 2-D filter, no robot rows, another
        reference than the attractive field, robots that say they yield). A lockstep
        engine that decides a step with them counts it with :meth:`add_compiled_steps`;
        a step the kernel does not decide alone (any code but unconstrained or optimal) is
        left to :meth:`decide`."""
        rec = self.reciprocity
        if not (
            type(self) is ConformalCBFController
            and type(self.safety_filter) is Exact2DSafetyFilter
            and self._fast
            and self._special
            and self._attract
            and rec is not None
            and rec.coordination == "none"
        ):
            return None
        ref = cast(AttractiveField, self.reference)
        return PeerStepForm(
            self._pv,
            self._col,
            self.safety_filter.step_buffer(),
            self._rec,
            self._turn,
            self._floor,
            self._peer_ids,
            int(self._ids.size),
            self._n,
            float(ref.K_att),
            float(ref.v_max),
        )

    def add_compiled_steps(self, steps: int, solves: int, t: float) -> None:
        """Count ``steps`` decisions a lockstep engine made on :meth:`peer_step_form`'s
        arrays (recorded from the form's row ``n`` on, each unconstrained or optimal;
        ``solves`` of them optimal; the last one at time ``t``, s), as :meth:`decide`
        counts its own.

        Parameters
        ----------
        steps : int
            Decisions made.
        solves : int
            The optimal ones among them.
        t : float
            Time of the last one (s).
        """
        if steps:
            self._n += int(steps)
            self.n_steps_ += int(steps)
            self._t_now = float(t)
            cast(Exact2DSafetyFilter, self.safety_filter).add_compiled_steps(solves)

    def _compiled_with_robots(
        self, state: ControlState, x0: float, x1: float, n0: float, n1: float, lam: float, i: int
    ) -> FilterResult | bool | None:
        """The compiled step with the peers' rows and hard rows (one compiled call); False
        for a step it leaves to the generic path (nothing recorded or counted)."""
        k = self._peer_ids.size
        n = self._ids.size
        if k:
            view = parked_shares(self._peer_view(state))
            self._col[0, n:] = view.shares
            pos = view.positions
            ref = view.reference
            own = view.own_reference
            if ref is None or own is None:
                ref, o0, o1 = np.zeros((k, 2)), 0.0, 0.0
            else:
                o0, o1 = float(own[0]), float(own[1])
        else:
            pos = ref = np.zeros((0, 2))
            o0 = o1 = 0.0
        return self.safety_filter.step_apf_record_peers(  # type: ignore[attr-defined, no-any-return]
            x0, x1, n0, n1, lam, self._pv, state.step, self._rec, i, (self._col, n),
            (pos, ref, o0, o1, self._turn, float(state.x[2]), float(state.x[3])),
            self._floor,
        )  # fmt: skip

    def _robot_columns(
        self, x_pred: np.ndarray, v_pred: np.ndarray, s: int
    ) -> dict[str, np.ndarray | None]:
        """The record's agent columns in the query's order (predicted, peers, ignored),
        with their shares, collision distances added and scoring."""
        if not self._typed:
            return {"x_pred": x_pred, "v_pred": v_pred}
        m = self._ignored_ids.size
        share = np.r_[self._col[0], np.ones(m)]
        margin = np.r_[self._col[2], np.zeros(m)]
        scored = self._scored
        if m:
            held = np.broadcast_to(self._ignored_x, (s, m, 2))
            x_pred = np.concatenate([x_pred, held], axis=1)
            v_pred = np.concatenate([v_pred, np.zeros((s, m, 2))], axis=1)
        if self._order is not None:
            o = self._order
            x_pred, v_pred, share, margin, scored = (
                x_pred[:, o],
                v_pred[:, o],
                share[o],
                margin[o],
                scored[o],
            )
        return {
            "x_pred": x_pred,
            "v_pred": v_pred,
            "share": share,
            "scored": scored.copy(),
            "margin": margin if margin.any() else None,
        }

    def compiled_state(self) -> CBFIntervalForm:
        """The interval's interpolated predictions (empty before the first interval)."""
        empty = np.zeros((0, 0, 2))
        return CBFIntervalForm(self.__dict__.get("_xp", empty), self.__dict__.get("_vp", empty))

    def interval_record(self) -> CBFIntervalRecord:
        if self._fast:
            s = self._n
            names = self._names
            if self._typed:
                xp, vp = self._pv[0, :s], self._pv[1, :s]
            else:
                xp, vp = self._xp[:s], self._vp[:s]
            return CBFIntervalRecord(
                ids=self._query_ids,
                x_ego=self._rx[:s].copy(),
                v_ego=self._rv[:s].copy(),
                lam_applied=self._rl[:s].copy(),
                status=[
                    names[j] if c == 2 else _CODE_STATUS[c]
                    for j, c in enumerate(self._rc[:s].astype(int).tolist())
                ],
                **self._robot_columns(xp, vp, s),  # type: ignore[arg-type]
            )
        s = len(self._rec_x)
        xp = self._xp[:s] if self._ids.size else np.zeros((s, 0, 2))
        vp = self._vp[:s] if self._ids.size else np.zeros((s, 0, 2))
        k = self._peer_ids.size
        if k:
            px = np.array(self._rec_px).reshape(-1, k, 2)
            pvel = np.array(self._rec_pv).reshape(-1, k, 2)
            if px.shape[0] != s:  # a robot decided by the fused path has no peer rows
                raise RuntimeError("peer rows were not recorded at every control instant")
            xp = np.concatenate([xp, px], axis=1)
            vp = np.concatenate([vp, pvel], axis=1)
        return CBFIntervalRecord(
            ids=self._query_ids,
            x_ego=np.array(self._rec_x).reshape(s, 2),
            v_ego=np.array(self._rec_v).reshape(s, 2),
            lam_applied=np.array(self._rec_lam, dtype=float),
            status=list(self._rec_status),
            **self._robot_columns(xp, vp, s),  # type: ignore[arg-type]
        )


class CrossingTestbed(Environment[PredictionQuery, ControlState, np.ndarray, CBFTruth]):
    """A small world for the contract checks of the controller: pedestrians of the built-in
    crossing scene replayed around a robot driven by a double integrator, sensed every
    ``tau_frames`` frames (the controller's ``_unit_test_environment()``).

    It lives beside the controller, in this module, so that the family's checks need
    nothing from a higher floor of the package and partner and family do not import each
    other; the full replay world (waypoints, frame log, time limits) is
    :class:`conformal_control.world.replay.ReplayEnvironment`.

    Parameters
    ----------
    frames : int
        Frames simulated (the episode ends after them or at the goal).
    tau_frames : int
        Frames per interval.
    substeps : int
        Control instants per frame.
    sensing_radius : float
        Sensor range (m).
    seed : int
        Seed of the crossing scene.
    """

    def __init__(
        self,
        frames: int = 24,
        tau_frames: int = 4,
        substeps: int = 2,
        sensing_radius: float = 10.0,
        seed: int = 0,
    ) -> None:
        self.frames = frames
        self.tau_frames = tau_frames
        self.substeps = substeps
        self.sensing_radius = sensing_radius
        self.seed = seed

    @classmethod
    def _unit_test_family(cls) -> ConformalCBFController:
        return first_test_instance(ConformalCBFController)

    def reset(self) -> None:
        scene = crossing_scene(seed=self.seed, duration=4.0)
        scene = scene.replace(positions=scene.positions)  # dense: read at every frame below
        self._scene = scene
        self._plant = VelocityTrackingDoubleIntegrator(K_acc=10.0)
        self._dt_frame = 1.0 / scene.fps
        self._dt = self._dt_frame / self.substeps
        self._fi = scene.start_index
        self._last = min(scene.n_frames - 1, scene.start_index + self.frames)
        self._x = np.array([*scene.start, 0.0, 0.0])
        self._t = 0.0
        self._step = 0
        self._done = False
        self._sensed = np.zeros(0, dtype=np.int64)
        self._k_start = self._fi

    @property
    def done(self) -> bool:
        return self._done

    def _window(self, lo: int, hi: int) -> np.ndarray:
        pos = self._scene.positions
        out = np.full((self._sensed.size, hi - lo, 2), np.nan)
        a, b = max(lo, 0), min(hi, pos.shape[0])
        if b > a and self._sensed.size:
            out[:, a - lo : b - lo] = pos[a:b, self._sensed].transpose(1, 0, 2)
        return out

    def sense(self) -> PredictionQuery:
        pos = self._scene.positions[self._fi]
        d = np.hypot(*(np.nan_to_num(pos, nan=np.inf) - self._x[:2]).T)
        self._sensed = np.flatnonzero(d <= self.sensing_radius)
        self._k_start, self._step = self._fi, 0
        return PredictionQuery(
            ids=self._scene.agent_ids[self._sensed],
            history=self._window(self._fi - 7, self._fi + 1),
            dt=self._dt_frame,
            horizon=self.tau_frames,
            t=self._t,
            frame=self._fi,
            scene=self._scene.name,
        )

    def control_instants(self) -> int:
        return max(min(self.tau_frames, self._last - self._fi), 0) * self.substeps

    def state(self) -> ControlState:
        goal = self._scene.goals[-1].copy()
        return ControlState(x=self._x.copy(), t=self._t, step=self._step, goal=goal)

    def apply(self, decision: np.ndarray) -> None:
        if self._done:
            raise RuntimeError("apply() called on a finished episode")
        self._x = self._plant.step(self._x, decision, self._dt)
        self._t += self._dt
        self._step += 1
        goal = self._scene.goals[-1]
        if math.hypot(*(self._x[:2] - goal)) <= self._scene.goal_radius:
            self._done = True
        if self._step % self.substeps == 0:
            self._fi += 1
            self._done = self._done or self._fi >= self._last

    def reveal(self) -> CBFTruth:
        frames = -(-self._step // self.substeps)
        samples = self._window(self._k_start, self._k_start + frames + 1)
        return CBFTruth(samples=samples, dt=self._dt_frame, substeps=self.substeps)
