"""What the batch engine does per episode, in Python (:class:`EpisodeSlots`, mixed into
the engine): build an episode as :func:`~conformal_control.runs.episode.run_episode` does
and load it into a slot, run the parts of its intervals that are its own objects' (its own
predictor, the acp family's regions, a fallback decided in Python, a loss scored on the
interval's record), measure it at its end; :class:`Episode` (one live episode's Python
state) and :class:`GapLossAt` (an interval's gap loss as a function of lambda).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import warnings
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from ....core.loop import (
    IntervalLog,
    LoopResult,
    check_per_agent,
    close_agent_interval,
)
from ....core.monitor import AgentMonitor, GuaranteeMonitor
from ....core.spec import RunSpec
from ....data.scene import Scene
from ....families.cbf.acp import ACPIntervalRecord
from ....families.cbf.barriers import APFForm
from ....families.cbf.constraint import time_to_contact
from ....families.cbf.controller import CBFIntervalRecord, PredictorError
from ....families.cbf.dynamics import VelocityTrackingForm
from ....families.cbf.feasibility import robot_speed_bound, row_floors
from ....families.cbf.filters.exact2d import Exact2DForm, Exact2DSafetyFilter
from ....families.cbf.loss import CBFGapLoss, CBFTruth, GapLossForm
from ....families.cbf.pyhypot import EXACT_FOR_THIS_PYTHON
from ....families.cbf.reference import AttractiveFieldForm
from ....families.cbf.roles import InfeasibleStep
from ....families.cbf.speed import speed_polygon
from ....predictors.recorded import RecordedForm
from ....predictors.shift import DelayedForm, ScaledForm, scene_key
from ....world.reactive import ReactiveEnvironment
from ....world.replay import FrameLog, ReplayCursor
from ...build import Flagship, build_flagship
from ...results.episode import EpisodeResult
from ...results.measure import (
    episode_config,
    feasibility,
    jsonable,
    lambda_safe_values,
    measure,
    warn_after_run,
    warn_before_run,
)
from ...results.metrics import EpisodeMetrics
from ...results.record import AnimationRecorder
from .. import kernels as bk
from ..crowd_kernels import dense_layout
from ..gap_kernels import PYTHON
from ..reactive import MODELS, CrowdSlots
from .pool import Pool
from .supports import (
    FALLBACKS,
    OWN,
    NotRun,
    Parts,
    episode_parts,
    form_of,
    info_keys,
    prediction,
    recorded_block,
    supports,
)


class GapLossAt:
    """The gap loss of an interval as a function of lambda: ``s(max_gap + lambda)``, as
    :meth:`CBFGapLoss.__call__ <conformal_control.families.cbf.loss.CBFGapLoss.__call__>` computes
    it
    (the gaps do not depend on lambda; lambda is added to their maximum), from the maximum
    the engine computed (what ``ConformalStepper.end_interval`` hands a rule with
    ``uses_loss_function``, without rebuilding the interval's record)."""

    def __init__(self, loss: CBFGapLoss, max_gap: np.float64) -> None:
        self.loss, self.max_gap = loss, max_gap

    def __call__(self, lam: float) -> float:
        if math.isnan(lam):
            raise ValueError("the loss needs a lambda that is a number, got nan")
        return float(self.loss.squash(self.max_gap + lam))


# ------------------------------------------------------------------------------ episodes
@dataclass
class Episode:
    """One live episode: its built flagship and what the loop accumulates in Python."""

    index: int
    run: RunSpec  # the episode's own: its seed and time limit
    fl: Flagship
    parts: Parts  # fl's roles as the classes the engine runs
    monitor: GuaranteeMonitor | AgentMonitor
    learn: bool
    seed: int
    max_frames: int | None
    lambda_safe: float | None  # in the scene's units, as run_episode reports it
    floor: Any
    goals: np.ndarray
    intervals: list[IntervalLog] = field(default_factory=list)
    n_sensed: list[int] = field(default_factory=list)
    # lambda run per agent: the interval's agents (keys) and their lambdas
    keys: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    lams: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # the keys of the forecast counters a compiled prediction fills (see info_keys)
    info_keys: tuple[str, ...] = ()


class EpisodeSlots:
    """What the engine does for each episode of its slots, in Python: build it and load it
    into a slot (:meth:`start`), the parts of its intervals that run through its own
    objects (its own predictor, the acp family's regions, a fallback decided in Python, a
    loss scored on the interval's record), and measure it at its end (:meth:`finish`).
    Mixed into the engine (:class:`~conformal_control.runs.engines.batch.engine.Engine`),
    whose state it reads."""

    pool: Pool
    eps: list[Episode | None]
    output: str
    run_spec: RunSpec
    extra_config: dict[str, Any] | None
    crowds: CrowdSlots | None
    warn_stacklevel: int
    on_control: Any
    _own: bool
    _acp: bool
    _scores: tuple[np.ndarray, ...]
    #: the one episode's animation recorder and flagship (:meth:`load_single`)
    recorder: AnimationRecorder | None
    built: Flagship | None

    def start(self, b: int, index: int, scene: Scene, seed: int, max_frames: int | None) -> None:
        """Build episode ``index`` as run_episode does and load it into slot ``b``.

        Parameters
        ----------
        b, index : int
            The slot, and the episode's position among the engine's scenes.
        scene : Scene
            The episode's scene (its run's task on it).
        seed : int
            The episode's seed.
        max_frames : int, optional
            Its frame limit.
        """
        run = dataclasses.replace(self.run_spec, seed=seed, max_frames=max_frames)
        learn = run.learn
        fl = build_flagship(scene, run)
        parts = episode_parts(fl)
        sc = fl.scene
        lambda_safe, lam_safe_si = lambda_safe_values(fl, run.lambda_safe, run.units)
        floor = feasibility(fl)
        warn_before_run(fl, floor, learn)
        # what ConformalLoop.run does first: reset the environment (validates the scene and
        # the timing), the family (validates; resets predictor, filter, reference), the rule
        env = parts.env
        env.reset()
        vec = fl.params.si["lambda_per"] == "agent"
        if vec:  # as ConformalStepper.start, and its begin_interval for the acp family
            check_per_agent(fl.family, fl.loss)
            if parts.acp is not None:
                raise ValueError(
                    f"{type(fl.family).__name__}.lambda_keys() gave None after "
                    "begin_interval: lambda cannot be run per agent with this family"
                )
        fl.family.reset()
        monitor: GuaranteeMonitor | AgentMonitor
        monitor = (AgentMonitor if vec else GuaranteeMonitor).for_rule(
            fl.rule,
            lambda_safe=lam_safe_si,
            lambda_safe_source=run.lambda_safe_source,
            premise_proven=False,
            bounds=parts.loss.bounds,
            learn=learn,
            **(
                {
                    "prior": fl.params.si["lambda_prior"],
                    "row_floor": fl.params.si["lambda_floor_row"],
                    "floor_step": fl.params.si["lambda_floor_step"],
                    "floor_limit": fl.params.si["lambda_floor_limit"],
                }
                if vec
                else {}
            ),
        )
        # each compiled part as its compiled form (validated constants), never its attributes
        forms = fl.compiled_forms()
        apf = form_of(forms, "barrier", APFForm)
        filt_form = form_of(forms, "safety_filter", Exact2DForm)
        ref_form = form_of(forms, "reference", AttractiveFieldForm)
        k = form_of(forms, "dynamics", VelocityTrackingForm).K_acc
        pred = fl.predictor
        reactive = isinstance(env, ReactiveEnvironment)
        if isinstance(env, ReactiveEnvironment):
            model = env.crowd.model_  # (built by the reset)
            if type(model) not in MODELS.values():
                raise NotRun(f"the crowd model is a {type(model).__name__}")
        # the acp family predicts, scores its past errors and sorts them in its own
        # begin_interval: its predictor is called through it; so is the oracle of a
        # reactive crowd (whose future is not known: its query says so)
        dt_frame = 1.0 / sc.fps
        ids = np.asarray(sc.agent_ids)
        code, shift, form, window = prediction(
            pred, forms.get("predictor"), dt_frame, int(env.history_frames), ids
        )
        if parts.acp is not None or (reactive and code == bk.ORACLE):
            code, shift, form, window = OWN, bk.NO_SHIFT, None, 1
        last = sc.n_frames - 1
        if max_frames is not None:
            last = min(last, sc.start_index + int(max_frames))
        recorded = None
        if code == bk.RECORDED:
            rform = cast(RecordedForm, forms.get("predictor"))
            recorded = recorded_block(rform, sc, dt_frame, last)
            if recorded is None:  # the predictor raises on this scene: called as it is
                code, window = OWN, 1
        if int(window) != window or window < 1:
            raise PredictorError(
                f"predictor {type(pred).__name__} failed on scene {sc.name}: ValueError: "
                f"window must be a positive integer, got {window!r}"
            )
        ep = Episode(
            index=index,
            run=run,
            fl=fl,
            parts=parts,
            monitor=monitor,
            learn=learn,
            seed=seed,
            max_frames=max_frames,
            lambda_safe=lambda_safe,
            floor=floor,
            goals=np.asarray(sc.goals, dtype=float),
            info_keys=info_keys(code, shift, form),
        )
        p = self.pool
        substeps, tau = int(env.substeps), int(env.tau_frames)
        S, s, verts, radius = speed_polygon(int(filt_form.speed_sides), float(filt_form.v_max))
        p.ensure(
            steps=tau * substeps,
            agents=1,
            columns=sc.n_agents,
            frames=last - sc.start_index + 1,
            sides=S.shape[0],
        )
        dt = dt_frame / substeps
        # the frames the episode reads: its history before the start, its frames, the last
        # interval's future (the oracle, the truth); the rest of a long scene stays out
        lo = sc.start_index - int(env.history_frames)
        if reactive:  # every column over the episode's frames, filled as the crowd walks
            assert isinstance(env, ReactiveEnvironment)
            lo, hi = max(lo, 0), min(last + tau + 2, sc.n_frames)
            m = sc.n_agents
            buffer = env.compiled_state().buffer
            assert buffer is not None  # a reactive environment holds its crowd's positions
            data = dense_layout(buffer[lo:hi], lo, sc.start_index, sc.n_frames)
            p.put(b, data, (sc.n_frames, m, m * (hi - lo), m * (hi - lo)))
            if self.crowds is None:
                self.crowds = CrowdSlots(p.size)
            self.crowds.load(b, env, last, lo)
        else:
            p.load(b, sc.tracks.clip(lo, last + tau + 2))
        p.reactive[b] = reactive
        # whether the episode's own objects read the environment's buffer during the run
        p.mirror[b] = reactive and (code == OWN or parts.gap is None)
        p.x[b] = (*sc.start, 0.0, 0.0)
        p.t[b] = 0.0
        p.goal[b] = ep.goals[0]
        p.goal_idx[b] = 0
        p.goal_radius[b] = sc.goal_radius
        p.t_goal[b] = math.nan
        p.neg_k_att[b] = -ref_form.K_att
        p.v_ref_max[b] = ref_form.v_max
        p.dt[b] = dt
        p.dt_frame[b] = dt_frame
        p.decay[b] = math.exp(-k * dt)
        p.gain[b] = -math.expm1(-k * dt)
        p.k_acc[b] = k
        p.radius[b] = env.sensing_radius
        p.lam[b] = monitor.lambda_1
        p.vec[b] = vec
        if parts.gap is not None:
            gap = form_of(forms, "loss", GapLossForm)
            p.scale[b] = gap.scale
            key = (type(parts.gap), float(gap.scale))
            p.sq[b] = p.squash.setdefault(key, (len(p.squash), gap.squash))[0]
        else:  # scored by the loss object (see end)
            p.scale[b] = math.nan
        p.last[b] = 0.0
        p.step[b] = 0
        p.fi[b] = sc.start_index
        p.last_frame[b] = last
        p.substeps[b] = substeps
        p.tau[b] = tau
        p.history[b] = int(env.history_frames)
        p.predictor[b] = code
        self._own = self._own or code == OWN
        self._acp = self._acp or parts.acp is not None
        p.window[b] = int(window)
        p.shift[b] = shift
        p.shift_k[b] = form.samples(dt_frame) if isinstance(form, DelayedForm) else 0
        p.shift_x[b] = (
            (form.scale, 0.0)
            if isinstance(form, ScaledForm)
            else (getattr(form, "p", 0.0), getattr(form, "duration_s", 1.0))
        )
        p.noise_sigma[b] = getattr(form, "sigma_m", 0.0)
        p.seeds[b] = getattr(form, "seed", 0)
        p.scene_keys[b] = scene_key(sc.name)
        p.first_frame[b] = sc.first_frame
        if shift in (bk.NOISY, bk.DROPOUT) or code == bk.RECORDED:
            p.agent_id[b, : ids.size] = ids
        p.shift_counts[b] = 0
        p.rec_counts[b] = 0
        if recorded is not None:
            p.put_recorded(b, recorded[0])
            p.rec_step[b] = recorded[1]
        else:
            p.rec_len[b] = 0
        p.n_log[b] = 0
        p.wall[b] = 0.0
        p.n_predicted[b] = p.n_short_total[b] = p.n_bad_total[b] = 0
        p.counts[b] = 0
        p.done[b] = False
        p.need_begin[b] = True
        p.active[b] = True
        poly = np.concatenate([S.ravel(), s, verts.ravel()])
        p.poly[b, : poly.size] = poly
        p.poly_len[b] = poly.size
        fallback_kernel = filt_form.fallback
        p.fallback[b] = FALLBACKS.get(fallback_kernel or "", PYTHON)
        p.forced[b] = False
        p.acp[b] = parts.acp is not None
        p.prm[b] = (
            apf.K_rep,
            apf.rho0,
            apf.d_c,
            apf.delta,
            apf.surface,
            float(fl.constraint.a),
            radius,
            not filt_form.speed_sides,
            filt_form.v_max,
            fallback_kernel == "lambda_search",
            filt_form.lambda_margin,
            p.cap,
            *fl.constraint.edge_settings(),
        )
        self.eps[b] = ep
        bk.log_frames(np.array([b]), p.store, p.where, p.fi, p.x, p.t, p.log, p.n_log)

    def _regions(self, b: int) -> None:
        """Slot ``b``'s barrier at each horizon step of the interval (the acp family:
        ``d_c`` raised by the region's inflation at the interval's lambda), as
        :meth:`ACPController.decide <conformal_control.families.cbf.acp.ACPController.decide>`
        sets up the compiled step."""
        p, ep = self.pool, self.eps[b]
        assert ep is not None and ep.parts.acp is not None  # b is a live acp slot
        if not p.n_agents[b]:  # no agent: no row, the controller computes no region
            return
        forms = ep.parts.acp.region_barriers(float(p.lam[b]))
        H = len(forms)
        if H > p.acp_dc.shape[1]:
            p.acp_dc = p.grown(p.acp_dc, 1, H)
            p.acp_delta = p.grown(p.acp_delta, 1, H)
        p.acp_h[b] = H
        for h, form in enumerate(forms):
            p.acp_dc[b, h] = form.d_c
            p.acp_delta[b, h] = form.delta

    def _capped(self, b: int) -> None:
        """Count slot ``b``'s control instants whose region was capped (the acp family's
        ``n_capped_``, one per instant with agents, as its ``decide`` counts them)."""
        p, ep = self.pool, self.eps[b]
        assert ep is not None and ep.parts.acp is not None
        s = int(p.step[b])
        if not p.n_agents[b] or not s:
            return
        capped = ep.parts.acp.compiled_state().capped
        h = np.minimum(np.arange(s) // int(p.substeps[b]), capped.size - 1)
        ep.parts.acp.n_capped_ += int(capped[h].sum())

    def _predict_own(self, b: int) -> None:
        """Slot ``b``'s predictions from its own predictor: the environment's query (its
        sensor on the engine's state), the controller's ``begin_interval`` (prediction,
        counters, sanitising, interpolation), copied into ``xp`` / ``vp``."""
        p, ep = self.pool, self.eps[b]
        assert ep is not None  # b is live
        env, policy = ep.parts.env, ep.fl.family
        n = int(p.n_agents[b])
        # the environment senses where the engine's robot is, at the engine's frame and time
        env.from_compiled(ReplayCursor(x=p.x[b].copy(), frame=int(p.fi[b]), t=float(p.t[b])))
        query = env.sense()
        sensed = env.compiled_state().sensed
        assert sensed is not None  # an environment's cursor always holds what it sensed
        if not np.array_equal(sensed, p.sensed[b, :n]):  # both are the same range test
            raise RuntimeError(
                f"run_batch: the sensor and the engine disagree on the agents sensed in "
                f"episode {ep.index} at frame {query.frame}; use run_episode"
            )
        policy.begin_interval(query)
        form = policy.compiled_state()
        s = int(form.xp.shape[0])
        p.xp[b, :s, :n] = form.xp
        p.vp[b, :s, :n] = form.vp

    def _fall_back(self, b: int) -> None:
        """Slot ``b``'s infeasible step decided by its own fallback (one the compiled step
        does not decide, e.g. ``relax``), on the rows the step left in the work buffer,
        as :meth:`Exact2DSafetyFilter.step_apf_record
        <conformal_control.families.cbf.filters.exact2d.Exact2DSafetyFilter.step_apf_record>`
        hands it over; the decision is applied when the slot runs on."""
        p, ep = self.pool, self.eps[b]
        assert ep is not None
        n, cap = int(p.n_agents[b]), p.cap
        n0, n1, lam = p.paused.tolist()
        step = InfeasibleStep(
            np.array((n0, n1)),
            p.work[: 2 * n].reshape(n, 2).copy(),
            p.work[2 * cap : 2 * cap + n].copy(),
            lam,
            p.last[b].copy(),
            escape=Exact2DSafetyFilter.escape_in(p.work, cap, int(p.poly_len[b]) // 5),
            # (the collision distance Exact2DSafetyFilter.contact_times takes)
            ttc=time_to_contact(
                p.x[b, :2],
                p.xp[b, int(p.step[b]), :n],
                p.vp[b, int(p.step[b]), :n],
                float(max(p.prm[b, 12], p.prm[b, 2])),
                np.array((n0, n1)),
            ),
        )
        res = ep.parts.safety_filter.fall_back(step)
        v = np.asarray(res.decision, dtype=float)
        p.forced_v[b] = (v[0], v[1], res.lambda_applied)
        p.forced[b] = True

    def _end_per_agent(
        self, b: int, ep: Episode, o: int | None, agent_top: np.ndarray, pairs: int
    ) -> tuple[IntervalLog, float]:
        """Slot ``b``'s interval end with lambda run per agent: each agent's gap loss from
        its largest gap (``agent_top[o:]``, the compiled gap loss), or the loss object's
        components on the interval's record and truth; then each agent's update
        (:func:`~conformal_control.core.loop.close_agent_interval`)."""
        p = self.pool
        assert isinstance(ep.monitor, AgentMonitor)
        s, n = int(p.step[b]), int(p.n_agents[b])
        gap = ep.parts.gap
        k = len(ep.intervals)
        if gap is None:  # the loss object on the interval's record and truth
            return close_agent_interval(
                k, ep.keys, ep.lams, s, monitor=ep.monitor, loss=ep.parts.loss,
                record=self._record(b), truth=self._truth(b), floors=self._floors(b, ep),
            )  # fmt: skip
        top = np.full(n, np.nan)
        floors = self._floors(b, ep)
        if o is not None:
            got = agent_top[o : o + n]
            top = np.where(np.isfinite(got), got, np.nan)
        comp = gap.keyed(ep.keys, top, ep.lams)
        diagnostics: dict[str, float] = {}
        if pairs and np.isfinite(comp.values).any():
            top_b, applied_b = self._scores[0][b], self._scores[1][b]
            diagnostics = {
                "loss_applied": float(gap.squash(applied_b)),
                "max_gap": float(top_b),
                "n_pairs": pairs,
                "n_truth_missing": s * n - pairs,
            }
        return close_agent_interval(
            k, ep.keys, ep.lams, s, monitor=ep.monitor, components=comp,
            diagnostics=diagnostics, floors=floors,
        )  # fmt: skip

    def _floors(self, b: int, ep: Episode) -> np.ndarray | None:
        """Slot ``b``'s agents' own feasibility floors of the interval (as the
        controller's ``lambda_floors`` gives them), when the run reads them
        (``lambda_floor_row`` > 0), else None."""
        assert isinstance(ep.monitor, AgentMonitor)
        if ep.monitor.row_floor <= 0.0:
            return None
        si = ep.fl.params.si
        speed = robot_speed_bound(float(si["v_max"]), int(si["speed_sides"]))
        return row_floors(ep.fl.constraint, self._record(b), speed)

    def _record(self, b: int) -> CBFIntervalRecord:
        """Slot ``b``'s interval as the controller's ``interval_record`` gives it, without
        the filter's status strings (the engine keeps them as codes, ``rec_code``, for the
        animation record; the losses that read a record do not use them)."""
        p, ep = self.pool, self.eps[b]
        assert ep is not None
        s, n = int(p.step[b]), int(p.n_agents[b])
        fields = {
            "ids": np.asarray(ep.parts.env.scene.agent_ids[p.sensed[b, :n]]),
            "x_ego": p.rec_x[b, :s].copy(),
            "v_ego": p.rec_v[b, :s].copy(),
            "x_pred": p.xp[b, :s, :n].copy(),
            "v_pred": p.vp[b, :s, :n].copy(),
            "lam_applied": p.rec_lam[b, :s].copy(),
        }
        acp = ep.parts.acp
        if acp is not None:  # what its regions were made of (ACPController.interval_record)
            form = acp.compiled_state()
            return ACPIntervalRecord(
                **fields,
                pred_samples=form.pred_samples.copy(),
                sorted_scores=form.sorted_scores,
                inflation=form.inflation.copy(),
            )
        return CBFIntervalRecord(**fields)

    def _truth(self, b: int) -> CBFTruth:
        """Slot ``b``'s truth, revealed by its environment (its own code) on the engine's
        state of the interval: its start frame, the agents sensed then, its steps."""
        p, ep = self.pool, self.eps[b]
        assert ep is not None
        ep.parts.env.from_compiled(
            ReplayCursor(
                k_start=int(p.k_start[b]),
                sensed=p.sensed[b, : int(p.n_agents[b])].copy(),
                step=int(p.step[b]),
            )
        )
        return ep.parts.env.reveal()

    def finish(self, b: int) -> tuple[int, EpisodeResult | EpisodeMetrics]:
        """Measure the episode of slot ``b`` with run_episode's code; free the slot.

        The counters go where the per-episode loop keeps them (the environment's frame log,
        ``t_goal_`` and ``n_sensed_``; the controller's and the filter's learned attributes),
        then :func:`run_episode`'s own measuring code runs on them.
        """
        p, ep = self.pool, self.eps[b]
        assert ep is not None
        fl = ep.fl
        sc, env, policy, filt = fl.scene, ep.parts.env, fl.family, ep.parts.safety_filter
        n = int(p.n_log[b])
        rows = p.log[b, :n]
        env.log = FrameLog(
            frame=(sc.first_frame + sc.start_index + np.arange(n)).tolist(),
            t=rows[:, 0].tolist(),
            state=list(rows[:, 1:5].copy()),
            d_min=rows[:, 5].tolist(),
        )
        env.t_goal_ = None if math.isnan(p.t_goal[b]) else float(p.t_goal[b])
        env.n_sensed_ = ep.n_sensed
        c = p.counts[b].tolist()
        policy.n_steps_ = c[4]
        if p.predictor[b] != OWN:  # (an own predictor's are the controller's already)
            policy.n_nonfinite_predictions_ = int(p.n_bad_total[b])
        if p.n_predicted[b] and ep.info_keys:
            totals = {
                "n_short_history": int(p.n_short_total[b]),
                "n_stale": int(p.shift_counts[b, 0]),
                "n_unseen": int(p.shift_counts[b, 1]),
                "n_dropped": int(p.shift_counts[b, 2]),
                "n_missing": int(p.rec_counts[b, 0]),
                "n_missing_steps": int(p.rec_counts[b, 1]),
                "n_extrapolated": int(p.rec_counts[b, 2]),
                "n_nonfinite_current": int(p.rec_counts[b, 3]),
            }
            policy.forecast_info_ = {key: totals[key] for key in ep.info_keys}
        # the compiled step's counts, added to those a fallback decided in Python counted
        filt.n_solves_ += c[0]
        filt.n_infeasible_ += c[1]
        filt.n_fallback_ += c[2]
        name = filt.fallback_.name
        if c[2] - c[5]:
            filt.fallback_counts_[name] = filt.fallback_counts_.get(name, 0) + c[2] - c[5]
        if c[5]:  # steps the edge rule decided alone
            filt.fallback_counts_["escape"] = filt.fallback_counts_.get("escape", 0) + c[5]
        if c[3]:
            filt.events_["lambda_search_vertex"] = c[3]
        if c[6]:  # brake / hold decisions moved into the edge rule's escape polygon
            filt.events_["escape_projected"] = filt.events_.get("escape_projected", 0) + c[6]
        crowd_config: dict[str, Any] = {"crowd": "replay"}
        if p.reactive[b]:  # the simulated crowd back to its environment, as it walked
            assert self.crowds is not None and isinstance(env, ReactiveEnvironment)
            self.crowds.mirror(b, env, p.store, p.where)
            self.crowds.finish(b, env)
            crowd_config = env.crowd_config()
        result = LoopResult(
            intervals=ep.intervals, lambda_final=float(p.lam[b]), monitor=ep.monitor
        )
        metrics, intervals, traj = measure(
            fl, result, ep.learn, ep.lambda_safe, ep.floor, float(p.wall[b])
        )
        warn_after_run(fl, metrics, ep.learn, ep.max_frames, stacklevel=self.warn_stacklevel)
        p.active[b] = False
        self.eps[b] = None
        if self.output == "metrics":
            return ep.index, metrics
        config = episode_config(fl, ep.run, ep.lambda_safe)
        config["feasibility"] = jsonable(ep.floor.as_dict())
        config.update(self.extra_config or {})
        config["crowd"] = crowd_config
        config["engine"] = "batch"
        return ep.index, EpisodeResult(sc, config, metrics, intervals, traj, {}, result, None)

    def load(self, b: int, index: int, scene: Scene, seed: int, max_frames: int | None) -> None:
        """Start episode ``index`` in slot ``b`` and lay out its interval's buffers.

        Parameters
        ----------
        b, index : int
            The slot, and the episode's position among the engine's scenes.
        scene : Scene
            The episode's scene (its run's task on it).
        seed : int
            The episode's seed.
        max_frames : int, optional
            Its frame limit.
        """
        p = self.pool
        self.start(b, index, scene, seed, max_frames)
        ep = self.eps[b]
        assert ep is not None
        frames = int(p.last_frame[b] - p.fi[b]) + 1
        p.prepare(b, ep.goals, frames * int(p.substeps[b]))

    # ------------------------------------------------------------------ one episode
    def load_single(self, scene: Scene, run: RunSpec) -> bool:
        """Load ``run``'s one episode on ``scene`` into slot 0, keeping its control
        instants (and its animation record with ``run.record_animation``); False if the
        engine does not run it and ``run.engine`` is ``"auto"`` (the loop then does),
        ``ValueError`` saying why with ``"batch"``."""
        engine = run.engine
        reason = supports(run)
        if reason is None and not EXACT_FOR_THIS_PYTHON:
            reason = (
                "the engine's distances reproduce CPython 3.11's math.hypot, not this "
                f"Python's ({sys.version_info[0]}.{sys.version_info[1]})"
            )
        if reason is not None:
            if engine == "auto":
                return False
            raise ValueError(f"engine='batch' cannot run this configuration: {reason}")
        self.pool.keep = True
        # the warnings of building the episode (before the engine knows whether it runs it)
        # are re-issued for run_episode's (or run's) caller, unless the loop runs it instead; the
        # warnings of the run point at the caller by themselves
        caught: list[warnings.WarningMessage] = []
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                self.load(0, 0, run.on_scene(scene), run.seed, run.max_frames)
        except NotRun:
            if engine == "auto":
                caught.clear()  # the loop builds the episode again and warns itself
                return False
            raise
        finally:
            for w in caught:  # load_single < run_single < run_episode (or run) < its caller
                warnings.warn(w.message, w.category, stacklevel=4)
        ep = self.eps[0]
        assert ep is not None
        self.built = ep.fl
        if run.record_animation:
            fl, si = ep.fl, ep.fl.params.si
            self.recorder = AnimationRecorder(
                fl.scene, fl.family, fl.barrier, fl.params.tau_frames, si["substeps"],
                si["sensing_radius"],
            )  # fmt: skip
            self.on_control = self.record_interval
        return True

    def record_interval(self, slots: np.ndarray) -> None:
        """Slot 0's interval into its animation record (what the recorder reads of the
        controller after an interval)."""
        p, ep, recorder = self.pool, self.eps[0], self.recorder
        assert ep is not None and recorder is not None
        s, n = int(p.step[0]), int(p.n_agents[0])
        recorder.add_interval(
            ep.fl.scene.agent_ids[p.sensed[0, :n]], p.xp[0, :s, :n], p.rec_code[0, :s]
        )

    def single_result(self, result: EpisodeResult) -> EpisodeResult:
        """The one episode's ``result`` with its control instants (``steps``) and its
        animation record."""
        p = self.pool
        n = int(p.n_st[0])
        result.steps = {
            "t": p.st_t[0, :n].copy(),
            "x": p.st_x[0, :n].copy(),
            "cmd": p.st_cmd[0, :n].copy(),
        }
        recorder = self.recorder
        if recorder is not None:
            fl = self.built
            assert fl is not None
            si = fl.params.si
            env = fl.env
            if isinstance(env, ReactiveEnvironment):  # the pedestrians the robot met, as the loop
                recorder.scene = env.simulated_scene()
            result.animation = recorder.finish(
                result.trajectory,
                result.intervals,
                {"epsilon": si["epsilon"], "lambda_unit": result.metrics.unit("lambda_final")},
            )
        return result
