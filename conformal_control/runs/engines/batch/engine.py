"""The batch engine's lockstep loop (:class:`Engine`): every live episode advances one
interval per iteration -- sense and predict at the sampling time, the interval's control
instants in one compiled call, the interval scored and lambda updated -- and a finished
episode's slot is refilled; :func:`run_batch` / :func:`iter_batch` (many episodes) and
:func:`run_single` (one episode: the engine choice of
:func:`~conformal_control.runs.episode.run_episode` and :func:`conformal_control.run`, this
engine when it runs the configuration, else the generic loop).
See :mod:`conformal_control.runs.engines.batch`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from itertools import repeat
from typing import Any

import numpy as np

from ....core.jit import compile_now
from ....core.loop import (
    IntervalLog,
    IntervalScore,
    close_interval,
)
from ....core.monitor import AgentMonitor
from ....core.spec import RunSpec
from ....data.scene import Scene
from ....world.reactive import ReactiveEnvironment
from ...build import Flagship, build_flagship
from ...results.episode import EpisodeResult
from ...results.measure import (
    LAMBDA_LIMIT,
    check_lambda,
)
from ...results.metrics import EpisodeMetrics
from ...results.record import AnimationRecorder
from ..loop import run_loop
from ..reactive import CrowdSlots
from .episode import Episode, EpisodeSlots, GapLossAt
from .pool import Pool
from .supports import OWN, as_run_spec, supports


# ------------------------------------------------------------------------------ engine
class Engine(EpisodeSlots):
    """The lockstep loop over a :class:`Pool` (see the module docstring)."""

    def __init__(
        self, size: int, output: str, run: RunSpec, extra_config: dict[str, Any] | None
    ) -> None:
        """The engine of ``size`` slots.

        Parameters
        ----------
        size : int
            Episodes alive at a time.
        output : {"metrics", "results"}
            What :meth:`finish` gives per episode.
        run : RunSpec
            The run of every episode (each gets its own seed and frame limit).
        extra_config : dict, optional
            Merged into each episode's configuration.
        """
        self.pool = Pool(size)
        self.eps: list[Episode | None] = [None] * size
        self.output = output
        self.run_spec = run
        self.extra_config = extra_config
        self._own = False  # whether an episode predicts with its own predictor object
        self._acp = False  # whether an episode is of the acp family
        self.crowds: CrowdSlots | None = None  # the reactive crowds, if any
        # the scores of an interval end, per slot (reset for the slots that end; reused
        # rather than allocated at every interval end)
        self._scores = (
            np.empty(size),  # top gap
            np.empty(size),  # top gap at the lambda applied
            np.empty(size, dtype=np.int64),  # pairs scored
            np.empty(size),  # loss
            np.empty(size),  # loss at the lambda applied
        )
        #: called with the slots after their interval's control instants, before it is
        #: scored (the single-episode run keeps its animation record with it)
        self.on_control: Any = None
        #: called with each scored interval's log, as the loop's ``on_interval``
        self.on_interval: Callable[[IntervalLog], None] | None = None
        #: stack level of the warnings of an episode's end (who they point at)
        self.warn_stacklevel = 4
        self.recorder: AnimationRecorder | None = None
        self.built: Flagship | None = None

    # ------------------------------------------------------------------ sampling time
    def begin(self, slots: np.ndarray) -> None:
        """Sampling time of ``slots``: sense, predict, interpolate."""
        p = self.pool
        p.sense(slots)
        n = p.n_agents[slots]
        most = int(n.max(initial=0))
        if most > p.cap:
            p.ensure(agents=most)
        p.k_start[slots] = p.fi[slots]
        p.step[slots] = 0
        p.need_begin[slots] = False
        for b, m in zip(slots.tolist(), n.tolist(), strict=True):
            ep = self.eps[b]
            assert ep is not None  # slots are live
            ep.n_sensed.append(m)
            if p.vec[b]:  # each sensed agent's lambda (a new one's at the prior)
                assert isinstance(ep.monitor, AgentMonitor)
                ep.keys = np.asarray(ep.parts.env.scene.agent_ids[p.sensed[b, :m]], np.int64)
                ep.lams = ep.monitor.values(ep.keys)
                ref = float(ep.lams.min()) if m else 0.0  # the family's smallest entry
                p.lam[b] = ref
                p.lam_off[b, :m] = ep.lams - ref
        predicted = slots[n > 0]  # the controller asks its predictor only about agents
        if self._acp:  # the acp family's begin_interval runs at every sampling time
            regions = p.acp[slots]
            for b in slots[regions].tolist():
                self._predict_own(b)
                self._regions(b)
            predicted = slots[(n > 0) & ~regions]
        if self._own:
            own = p.predictor[predicted] == OWN
            for b in predicted[own].tolist():
                self._predict_own(b)
            predicted = predicted[~own]
        if predicted.size:
            p.predict(predicted)

    # ------------------------------------------------------------------ control instants
    def control(self, slots: np.ndarray) -> None:
        """The control instants of the current interval of ``slots``, each slot up to its
        interval's end or its episode's end, in one compiled call
        (:func:`~conformal_control.runs.engines.interval.run_interval`: reference, filter,
        plant, goal with waypoints, frame clock and frame log)."""
        p = self.pool
        todo = slots
        walk = slots[p.reactive[slots]] if self.crowds is not None else slots[:0]
        if walk.size:  # the robots' velocities at the start, the log rows before
            v_start = p.x[walk, 2:4].copy()
            n_log0 = p.n_log[walk].copy()
        while True:
            bad, paused = p.run_interval(todo)
            if paused < 0 or bad >= 0:
                break
            todo = todo[paused:]  # the paused slot decides, then runs on with the rest
            self._fall_back(int(todo[0]))
        if walk.size and bad < 0:
            crowds = self.crowds
            assert crowds is not None
            crowds.advance(walk, p, v_start, n_log0)
            for b in walk[p.mirror[walk]].tolist():
                ep = self.eps[b]
                assert ep is not None and isinstance(ep.parts.env, ReactiveEnvironment)
                crowds.mirror(b, ep.parts.env, p.store, p.where)
        if self._acp:
            for b in slots[p.acp[slots]].tolist():
                self._capped(b)
        if bad >= 0:
            ep = self.eps[bad]
            assert ep is not None  # bad is one of slots, which are live
            which = f"episode {ep.index} of the batch, " if len(self.eps) > 1 else ""
            raise ValueError(
                "Exact2DSafetyFilter received non-finite constraints, lambda or nominal "
                f"decision ({which}scene {ep.fl.scene.name}, t = {p.t[bad]:.3f} s); "
                "predictions must be sanitised before building constraints"
            )

    # ------------------------------------------------------------------ interval end
    def end(self, slots: np.ndarray) -> list[int]:
        """Score the intervals of ``slots`` (they end now), update lambda; returns the
        slots whose episode is over."""
        p = self.pool
        # the gap loss's intervals with pairs to score (other losses: their objects, below)
        if slots.size == 1:  # one episode (run_episode's): the same test on scalars
            b = int(slots[0])
            one = p.n_agents[b] > 0 and p.step[b] > 0 and not math.isnan(p.scale[b])
            scored = slots if one else slots[:0]
        else:
            scored = slots[
                (p.n_agents[slots] > 0) & (p.step[slots] > 0) & ~np.isnan(p.scale[slots])
            ]
        top, top_applied, n_pairs, loss, applied = self._scores
        top[slots] = -np.inf
        top_applied[slots] = -np.inf
        n_pairs[slots] = 0
        loss[slots] = np.nan
        applied[slots] = np.nan
        agent_top, where = p.score_gaps(scored, self._scores)
        finished = []
        for b in slots.tolist():
            ep = self.eps[b]
            assert ep is not None
            lam = float(p.lam[b])
            s = int(p.step[b])
            pairs = int(n_pairs[b])
            gap = ep.parts.gap
            if isinstance(ep.monitor, AgentMonitor):
                log, lam = self._end_per_agent(b, ep, where.get(b), agent_top, pairs)
                ep.intervals.append(log)
                p.lam[b] = lam
                extreme = [lam, *ep.monitor.current().tolist()]
                for x in extreme:
                    if not (math.isfinite(x) and abs(x) <= LAMBDA_LIMIT):
                        check_lambda(x, ep.fl, log.k)  # raises
                if self.on_interval is not None:
                    self.on_interval(log)
                if p.done[b]:
                    finished.append(b)
                else:
                    p.need_begin[b] = True
                continue
            score: IntervalScore | None = None
            record = revealed = None
            if gap is None:  # the loss object on the interval's record and truth
                record, revealed = self._record(b), self._truth(b)
            elif pairs:  # the compiled gap loss: the same arithmetic as CBFGapLoss
                score = IntervalScore(
                    float(loss[b]),
                    {
                        "loss_applied": float(applied[b]),
                        "max_gap": float(top[b]),
                        "n_pairs": pairs,
                        "n_truth_missing": s * int(p.n_agents[b]) - pairs,
                    },
                    GapLossAt(gap, top[b]),
                )
            else:
                score = IntervalScore(None)
            log, lam = close_interval(
                len(ep.intervals),
                lam,
                s,
                rule=ep.fl.rule,
                monitor=ep.monitor,
                learn=ep.learn,
                loss=ep.parts.loss,
                record=record,
                truth=revealed,
                score=score,
            )
            ep.intervals.append(log)
            p.lam[b] = lam
            if not (math.isfinite(lam) and abs(lam) <= LAMBDA_LIMIT):
                check_lambda(lam, ep.fl, log.k)  # raises
            if self.on_interval is not None:
                self.on_interval(log)
            if p.done[b]:
                finished.append(b)
            else:
                p.need_begin[b] = True
        return finished

    # ------------------------------------------------------------------ the loop
    def run(
        self, source: Iterator[tuple[int, Scene, int, int | None]], started: int = 0
    ) -> Iterator[tuple[int, EpisodeResult | EpisodeMetrics]]:
        """Advance every live episode one interval per iteration (every slot is then at a
        sampling time, so free slots are refilled at every iteration). Slots below
        ``started`` hold episodes loaded already (:meth:`load`)."""
        p = self.pool
        free = list(range(p.size - 1, started - 1, -1))  # slots to fill (popped from the end)
        slots = np.flatnonzero(p.active) if started else np.zeros(0, dtype=np.int64)
        elapsed = 0.0  # time of the iterations since the live slots last changed
        while True:
            if free:
                loaded = False
                while free:
                    nxt = next(source, None)
                    if nxt is None:
                        break
                    self.load(free.pop(), *nxt)
                    loaded = True
                if loaded:
                    slots = np.flatnonzero(p.active)
            if not slots.size:
                return
            t0 = time.perf_counter()
            # every live slot is at a sampling time: a new one, or its interval was scored
            self.begin(slots)
            self.control(slots)
            if self.on_control is not None:
                self.on_control(slots)
            finished = self.end(slots)
            elapsed += time.perf_counter() - t0
            if finished:  # each slot's share of the iterations it took part in
                p.wall[slots] += elapsed / slots.size
                elapsed = 0.0
                for b in finished:
                    yield self.finish(b)
                free += reversed(finished)
                slots = np.flatnonzero(p.active)


def _per_episode(value: Any, name: str) -> Iterator[Any]:
    """A value for every episode: a scalar repeated, or one per episode from a sequence."""
    if value is None or isinstance(value, (int, np.integer)):
        return repeat(None if value is None else int(value))
    if isinstance(value, Iterable) and not isinstance(value, (str, bytes)):
        return iter(value)
    raise TypeError(f"{name} must be an int, None or one value per scene, got {value!r}")


def iter_batch(
    scenes: Iterable[Scene],
    spec: Any = None,
    params: dict[str, Any] | None = None,
    *,
    max_frames: int | Iterable[int | None] | None = None,
    seeds: int | Sequence[int] | None = None,
    batch_size: int = 256,
    output: str = "metrics",
    extra_config: dict[str, Any] | None = None,
    **settings: Any,
) -> Iterator[tuple[int, EpisodeResult | EpisodeMetrics]]:
    """:func:`run_batch`, yielding ``(index, result)`` as episodes finish.

    Parameters
    ----------
    scenes : iterable of Scene
        Consumed lazily, one scene as a slot opens.
    spec : RunSpec or str, optional
        The run of every episode, or its predictor's registered name.
    params : dict, optional
        Parameter overrides (the run's ``params``).
    max_frames : int, iterable or None
        The frame limit of every episode, or one per scene (an iterator is consumed one
        value per scene as the scene is started).
    seeds : int, sequence or None
        The seed of every episode, or one per scene.
    batch_size : int
        Episodes alive at a time.
    output : {"metrics", "results"}
        What is yielded per episode.
    extra_config : dict, optional
        Merged into each episode's configuration.
    **settings
        Other settings of the run (:meth:`RunSpec.from_settings
        <conformal_control.core.spec.RunSpec.from_settings>`).

    Yields
    ------
    (int, EpisodeMetrics or EpisodeResult)
        In completion order; the int is the scene's position in ``scenes``.
    """
    settings.pop("max_frames", None)
    settings.pop("seed", None)
    run = as_run_spec(spec or settings.pop("predictor", None), params, **settings)
    # the engine keeps no animation record of a batch: the specification says so
    run = dataclasses.replace(run, record_animation=False)
    reason = supports(run)
    if reason is not None:
        raise ValueError(f"run_batch does not support this configuration: {reason}")
    if output not in ("metrics", "results"):
        raise ValueError(f"output must be 'metrics' or 'results', got {output!r}")
    if int(batch_size) != batch_size or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    compile_now()  # many episodes: compiled from the start (see conformal_control.core.jit)
    frames = _per_episode(max_frames, "max_frames")
    seed_values = _per_episode(0 if seeds is None else seeds, "seeds")

    def source() -> Iterator[tuple[int, Scene, int, int | None]]:
        for i, scene in enumerate(scenes):
            try:
                mf, seed = next(frames), next(seed_values)
            except StopIteration:
                raise ValueError("max_frames / seeds have fewer values than scenes") from None
            yield i, run.on_scene(scene), int(seed), None if mf is None else int(mf)

    engine = Engine(int(batch_size), output, run, extra_config)
    yield from engine.run(source())


def run_batch(
    scenes: Iterable[Scene],
    spec: Any = None,
    params: dict[str, Any] | None = None,
    *,
    max_frames: int | Sequence[int | None] | None = None,
    seeds: int | Sequence[int] | None = None,
    batch_size: int = 256,
    output: str = "metrics",
    **settings: Any,
) -> list[EpisodeMetrics] | list[EpisodeResult]:
    """Run one episode per scene, many at once, with the metrics of :func:`run_episode`.

    Parameters
    ----------
    scenes : iterable of Scene
        Consumed lazily (a generator keeps only the live episodes' scenes in memory).
    spec : RunSpec or str, optional
        The run of every episode (:class:`~conformal_control.core.spec.RunSpec`), or its
        predictor (a registered name).
    params : dict, optional
        Parameter overrides (the run's ``params``).
    max_frames : int, sequence or None
        The frame limit of every episode, or one per scene (e.g. each benchmark
        scenario's ``max_frames``).
    seeds : int, sequence or None
        The seed recorded for every episode (default 0, as ``run_episode``), or one per
        scene.
    batch_size : int
        Episodes alive at a time (memory grows with it; 256 keeps the per-iteration
        overhead well below the compiled work).
    output : {"metrics", "results"}
        Return :class:`EpisodeMetrics` (default) or :class:`EpisodeResult` objects.
    **settings
        Any other setting of the run that :func:`supports` accepts (``units``,
        ``learn``, ``rule_params``, ``fallback``, ``lambda_safe``, ...), and
        ``extra_config`` (merged into each episode's config).

    Returns
    -------
    list
        One item per scene, in the order of ``scenes``.

    Raises
    ------
    ValueError
        For a configuration :func:`supports` rejects (the message gives the reason), and
        for anything ``run_episode`` rejects.
    """
    out: dict[int, Any] = {}
    for index, item in iter_batch(
        scenes,
        spec,
        params,
        max_frames=max_frames,
        seeds=seeds,
        batch_size=batch_size,
        output=output,
        **settings,
    ):
        out[index] = item
    return [out[i] for i in range(len(out))]


# ------------------------------------------------------------------------------ one episode
def run_single(
    scene: Scene,
    run: RunSpec,
    *,
    on_interval: Callable[[IntervalLog], None] | None = None,
    extra_config: dict[str, Any] | None = None,
) -> EpisodeResult:
    """One episode of ``run`` on the engine ``run.engine`` chooses: THE engine choice of
    one episode, which :func:`~conformal_control.runs.episode.run_episode` and
    :func:`conformal_control.run` both call.

    ``"auto"``: the compiled engine when it runs the configuration (:func:`supports`, then
    the episode as built), else the generic loop
    (:func:`~conformal_control.runs.engines.loop.run_loop`); ``"batch"``: the compiled
    engine, or ``ValueError`` saying why not; ``"loop"``: the loop. Both give the result the
    loop gives (metrics but the wall time, intervals, trajectory, per-instant ``steps`` and,
    with ``record_animation``, the animation record); ``config["engine"]`` says which ran.
    The warnings of the run point at the line that called ``run_episode`` or
    ``conformal_control.run``.

    Parameters
    ----------
    scene : Scene
    run : RunSpec
        The episode's specification (one robot).
    on_interval : callable, optional
        Called with each scored interval's log, as the loop calls it.
    extra_config : dict, optional
        Merged into the configuration.
    """
    if run.engine != "loop":  # (the compiled engine puts the run's task on the scene)
        eng = Engine(1, "results", run, extra_config)
        if eng.load_single(scene, run):
            eng.on_interval = on_interval
            # warn_after_run < finish < run < run_single < run_episode (or run) < its caller
            eng.warn_stacklevel = 6
            [(_, result)] = list(eng.run(iter(()), started=1))
            assert isinstance(result, EpisodeResult)
            return eng.single_result(result)
    fl = build_flagship(run.on_scene(scene), run)
    return run_loop(fl, run, on_interval=on_interval, extra_config=extra_config, stacklevel=6)
