"""The ``batch`` executor of a sweep: runs the lockstep engine can run, batched.

With ``run_sweep(..., executor="batch")`` (``bench run`` uses it by default) the runs of a
sweep are split in two:

* a run is **batched** when :func:`~conformal_control.runs.engines.batch.supports` accepts its
  ``run_episode`` arguments (replayed crowd, or social force, ORCA or mixed without noise;
  the constant-velocity, oracle or ``recorded`` predictor and the shifts of the first two
  (compiled in the engine), or any other predictor marked ``fast`` -- the engine calls the
  others in this process, one episode after another, while the pool predicts in parallel;
  any update rule given by name; APF barrier; exact 2-D filter with the ``lambda_search``,
  ``brake`` or ``hold`` fallback; attractive field; velocity-tracking plant; ``cbf_gap``,
  ``collision`` or ``distance_shortfall`` loss; learning or not) and it writes no animation
  or plots
  (``plot="metrics"`` or ``"none"``, or ``record_animation: false``): the lockstep engine
  keeps neither. Batched runs are grouped by everything but their scene, seed and frame
  limit, and each group runs in this process through
  :func:`~conformal_control.runs.engines.batch.iter_batch` (one core);
* with one worker (``workers=1``), a run of a sampling-MPC family (``mpc``, ``cc_mpc``,
  ``acp_mpc``, ``ecp_mpc``, ``fcp_mpc``, ...;
  :func:`~conformal_control.runs.engines.mpc_batch.mpc_batch_reason`) with a predictor the
  engine would batch and no plots runs in this process too, one episode after another
  (:func:`~conformal_control.runs.engines.mpc_batch.iter_mpc_batch`: no pool task per
  episode), each equal to its run on the generic loop (``config.json`` says ``"engine":
  "mpc_batch"``); with more workers the pool runs them in parallel;
* every other run goes to a process pool (``workers``), one episode per task, as with
  ``executor="process"``.

A batched run's record, ``metrics.json`` and ``config.json`` are those of the per-episode
run (the engine gives ``run_episode``'s metrics exactly), except ``wall_s`` (the run's share
of the batch's wall time), ``elapsed_s``, ``worker`` and the extra ``"engine": "batch"`` of
``config.json``. If a batch raises (an invalid scene, a failing episode), its runs not yet
recorded are run one by one through :func:`~conformal_control.experiments.worker.execute_run`, so a
bad run fails alone, as in any sweep.
"""

from __future__ import annotations

import dataclasses
import json
import time
import traceback
from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from .executors.base import Executor, Outcome
from .plan import SweepRun
from .worker import METRIC_COLUMNS, execute_run, run_dir_name

__all__ = ["batch_reason", "mpc_batch_reason", "run_batched", "run_chunk", "run_chunked"]


def _written(plot: bool | str) -> str:
    """What a run writes, as :func:`execute_run`'s ``plot`` names it."""
    return plot if isinstance(plot, str) else ("plots" if plot else "full")


def batch_reason(run: SweepRun, plot: bool | str = "metrics") -> str | None:
    """Why ``run`` is not batched, or None if it is.

    Parameters
    ----------
    run : SweepRun
        The run.
    plot : bool or str
        What the run writes (as :func:`execute_run` takes it).
    """
    from ..runs.engines.batch import supports

    files = _written(plot)
    spec = run.spec
    if files in ("metrics", "none"):
        # not written: the episode may skip it
        spec = dataclasses.replace(spec, record_animation=True)
    elif files == "plots":
        return "the batch engine keeps no per-instant steps to plot"
    elif spec.record_animation:
        return "the run directory gets an animation, which the batch engine does not record"
    slow = _slow_predictor(spec.role("predictor")[0])
    if slow is not None:
        return slow
    return supports(spec)


def mpc_batch_reason(run: SweepRun, plot: bool | str = "metrics") -> str | None:
    """Why ``run`` does not run with the sampling-MPC episodes in this process
    (:func:`~conformal_control.runs.engines.mpc_batch.iter_mpc_batch`), or None if it does.

    Parameters
    ----------
    run : SweepRun
        The run.
    plot : bool or str
        What the run writes (as :func:`execute_run` takes it).
    """
    from ..runs.engines.mpc_batch import mpc_batch_reason as reason

    files = _written(plot)
    if files == "plots":
        return "the run directory gets plots, drawn on the pool"
    slow = _slow_predictor(run.spec.role("predictor")[0])
    if slow is not None:
        return slow
    return reason(run.spec)


def _slow_predictor(name: Any) -> str | None:
    """Why runs with the predictor ``name`` go to the pool: the engine calls a predictor it
    does not compile (any but constant_velocity and oracle) in this process, one episode
    after another, so only predictors marked ``fast`` are batched; a slow one predicts in
    parallel on the pool's workers."""
    from ..core import registry

    if not isinstance(name, str) or name in ("constant_velocity", "oracle"):
        return None  # an instance: supports() says why not
    try:
        fast = bool(registry.get("predictor", name).capabilities.batchable)
    except (registry.UnknownPluginError, registry.PluginUnavailableError) as exc:
        return f"predictor {name!r}: {exc}"
    if fast:
        return None
    return f"predictor {name!r} is not declared batchable: its runs predict in parallel on the pool"


def _group_key(run: SweepRun) -> str:
    """What the runs of one batch share: the specification but its seed and frame limit
    (the scene, the seed, the limit and the names may differ inside a batch)."""
    shared = dataclasses.replace(run.spec, seed=0, max_frames=None)
    return json.dumps(shared.as_dict(), sort_keys=True, default=repr)


def _record(
    run: SweepRun, key: str, out_dir: str, plot: bool | str, result: Any, t0: float
) -> dict[str, Any]:
    """The sweep record of a batched run (as :func:`execute_run` writes it)."""
    import os

    from ..runs.results.rundir import write_run_dir

    rec: dict[str, Any] = {
        "key": key,
        "status": "failed",
        "run_dir": None,
        "metrics": {},
        "error": None,
        "traceback": None,
        "worker": f"{os.uname().nodename}:{os.getpid()} (batch)",
    }
    try:
        result.config.update({"sweep": {"key": key, "run": run.as_dict()}})
        files = _written(plot)
        run_dir: Path | None = None
        if files in ("metrics", "full"):
            run_dir = Path(out_dir) / "runs" / run_dir_name(run, key)
            if files == "metrics":
                only = ("config.json", "metrics.json")
                write_run_dir(result, run_dir, plot=False, only=only)
            else:
                write_run_dir(result, run_dir, plot=False)
        m = result.metrics
        rec.update(
            status="ok",
            run_dir=None if run_dir is None else str(run_dir),
            metrics={k: m.get(k) for k in METRIC_COLUMNS},
        )
    except Exception as exc:
        rec["error"] = f"{type(exc).__name__}: {exc}"
        rec["traceback"] = traceback.format_exc()
    rec["elapsed_s"] = time.perf_counter() - t0
    return rec


def run_batched(
    ex: Executor,
    tasks: Sequence[tuple[SweepRun, str, str, bool | str]],
    *,
    batch_size: int = 256,
) -> Iterator[Outcome]:
    """Yield ``(index, record)`` for every task (``(run, key, out_dir, plot)``, the
    arguments of :func:`execute_run`): the batched groups in this process while the other
    runs go to ``ex`` at the same time (a thread waits for the pool's results), so that the
    pool's workers and this process share the machine instead of taking turns."""

    from ..runs.engines.batch import iter_batch
    from ..runs.engines.mpc_batch import iter_mpc_batch
    from .worker import load_run_scene

    groups: dict[str, list[int]] = {}
    lock: list[int] = []  # sampling-MPC runs, in this process
    rest: list[int] = []
    # the MPC runs here only when the pool has one worker: with more, the pool runs them in
    # parallel (this process runs them one after another, on one core)
    here = int(getattr(ex, "n_workers", 1)) <= 1
    for i, (run, _key, _out, plot) in enumerate(tasks):
        if batch_reason(run, plot) is None:
            groups.setdefault(_group_key(run), []).append(i)
        elif here and mpc_batch_reason(run, plot) is None:
            lock.append(i)
        else:
            rest.append(i)

    def scene_id(run: SweepRun) -> tuple[Any, ...]:
        seed = run.spec.seed if run.scene == "crossing" else 0
        return run.scene, run.data_root, seed

    # a scene used by several batched runs (one per method of a benchmark) is loaded once
    # and kept until its last use; the others are loaded when their slot opens
    uses = Counter(scene_id(tasks[i][0]) for idx in [*groups.values(), lock] for i in idx)
    kept: dict[tuple[Any, ...], Any] = {}

    def scene_of(run: SweepRun) -> Any:
        sid = scene_id(run)
        scene = kept.get(sid)
        if scene is None:
            scene = load_run_scene(run)
        uses[sid] -= 1
        if uses[sid] > 0:
            kept[sid] = scene
        else:
            kept.pop(sid, None)
        # a shallow copy per run: building an episode sets radii and v_max on its scene
        return scene.replace(meta=dict(scene.meta), defaults=dict(scene.defaults))

    def batched() -> Iterator[Outcome]:
        for idx in groups.values():
            run0 = tasks[idx[0]][0]
            frames: list[int | None] = []

            def scenes(idx: list[int] = idx, frames: list[int | None] = frames) -> Iterator[Any]:
                for i in idx:
                    run = tasks[i][0]
                    scene = scene_of(run)
                    frames.append(run.spec.max_frames or scene.meta.get("max_frames"))
                    yield scene

            def limits(frames: list[int | None] = frames) -> Iterator[int | None]:
                k = 0  # max_frames of the k-th scene, known once scenes() has loaded it
                while True:
                    yield frames[k]
                    k += 1

            done: set[int] = set()
            t0 = time.perf_counter()
            try:
                # the limits are per scene
                shared = dataclasses.replace(run0.spec, max_frames=None, record_animation=False)
                for j, result in iter_batch(
                    scenes(),
                    shared,
                    max_frames=limits(),
                    seeds=[tasks[i][0].spec.seed for i in idx],
                    batch_size=batch_size,
                    output="results",
                ):
                    i = idx[j]
                    run, key, out_dir, plot = tasks[i]
                    done.add(i)
                    yield i, _record(run, key, out_dir, plot, result, t0)
            except Exception:  # the batch stopped: its other runs fail (or not) one by one
                for i in idx:
                    if i not in done:
                        yield i, execute_run(*tasks[i])
        if lock:
            yield from mpc_runs()

    def mpc_runs() -> Iterator[Outcome]:
        def episodes() -> Iterator[tuple[Any, Any, dict[str, Any]]]:
            for i in lock:
                run, key = tasks[i][0], tasks[i][1]
                scene = scene_of(run)  # a benchmark scenario carries its time limit
                spec = run.spec_on(scene.meta.get("max_frames"))
                yield scene, spec, {"sweep": {"key": key, "run": run.as_dict()}}

        done: set[int] = set()
        t0 = time.perf_counter()
        try:
            for j, result in iter_mpc_batch(episodes()):
                i = lock[j]
                run, key, out_dir, plot = tasks[i]
                done.add(i)
                yield i, _record(run, key, out_dir, plot, result, t0)
        except Exception:  # stopped: its other runs fail (or not) one by one
            for i in lock:
                if i not in done:
                    yield i, execute_run(*tasks[i])

    pool = _PoolDrain(ex, rest, [tasks[i] for i in rest]) if rest else None
    try:
        for item in batched():
            yield item
            if pool is not None:
                yield from pool.ready()
        if pool is not None:
            yield from pool.remaining()
    finally:
        if pool is not None:
            pool.stop()


_DONE = object()


class _PoolDrain:
    """The pool's outcomes, collected by a thread into a queue while this process runs the
    batched groups (the pool's generator submits new runs only while it is iterated)."""

    def __init__(self, ex: Executor, index: list[int], tasks: list[Any]) -> None:
        import queue
        import threading

        self._queue: queue.Queue[Any] = queue.Queue()
        self._index = index
        self._ex = ex
        self._stopping = threading.Event()
        self._outcomes = ex.run(execute_run, tasks)
        self._thread = threading.Thread(target=self._drain, name="sweep-pool", daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        try:
            for k, outcome in self._outcomes:
                self._queue.put((self._index[k], outcome))
                if self._stopping.is_set():
                    break
        except BaseException as exc:  # the machinery failed: re-raised in the consumer
            self._queue.put(exc)
        finally:
            close = getattr(self._outcomes, "close", None)
            if close is not None:
                close()
            self._queue.put(_DONE)

    def _take(self, item: Any) -> Outcome:
        if isinstance(item, BaseException):
            raise item
        return item  # type: ignore[no-any-return]

    def ready(self) -> Iterator[Outcome]:
        """The outcomes that have arrived, without waiting."""
        import queue

        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return
            if item is _DONE:
                self._queue.put(_DONE)  # keep the end marker for remaining()
                return
            yield self._take(item)

    def remaining(self) -> Iterator[Outcome]:
        """Every outcome still to come, waiting for them."""
        while True:
            item = self._queue.get()
            if item is _DONE:
                return
            yield self._take(item)

    def stop(self) -> None:
        """Stop the pool (an interrupted sweep): its workers are terminated at once
        (:meth:`ProcessExecutor.abort`, when the executor has it) and the thread ends;
        when this returns no worker writes a run directory any more, so the caller can
        journal the finished ones from disk."""
        self._stopping.set()
        abort = getattr(self._ex, "abort", None)
        if abort is not None:
            abort()
        self._thread.join(timeout=60)


def run_chunk(tasks: Sequence[tuple[SweepRun, str, str, bool | str]]) -> list[Outcome]:
    """Run ``tasks`` in this process (the batched groups on the lockstep engine, the others
    one by one) and return their ``(index, record)``: the task a cluster's worker runs for a
    chunk of a sweep (:func:`run_chunked`)."""
    from .executors.serial import SerialExecutor

    return list(run_batched(SerialExecutor(), tasks))


def _chunk_or_run(*args: Any) -> Any:
    """A job of :func:`run_chunked`: a chunk (one argument, the tasks) or one run."""
    return run_chunk(args[0]) if len(args) == 1 else execute_run(*args)


def run_chunked(
    ex: Executor,
    tasks: Sequence[tuple[SweepRun, str, str, bool | str]],
    *,
    chunk: int | None = None,
) -> Iterator[Outcome]:
    """Yield ``(index, record)`` for every task on a cluster (``ex``, e.g. Dask): the runs the
    lockstep engine batches are cut into chunks of ``chunk`` runs with the same settings
    (default: about four chunks per worker, 8 to 256 runs each), each chunk one task that a
    worker runs on its own engine (:func:`run_chunk`); every other run is one task. The
    records are those of :func:`run_batched`; a chunk lost with its worker fails its runs
    (rerun them: finished runs are skipped)."""
    batched: dict[str, list[int]] = {}
    rest: list[int] = []
    for i, (run, _key, _out, plot) in enumerate(tasks):
        if batch_reason(run, plot) is None:
            batched.setdefault(_group_key(run), []).append(i)
        else:
            rest.append(i)
    order = [i for idx in batched.values() for i in idx]
    if chunk is None:
        chunk = max(8, min(256, -(-len(order) // (4 * max(1, ex.n_workers)))))
    parts = [order[k : k + chunk] for k in range(0, len(order), chunk)]
    jobs: list[tuple[Any, ...]] = [([tasks[i] for i in part],) for part in parts]
    jobs += [tasks[i] for i in rest]
    for k, outcome in ex.run(_chunk_or_run, jobs):
        if k < len(parts):
            part = parts[k]
            if isinstance(outcome, BaseException):  # the chunk's worker failed
                yield from ((i, outcome) for i in part)
            else:
                yield from ((part[j], rec) for j, rec in outcome)
        else:
            yield rest[k - len(parts)], outcome
