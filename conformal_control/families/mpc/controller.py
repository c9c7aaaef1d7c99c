"""A sampling-based model-predictive controller as a conformal decision family (``mpc``).

At a control instant the controller

1. draws ``n_samples`` command sequences of ``horizon`` steps of ``dt_plan`` seconds in the
   plant's command space (:mod:`~conformal_control.families.mpc.sampling`), plus three seeds: the
   previous plan shifted to now (warm start), standing still / braking, and the reference
   controller's command held (velocity commands only);
2. rolls them out through the plant
(:meth:`~conformal_control.families.cbf.roles.Dynamics.rollout`);
3. keeps the **safe** ones: at every plan step h the robot stays at least the safe
   distance ``r_h(lambda)`` from every sensed agent's *predicted* position at that time
   (:mod:`~conformal_control.families.mpc.kernels`; over the whole step, not only at its end);
4. among them picks the cheapest: ``cost = w_goal sum_{h<H} |p_h - g|^2 + w_terminal
   |p_H - g|^2 + w_effort sum |u_h|^2 + w_comfort sum |u_h - u_{h-1}|^2`` (progress to the
   goal g, control effort, and an optional comfort term on command changes; the form of
   the published sampling MPCs with ``w_comfort = 0``);
5. applies the plan's first command (and, with ``replan_every > 1``, its next commands at
   the following instants without planning again).

**The knob.** ``r_h(lambda) = max(d_c + margin - lambda, 0)``: a smaller lambda keeps the
robot further from the predictions (the toolkit's sign convention), lambda = 0 asks for
the collision distance ``d_c`` plus the fixed ``margin``. Subclasses move the knob
elsewhere by overriding :meth:`SamplingMPC.safe_radius` (the ``acp_mpc`` family:
conformal regions per plan step).

**The edge rule** (``edge="escape"``, the default): when a sensed agent is already within
``d_c`` of the robot, no plan whose first step closes in on it (its predicted distance
at the first plan step below the distance now) is chosen while one that does not
exists -- neither among the safe samples nor by the fallback; when none exists, the plan
closing in slowest is. Counted as ``n_edge`` (plans made with an agent within ``d_c``).
``edge="paper"`` leaves the choice to the safe set and the fallback alone.

**lambda's ceiling.** lambda never pushes the safe distance below ``d_c``: a run's rule
gets ``lambda_max = margin`` unless it gives one (:meth:`SamplingMPC.lambda_ceiling`),
and a negative ``margin`` is refused.

**Infeasibility.** When no sample is safe the step is *infeasible*: it is counted
(``n_infeasible``) and the ``fallback`` decides, also counted (``n_fallback_<name>``):

* ``"brake"`` (default; what the published ETH/UCY protocol does): stand still (zero
  velocity or unicycle command; for an acceleration command, the deceleration that stops
  the robot within one plan step, bounded by ``a_max``);
* ``"least_violation"``: the sample that intrudes least into the safe distances, summed
  over its steps (the cheapest among equals).

The interval's record says, per control instant, the clearance of the applied plan (its
smallest ``distance - r_h`` over steps and agents, m; ``inf`` with nobody sensed) and the
lambda it satisfies (``nan`` for a fallback). With ``status == "optimal"`` the clearance is
``>= 0``: the chosen plan meets every constraint it reports.

Predictions: at each sampling time the predictor is asked for the whole plan horizon
beyond the interval (``horizon * dt_plan`` seconds, in the scene's frames); positions at
plan times between samples are interpolated linearly, and beyond the forecast the last
sample is held. Non-finite predicted samples are replaced by the last finite one before
them (counted in ``n_nonfinite_predictions``), as the CBF family does.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from ...core.base import DecisionFamily, first_test_instance
from ...core.spec import parameter_info
from ...predictors.base import Forecast, PredictionQuery, Predictor
from ..cbf.controller import CBFIntervalRecord, ControlState, PredictorError, merge_forecast_info
from ..cbf.interp import forward_fill, interpolate_at_substeps
from ..cbf.reciprocal import YIELD_HOLD_S, Reciprocity
from ..cbf.roles import Dynamics, ReferenceController
from .kernels import (
    choose_safe,
    evaluate,
    plan_choice,
    plan_predictions,
    positions_of,
    predicted_at,
    substep_states,
)
from .peers import has_peer_terms, peer_terms, split_robots, with_robot_columns
from .sampling import sample_sequences
from .settings import Costs, Limits, Sampling, check_groups

__all__ = ["FALLBACKS", "MPCIntervalRecord", "Plan", "PlanInputs", "SamplingMPC"]

#: The fallbacks a sampling MPC knows (see the module docstring).
FALLBACKS = ("brake", "least_violation")


@dataclass
class MPCIntervalRecord(CBFIntervalRecord):
    """The CBF record of an interval (ego positions, velocities, the sensed agents'
    interpolated predictions at the control instants, lambda applied, status) plus what
    the MPC planned.

    Attributes
    ----------
    command : ndarray of shape (S, 2)
        The command applied at each control instant (the plant's command: a velocity,
        an acceleration or ``(v, omega)``).
    clearance : ndarray of shape (S,)
        Clearance of the applied plan at the lambda it was planned with (m; ``inf`` with
        nobody sensed).
    n_safe : ndarray of shape (S,)
        Safe samples when the plan was made (-1 at instants that replayed a plan).
    """

    command: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    clearance: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_safe: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


@dataclass
class PlanInputs:
    """What :meth:`SamplingMPC.plan_begin` prepared: the state and lambda planned for, the
    candidates (commands (N, H, 2), positions (N, H, 2)) and ``problem``, the arguments of
    :func:`~conformal_control.families.mpc.kernels.evaluate` for them."""

    state: Any
    lam: float
    commands: np.ndarray
    positions: np.ndarray
    problem: tuple[Any, ...]
    #: ``(pred, ex, ey, sx, sy)``: the evaluation's rows of the predictions ``pred``
    #: (:func:`~conformal_control.families.mpc.kernels.plan_predictions`), or None.
    rows: tuple[np.ndarray, ...] | None = None

    def agent_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The ``rows`` of :func:`~conformal_control.families.mpc.kernels.evaluate` for
        ``problem`` when they were made with it (its predictions the same object), else
        None (evaluate makes them)."""
        rows = self.rows
        if rows is None or rows[0] is not self.problem[3]:
            return None
        return rows[1], rows[2], rows[3], rows[4]


_IN_ONE_CALL: dict[type, bool] = {}


def _plans_in_one_call(cls: type) -> bool:
    """Whether ``cls`` plans with :meth:`SamplingMPC.plan_begin`, :meth:`SamplingMPC.plan_end`
    and the shared safe distance and edge rule of :class:`SamplingMPC` (none overridden):
    then :meth:`SamplingMPC.plan` may run them as one compiled call."""
    known = _IN_ONE_CALL.get(cls)
    if known is None:
        known = _IN_ONE_CALL[cls] = all(
            getattr(cls, name) is getattr(SamplingMPC, name)
            for name in ("plan_begin", "plan_end", "plan_radius", "safe_radius", "edge_closing")
        )
    return known


#: No agent's predictions (the edge rule's arguments when it cannot apply).
_NO_PRED = np.zeros((0, 1, 2))


@dataclass
class Plan:
    """One planning step's outcome (:meth:`SamplingMPC.plan`).

    Attributes
    ----------
    commands : ndarray of shape (H, 2)
        The chosen command sequence.
    positions : ndarray of shape (H, 2)
        Its planned positions at plan steps 1..H (m).
    clearance : float
        Its clearance (m) against the safe distances it was planned with.
    cost : float
    status : str
        ``"optimal"`` (the cheapest safe sample), ``"unconstrained"`` (nobody sensed:
        the cheapest sample), ``"peer_yield"`` (no sample meets every robot peer's line
        too: the one keeping the pedestrians' safe distances that intrudes least over the
        lines, :mod:`~conformal_control.families.mpc.peers`) or the fallback's name.
    n_safe : int
        Number of safe samples.
    """

    commands: np.ndarray
    positions: np.ndarray
    clearance: float
    cost: float
    status: str
    n_safe: int


class SamplingMPC(
    DecisionFamily[PredictionQuery, ControlState, np.ndarray, MPCIntervalRecord],
    # the loss of a run that gives none (the CDT conformal controller's); lambda is a length
    # (how much closer than d_c + margin the robot may come); the rule's target, step and
    # floor when a run gives none (the scene's are the CBF's): a distance shortfall of 0.1
    # on average, lambda moving by at most 0.2 m per update and never asking for more than
    # 1 m beyond d_c + margin (against wind-up)
    default_loss="distance_shortfall",
    lambda_unit="m",
    default_rule_params={"epsilon": 0.1, "eta": 0.2, "lambda_min": -1.0},
    run_values={
        "predictor": "predictor",
        "dynamics": "dynamics",
        "reference": "reference",
        "d_c": "collision_distance",
        "margin": "barrier_margin",
        "limits__v_max": "v_max",
        "substeps": "substeps",
        "random_state": "seed",
    },
):
    """Sampling-based MPC whose safe distance to the predicted agents is set by lambda.

    See the module docstring for the algorithm, the knob and the fallbacks. Every length
    is in metres, every time in seconds.

    Parameters
    ----------
    predictor : Predictor
        Trajectory predictor, asked at every sampling time for the plan's horizon.
    dynamics : Dynamics
        The plant model plans are rolled out with (the robot's own plant in a run).
    reference : ReferenceController, optional
        Seeds one sample with its command held (velocity commands only).
    sampling : Sampling, optional
        How plans are drawn: ``n_samples``, ``horizon``, ``dt_plan`` (s), ``hold``,
        ``replan_every``; default ``Sampling()`` (500 samples, 12 steps of 0.4 s, each
        random command held 2 steps, a plan at every control instant).
    d_c : float
        Collision distance between centres (m, >= 0): robot radius + agent radius.
    margin : float
        Fixed extra safe distance (m, >= 0); also lambda's default ceiling.
    limits : Limits, optional
        ``v_max`` (m/s) and ``a_max`` (m/s^2), the bounds of the sampled commands;
        default ``Limits()`` (1 m/s, 2 m/s^2).
    costs : Costs, optional
        The cost weights ``w_goal``, ``w_terminal``, ``w_effort``, ``w_comfort``;
        default ``Costs()`` (1, 10, 0.001, 0).
    fallback : {"brake", "least_violation"}
        What is applied when no sample is safe.
    continuous : bool
        Check the safe distance over the whole of every plan step, robot and agents
        moving linearly within it (True), or at the steps' end points only (False, as
        the published sampling MPCs do); see :mod:`~conformal_control.families.mpc.kernels`.
    substeps : int
        Control instants per prediction sample (for the interval's record).
    random_state : int
        Seed of the sampler (reset at every episode).
    edge : {"escape", "paper"}
        The edge rule (see the module docstring).
    **grouped
        A group's field as ``<group>__<field>`` (``costs__w_goal=2.0``: the registry's
        ``(name, params)`` form); the former flat keywords (``n_samples=``, ``w_goal=``,
        ``v_max=``, ...) are still accepted with a ``DeprecationWarning``.
    """

    #: Names of the seeded samples, in order (reported by :meth:`plan`'s tests).
    SEEDS: ClassVar[tuple[str, ...]] = ("warm_start", "stop", "reference")

    #: The former flat keywords, now fields of ``sampling``, ``limits`` and ``costs``.
    renamed_params: ClassVar[dict[str, str]] = {
        **{k: f"sampling__{k}" for k in ("n_samples", "horizon", "dt_plan", "hold")},
        "replan_every": "sampling__replan_every",
        **{k: f"limits__{k}" for k in ("v_max", "a_max")},
        **{k: f"costs__{k}" for k in ("w_goal", "w_terminal", "w_effort", "w_comfort")},
    }

    #: How the robots the sensor reports are treated (set by a multi-robot run,
    #: :func:`~conformal_control.runs.fleet.set_reciprocity`): reciprocal robots are kept on
    #: their side of shared lines (:mod:`~conformal_control.families.mpc.peers`); None predicts
    #: every agent alike.
    reciprocity: Reciprocity | None = None

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
        edge: str = "escape",
        **grouped: Any,
    ) -> None:
        self.predictor = predictor
        self.dynamics = dynamics
        self.reference = reference
        self.sampling = Sampling() if sampling is None else sampling
        self.d_c = d_c
        self.margin = margin
        self.limits = Limits() if limits is None else limits
        self.costs = Costs() if costs is None else costs
        self.fallback = fallback
        self.continuous = continuous
        self.substeps = substeps
        self.random_state = random_state
        self.edge = edge
        self._set_grouped(grouped)

    # ------------------------------------------------------------------ contract kit
    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        from ...predictors.constant_velocity import ConstantVelocityPredictor
        from ..cbf.dynamics import VelocityTrackingDoubleIntegrator
        from ..cbf.reference import AttractiveField

        return [
            {
                "predictor": ConstantVelocityPredictor(),
                "dynamics": VelocityTrackingDoubleIntegrator(K_acc=10.0),
                "reference": AttractiveField(K_att=1.0),
                "sampling": Sampling(n_samples=40, horizon=6, dt_plan=0.3),
                "limits": Limits(v_max=1.5),
                "substeps": 2,
            },
            {
                "predictor": ConstantVelocityPredictor(),
                "dynamics": VelocityTrackingDoubleIntegrator(K_acc=10.0),
                "sampling": Sampling(n_samples=25, horizon=4, dt_plan=0.5, hold=1, replan_every=3),
                "fallback": "least_violation",
                "costs": Costs(w_comfort=0.1),
                "substeps": 2,
            },
        ]

    @classmethod
    def _unit_test_environment(cls) -> Any:
        from ...world.replay import ReplayEnvironment

        return first_test_instance(ReplayEnvironment)

    # ------------------------------------------------------------------ episode
    def _validate(self) -> None:
        check_groups(self.sampling, self.costs, self.limits)
        v, top = self.substeps, int(parameter_info("substeps").high)
        if isinstance(v, bool) or int(v) != v or not 1 <= v <= top:
            raise ValueError(f"substeps must be an integer from 1 to {top}, got {v!r}")
        if not (math.isfinite(self.d_c) and self.d_c >= 0):
            raise ValueError(f"d_c must be a finite distance >= 0, got {self.d_c!r}")
        if not (math.isfinite(self.margin) and self.margin >= 0):
            raise ValueError(
                f"margin must be a finite distance >= 0 (a negative one puts the safe "
                f"distance inside the collision distance d_c), got {self.margin!r}"
            )
        if self.edge not in ("escape", "paper"):
            raise ValueError(f"edge must be 'escape' or 'paper', got {self.edge!r}")
        if self.fallback not in FALLBACKS:
            raise ValueError(
                f"fallback must be one of {', '.join(FALLBACKS)}, got {self.fallback!r}"
            )

    def reset(self) -> None:
        self._validate()
        self.predictor.reset()
        if self.reference is not None:
            self.reference.reset()
        kind = self.dynamics.command_kind
        self._box = self.dynamics.command_limits() if kind == "unicycle" else None
        if kind == "unicycle" and self._box is None:
            raise ValueError(
                f"{type(self.dynamics).__name__} takes unicycle commands but has no limits"
            )
        self._rng = np.random.default_rng(self.random_state)
        self.n_steps_ = 0
        self.n_plans_ = 0
        self.n_infeasible_ = 0
        self.n_edge_ = 0
        self.n_fallback_: dict[str, int] = dict.fromkeys(FALLBACKS, 0)
        self.n_peer_yield_ = 0
        self._yield_until = -math.inf
        self._t_now = 0.0
        self.n_nonfinite_predictions_ = 0
        self.forecast_info_: dict[str, Any] = {}
        self._warm: np.ndarray | None = None  # last plan's commands
        self._next_plan: Plan | None = None  # made for the next decide (use_plan)
        self._warm_t = 0.0
        self._last_cmd = np.zeros(2)
        self._begin_empty(0.0)

    def stats(self) -> dict[str, float]:
        return {
            "n_steps": self.n_steps_,
            "n_plans": self.n_plans_,
            "n_infeasible": self.n_infeasible_,
            "n_edge": self.n_edge_,
            "n_fallback": sum(self.n_fallback_.values()),
            **{f"n_fallback_{k}": v for k, v in self.n_fallback_.items()},
            "n_peer_yield": self.n_peer_yield_,
            "n_nonfinite_predictions": self.n_nonfinite_predictions_,
        }

    def _begin_empty(self, t: float) -> None:
        self._t0 = t
        self._dt = 1.0
        self._ids = np.zeros(0, dtype=np.int64)
        self._samples = np.zeros((0, 1, 2))  # (M, F + 1, 2) from the sampling time
        self._xp = np.zeros((0, 0, 2))
        self._vp = np.zeros((0, 0, 2))
        self._plan: Plan | None = None
        self._plan_t = 0.0
        self._since = 0
        self._aoff: np.ndarray | None = None  # lambda per agent: safe-distance offsets
        self._rec: dict[str, list[Any]] = {k: [] for k in ("lam", "status", "clear", "safe")}
        # the ego's position, velocity and command at each control instant, written in
        # place (columns x, y, vx, vy, cmd x, cmd y; rows _n_rec; grown when full)
        self._rows = np.empty((64, 6))
        self._n_rec = 0

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

    def forecast_frames(self, observation: PredictionQuery) -> int:
        """Samples asked of the predictor: the interval plus the plan's horizon."""
        ahead = math.ceil(self.sampling.horizon * self.sampling.dt_plan / observation.dt - 1e-9)
        return int(observation.horizon) + max(ahead, 1)

    def begin_interval(self, observation: PredictionQuery) -> None:
        observation, self._robots = split_robots(self.reciprocity, observation)
        self._begin_empty(observation.t)
        self._dt = float(observation.dt)
        self._ids = np.asarray(observation.ids)
        n = observation.n_agents
        if n == 0:
            return
        frames = self.forecast_frames(observation)
        query = dataclasses.replace(observation, horizon=frames)
        forecast = self._predict(query)
        merge_forecast_info(self.forecast_info_, forecast.info)
        pos = np.asarray(forecast.positions, dtype=float)
        if pos.ndim != 3 or pos.shape[0] != n or pos.shape[1] < frames or pos.shape[2] != 2:
            raise ValueError(
                f"predictor returned positions of shape {pos.shape}; expected "
                f"({n}, >= {frames}, 2) for {n} sensed agents and horizon {frames}"
            )
        samples = np.concatenate([observation.current[:, None, :], pos[:, :frames]], axis=1)
        if not np.isfinite(samples).all():  # (all finite: forward_fill changes nothing)
            samples, had_bad = forward_fill(samples)
            self.n_nonfinite_predictions_ += int(had_bad.sum())
        self._samples = np.ascontiguousarray(samples, dtype=np.float64)
        steps, sub = int(observation.horizon) * int(self.substeps), int(self.substeps)
        if steps > (samples.shape[1] - 1) * sub or self._samples.shape[0] == 0:
            self._xp, self._vp = interpolate_at_substeps(samples, self._dt, sub, steps)
        else:  # compiled, the same numbers (kernels.substep_states)
            self._xp, self._vp = substep_states(self._samples, self._dt, sub, steps)

    def predicted_at(self, offsets: np.ndarray) -> np.ndarray:
        """Predicted positions of the sensed agents at ``offsets`` seconds after the
        sampling time, shape (M, len(offsets), 2) (linear between samples, the samples'
        own values at sample times, the last sample held beyond the forecast)."""
        out: np.ndarray = predicted_at(
            np.ascontiguousarray(self._samples, dtype=np.float64),
            float(self._dt),
            np.ascontiguousarray(offsets, dtype=np.float64).ravel(),
        )
        return out

    # ------------------------------------------------------------------ the knob
    @classmethod
    def lambda_ceiling(cls, margin: float) -> float:
        """lambda's default ceiling for a run with this ``margin`` (m): ``margin``, so the
        safe distance ``d_c + margin - lambda`` never falls below ``d_c``. A family whose
        lambda is not a length taken off the safe distance (its ``lambda_unit`` is not
        ``"m"``) returns ``inf`` (its own ``default_rule_params`` may bound it).

        Parameters
        ----------
        margin : float
            The family's fixed extra safe distance (m).
        """
        return float(margin) if cls.capabilities.lambda_unit == "m" else math.inf

    def safe_radius(self, lam: float) -> np.ndarray:
        """Safe centre distance at each plan step (m), shape (H,): ``max(d_c + margin -
        lambda, 0)``. Subclasses move the knob here."""
        r = max(float(self.d_c) + float(self.margin) - float(lam), 0.0)
        return np.full(int(self.sampling.horizon), r)

    def lambda_keys(self) -> np.ndarray | None:
        """The interval's predicted agents (``record.ids``): lambda run per agent gives
        agent j the safe distance ``max(d_c + margin - lambda_j, 0)``. None for a family
        that moves the knob elsewhere (``safe_radius`` or ``plan_radius`` overridden)."""
        me = type(self)
        if (
            me.safe_radius is not SamplingMPC.safe_radius
            or me.plan_radius is not SamplingMPC.plan_radius
        ):
            return None
        return self._ids

    def _per_agent(self, lam: Any) -> float:
        """lambda as one number for the shared radius: an array per agent becomes its
        smallest entry (the largest safe distance), each agent's safe distance kept as an
        offset from it (exactly 0 for that entry: one agent is the scalar path)."""
        if not isinstance(lam, np.ndarray):
            self._aoff = None
            return float(lam)
        if getattr(self, "_robots", None) is not None:
            raise ValueError("lambda per agent is not supported with several robots")
        if lam.shape != self._ids.shape:
            raise ValueError(
                f"lambda per agent has shape {lam.shape}; the interval has "
                f"{self._ids.size} agents (lambda_keys())"
            )
        ref = float(lam.min()) if lam.size else 0.0
        base = float(self.d_c) + float(self.margin)
        self._aoff = np.maximum(base - lam, 0.0) - max(base - ref, 0.0)
        return ref

    def plan_radius(self, lam: float, positions: np.ndarray) -> np.ndarray:
        """Safe distance per plan and step (m), shape (N, H) or (H,): :meth:`safe_radius`
        shared by every plan (a family whose regions depend on where the robot would be
        overrides this)."""
        return self.safe_radius(lam)

    # ------------------------------------------------------------------ planning
    def _seeds(self, state: ControlState, t_off: float) -> list[np.ndarray]:
        """Warm start, stop, reference: each a (H, 2) sequence, or one (2,) command held
        over the plan."""
        h = int(self.sampling.horizon)
        out = []
        if self._warm is not None:
            shift = min(round((state.t - self._warm_t) / self.sampling.dt_plan), h)
            warm = np.empty((h, 2))  # the last plan shifted, its last command held
            warm[: h - shift] = self._warm[shift:]
            warm[h - shift :] = self._warm[-1]
            out.append(warm)
        out.append(self._stop_command(state))
        kind = self.dynamics.command_kind
        if self.reference is not None and kind == "velocity":
            v = np.asarray(self.reference(state.x, state.t, state.goal), dtype=float)
            speed = math.hypot(v[0], v[1])
            if speed > self.limits.v_max:
                v = v * (self.limits.v_max / speed)
            out.append(v)
        return out

    def _stop_command(self, state: ControlState) -> np.ndarray:
        if self.dynamics.command_kind != "acceleration":
            return np.zeros(2)
        a = -np.asarray(self.dynamics.velocity(state.x), dtype=float) / self.sampling.dt_plan
        norm = math.hypot(a[0], a[1])
        return a * (self.limits.a_max / norm) if norm > self.limits.a_max else a

    def sample_commands(self, state: ControlState, t_off: float) -> np.ndarray:
        """The candidate command sequences, shape (N + seeds, H, 2): the seeds first."""
        seeds = self._seeds(state, t_off)
        radius = (
            self.limits.a_max if self.dynamics.command_kind == "acceleration" else self.limits.v_max
        )
        k, n, h = len(seeds), int(self.sampling.n_samples), int(self.sampling.horizon)
        out = np.empty((k + n, h, 2))
        for i, seed in enumerate(seeds):
            out[i] = seed  # a (2,) command is held over the plan
        sample_sequences(
            self._rng,
            n,
            h,
            int(self.sampling.hold),
            box=self._box,
            radius=float(radius),
            out=out[k:],
        )
        return out

    def plan(self, state: ControlState, lam: float) -> Plan:
        """Sample, roll out, check and choose (one planning step; counts included)."""
        if _plans_in_one_call(type(self)):
            ref = self._per_agent(lam)
            if self._aoff is None and not has_peer_terms(self, state):
                return self._plan_compiled(state, ref)
        todo = self.plan_begin(state, lam)  # lambda as given: a vector keeps its offsets
        return self.plan_end(todo, *evaluate(*todo.problem, rows=todo.agent_rows()))

    def _plan_compiled(self, state: ControlState, lam: float) -> Plan:
        """:meth:`plan_begin`, :func:`evaluate` and :meth:`plan_end` for one safe distance
        shared by every plan and agent and no peers' lines: the candidates sampled and
        rolled out as :meth:`plan_begin` does, the rest in one compiled call
        (:func:`~conformal_control.families.mpc.kernels.plan_choice`: the kernels those
        steps call, on the arguments they form; the same numbers), then the same counts
        and fallbacks."""
        goal = np.asarray(state.goal, dtype=float)
        if goal.shape != (2,) or not (math.isfinite(goal[0]) and math.isfinite(goal[1])):
            raise ValueError(f"the goal must be a finite (x, y) in metres, got {state.goal!r}")
        t_off = float(state.t - self._t0)
        cmds = self.sample_commands(state, t_off)
        dt_plan = float(self.sampling.dt_plan)
        states = self.dynamics.rollout(state.x, cmds, dt_plan)
        c = self.costs
        i, n_safe, applied, pos, cost, clear, viol, allowed = plan_choice(
            np.asarray(states, dtype=np.float64),
            np.ascontiguousarray(cmds, dtype=np.float64),
            np.ascontiguousarray(state.x, dtype=np.float64),
            self._samples,
            float(self._dt),
            t_off,
            dt_plan,
            max(float(self.d_c) + float(self.margin) - float(lam), 0.0),  # safe_radius's
            np.ascontiguousarray(goal, dtype=np.float64),
            np.array([c.w_goal, c.w_terminal, c.w_effort, c.w_comfort], dtype=np.float64),
            np.ascontiguousarray(self._last_cmd, dtype=np.float64),
            bool(self.continuous),
            float(self.d_c),
            self.edge == "escape" and bool(self._ids.size),
        )
        self._candidates = pos  # the plan's candidate positions (N, H, 2), for subclasses
        if applied:
            self.n_edge_ += 1
        return self._conclude(
            state, cmds, pos, cost, clear, viol, int(i), int(n_safe), allowed if applied else None
        )

    def plan_begin(self, state: ControlState, lam: float) -> PlanInputs:
        """The first half of :meth:`plan`: the candidates sampled and rolled out, and the
        arguments of their evaluation (:func:`~conformal_control.families.mpc.kernels.evaluate`),
        which a batch of episodes evaluates in one call
        (:func:`~conformal_control.families.mpc.kernels.evaluate_many`) before :meth:`plan_end`."""
        lam = self._per_agent(lam)
        goal = np.asarray(state.goal, dtype=float)
        if goal.shape != (2,) or not (math.isfinite(goal[0]) and math.isfinite(goal[1])):
            raise ValueError(f"the goal must be a finite (x, y) in metres, got {state.goal!r}")
        t_off = float(state.t - self._t0)
        cmds = self.sample_commands(state, t_off)
        states = self.dynamics.rollout(state.x, cmds, float(self.sampling.dt_plan))
        pos = positions_of(np.asarray(states, dtype=np.float64))
        self._candidates = pos  # the plan's candidate positions (N, H, 2), for subclasses
        h = int(self.sampling.horizon)
        rows = None
        if self._ids.size:
            pred, y0, *rows = plan_predictions(
                self._samples, float(self._dt), t_off, float(self.sampling.dt_plan), h
            )
            radius = self.plan_radius(lam, pos)
        else:
            pred, y0, radius = np.zeros((0, h, 2)), np.zeros((0, 2)), np.zeros(h)
        c = self.costs
        weights = (c.w_goal, c.w_terminal, c.w_effort, c.w_comfort)
        problem: tuple[Any, ...] = (
            pos,
            cmds,
            state.x[:2],
            pred,
            y0,
            radius,
            goal,
            weights,
            self._last_cmd,
            bool(self.continuous),
        )
        if self._aoff is not None and self._ids.size:
            problem = (*problem, self._aoff)
        return PlanInputs(
            state, float(lam), cmds, pos, problem, None if rows is None else (pred, *rows)
        )

    def plan_end(
        self, todo: PlanInputs, cost: np.ndarray, clear: np.ndarray, viol: np.ndarray
    ) -> Plan:
        """The second half of :meth:`plan`: the plan chosen from the candidates' cost,
        clearance and violation (counts included).

        Parameters
        ----------
        todo : PlanInputs
            What :meth:`plan_begin` prepared.
        cost, clear, viol : ndarray of shape (N,)
            :func:`~conformal_control.families.mpc.kernels.evaluate` of ``todo.problem``.

        Returns
        -------
        Plan
        """
        state, lam, cmds, pos = todo.state, todo.lam, todo.commands, todo.positions
        lines = peer_terms(self, state, lam, pos)  # robot peers' lines (mpc/peers.py)
        line_viol = np.zeros_like(viol)
        kept: np.ndarray | None = None
        if lines is not None:
            line_clear, line_viol = lines
            kept = clear >= 0.0  # the pedestrians' safe distances hold
            clear = np.minimum(clear, line_clear)
            if self.reciprocity.priority != "pedestrians":  # type: ignore[union-attr]
                # one problem: no order between the lines and the pedestrians
                viol, line_viol, lines = viol + line_viol, np.zeros_like(viol), None
        allowed: np.ndarray | None = None
        if lines is None and type(self).edge_closing is SamplingMPC.edge_closing:
            # the common case in one compiled call: the edge rule and the cheapest safe plan
            # (kernels.choose_safe: the numbers of the numpy form below)
            edge = self.edge == "escape" and bool(self._ids.size)
            x, pred, y0 = todo.problem[2:5] if edge else (np.zeros(2), _NO_PRED, _NO_PRED[:, 0])
            allowed = np.empty(cost.shape[0], dtype=np.bool_)
            i, n_safe, applied = choose_safe(
                np.asarray(cost, dtype=np.float64),
                np.asarray(clear, dtype=np.float64),
                np.asarray(pos, dtype=np.float64),
                np.asarray(x, dtype=np.float64),
                np.asarray(pred, dtype=np.float64),
                np.asarray(y0, dtype=np.float64),
                float(self.d_c),
                float(self.sampling.dt_plan),
                edge,
                allowed,
            )
            if applied:
                self.n_edge_ += 1
            else:
                allowed = None
        else:
            safe = clear >= 0.0
            closing = self.edge_closing(todo)
            if closing is not None:  # the edge rule: never close in while another plan exists
                self.n_edge_ += 1
                allowed = closing <= 1e-9
                if not allowed.any():  # none exists: the plan closing in slowest (then cheapest)
                    allowed = closing <= closing.min() + 1e-9
                safe &= allowed
                if lines is not None and kept is not None:
                    kept &= allowed
            n_safe = int(safe.sum())
            i = int(np.argmin(np.where(safe, cost, np.inf))) if n_safe else -1
        return self._conclude(
            state, cmds, pos, cost, clear, viol, i, n_safe, allowed, lines, kept, line_viol
        )

    def _conclude(
        self,
        state: ControlState,
        cmds: np.ndarray,
        pos: np.ndarray,
        cost: np.ndarray,
        clear: np.ndarray,
        viol: np.ndarray,
        i: int,
        n_safe: int,
        allowed: np.ndarray | None,
        lines: Any = None,
        kept: np.ndarray | None = None,
        line_viol: np.ndarray | None = None,
    ) -> Plan:
        """The end of :meth:`plan_end` once candidate ``i`` (-1: none safe) is chosen:
        the counts, the peers' yield and the fallbacks."""
        self.n_plans_ += 1
        if n_safe:
            status = "optimal" if self._ids.size else "unconstrained"
        elif lines is not None and kept is not None and line_viol is not None and kept.any():
            # the lines give way before the pedestrians
            self.n_peer_yield_ += 1
            self._yield_until = state.t + YIELD_HOLD_S
            i = int(np.lexsort((cost, np.where(kept, line_viol, np.inf)))[0])
            status = "peer_yield"
        else:
            self.n_infeasible_ += 1
            self.n_fallback_[self.fallback] += 1
            if lines is not None:  # squeezed: the lines are given way too
                self._yield_until = state.t + YIELD_HOLD_S
            status = self.fallback
            stop = 1 if self._warm is not None else 0  # the stop seed
            # least intrusion into the pedestrians' safe distances, then over the peers'
            # lines (priority "pedestrians"), then cheapest
            if line_viol is None:
                line_viol = np.zeros_like(viol)
            order = np.lexsort((cost, line_viol, viol))
            if self.fallback == "least_violation":
                i = int(order[0] if allowed is None else order[allowed[order]][0])
            elif allowed is None or allowed[stop]:  # brake: the stop seed
                i = stop
            else:  # brake would close in: the allowed plan intruding least
                i = int(order[allowed[order]][0])
        return Plan(
            commands=cmds[i].copy(),
            positions=pos[i].copy(),
            clearance=float(clear[i]),
            cost=float(cost[i]),
            status=status,
            n_safe=n_safe,
        )

    def edge_closing(self, todo: PlanInputs) -> np.ndarray | None:
        """The edge rule's measure of each candidate: the fastest rate (m/s) at which its
        first step closes in on an agent already within ``d_c`` (the predicted distance at
        the first plan step against the distance now); None when no agent is that close
        (or ``edge="paper"``).

        Parameters
        ----------
        todo : PlanInputs
            What :meth:`plan_begin` prepared.
        """
        if self.edge != "escape" or not self._ids.size:
            return None
        pos, _, x, pred, y0 = todo.problem[:5]
        d0 = np.hypot(*(np.asarray(x, dtype=float)[None, :2] - y0).T)
        near = d0 < float(self.d_c)
        if not near.any():
            return None
        gap = pos[:, 0, None, :] - pred[None, near, 0, :]  # (N, K, 2) at the first step
        d1 = np.hypot(gap[..., 0], gap[..., 1])
        out: np.ndarray = ((d0[near][None, :] - d1) / float(self.sampling.dt_plan)).max(axis=1)
        return out

    def will_plan(self) -> bool:
        """Whether the next :meth:`decide` plans (else it replays the current plan)."""
        return self._plan is None or self._since >= int(self.sampling.replan_every)

    def use_plan(self, plan: Plan) -> None:
        """Have the next :meth:`decide` apply ``plan`` (made by :meth:`plan_begin` and
        :meth:`plan_end` on its state and lambda) instead of planning itself."""
        self._next_plan = plan

    # ------------------------------------------------------------------ control instant
    def decide(self, state: ControlState, lam: float) -> np.ndarray:
        self._t_now = float(state.t)
        given = lam  # an array when lambda is run per agent (lambda_keys)
        lam = self._per_agent(lam)
        replan = self.will_plan()
        if replan:
            ready, self._next_plan = self._next_plan, None
            # the plan gets lambda as given: each agent its own safe distance, as in a
            # lockstep batch (plan_all -> plan_begin(vector))
            self._plan = plan = ready if ready is not None else self.plan(state, given)
            self._plan_t = state.t
            self._since = 0
            self._warm, self._warm_t = plan.commands, state.t
            j = 0
        else:
            plan = self._plan  # type: ignore[assignment]  # set above on the first instant
            j = min(
                int((state.t - self._plan_t) / self.sampling.dt_plan + 1e-9),
                int(self.sampling.horizon) - 1,
            )
        self._since += 1
        cmd: np.ndarray = plan.commands[j].copy()
        self._last_cmd = cmd
        ok = plan.status in ("optimal", "unconstrained", "peer_yield")
        rows, i = self._rows, self._n_rec
        if i == rows.shape[0]:
            self._rows = rows = np.concatenate([rows, np.empty_like(rows)])
        rows[i, 0:2] = state.x[:2]
        rows[i, 2:4] = (
            cmd if self.dynamics.command_kind == "velocity" else self.dynamics.velocity(state.x)
        )
        rows[i, 4:6] = cmd
        self._n_rec = i + 1
        rec = self._rec
        rec["lam"].append(float(lam) if ok else math.nan)
        rec["status"].append(plan.status)
        rec["clear"].append(plan.clearance)
        rec["safe"].append(plan.n_safe if replan else -1)
        self.n_steps_ += 1
        return cmd

    def yielding(self) -> bool:
        """Whether this robot says it yields to its peers (its reciprocity's
        ``coordination="yield"``, and a plan within the last
        :data:`~conformal_control.families.cbf.reciprocal.YIELD_HOLD_S` seconds gave way on the
        peers' lines or fell back)."""
        rec = self.reciprocity
        return bool(
            rec is not None and rec.coordination == "yield" and self._t_now < self._yield_until
        )

    def planned_path(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The current plan as ``(times (H,) s since the start, positions (H, 2) m)``: what
        a robot broadcasts to the others (None before the first plan)."""
        if self._plan is None:
            return None
        h = self._plan.positions.shape[0]
        return self._plan_t + self.sampling.dt_plan * np.arange(1, h + 1), self._plan.positions

    def interval_record(self) -> MPCIntervalRecord:
        return with_robot_columns(self._record(), getattr(self, "_robots", None))  # type: ignore[no-any-return]

    def _record(self) -> MPCIntervalRecord:
        rec = self._rec
        s = self._n_rec
        n = self._ids.size
        rows = self._rows[:s]
        return MPCIntervalRecord(
            ids=self._ids,
            x_ego=rows[:, 0:2].copy(),
            v_ego=rows[:, 2:4].copy(),
            x_pred=self._xp[:s].copy() if n else np.zeros((s, 0, 2)),
            v_pred=self._vp[:s].copy() if n else np.zeros((s, 0, 2)),
            lam_applied=np.array(rec["lam"], dtype=float),
            status=list(rec["status"]),
            command=rows[:, 4:6].copy(),
            clearance=np.array(rec["clear"], dtype=float),
            n_safe=np.array(rec["safe"], dtype=np.int64),
        )
