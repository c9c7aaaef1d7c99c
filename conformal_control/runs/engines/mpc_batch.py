"""Sampling-MPC episodes of a sweep run in this process: :func:`iter_mpc_batch`.

Every episode is built and run as :func:`~conformal_control.runs.episode.run_episode` runs it
on the generic loop (:func:`~conformal_control.runs.build.build_flagship`, then
:func:`~conformal_control.runs.engines.loop.loop_steps`, the body of
:func:`~conformal_control.runs.engines.loop.run_loop` one control instant at a time), with its
own random stream, predictor, loss and rule: its result equals the one-at-a-time result
(``tests/runs/engines/test_mpc_batch.py`` compares every metric, interval, step and the
configuration), except ``wall_s`` and ``config["engine"]`` (``"mpc_batch"``).

``lockstep=True`` advances the episodes of a batch together from one plan to the next and
makes the plans of all of them together
(:func:`~conformal_control.families.mpc.batch.plan_all`: each episode samples and rolls out
its own candidates, ONE compiled call evaluates the candidates of every episode, each
chooses its own plan; an episode's ``wall_s`` is then its own time plus an equal share of
each joint plan it took part in). **Measured: it does not pay**, so it is off by default:
25 ``mpc`` episodes of ``crossings-v2`` (the first 5 test scenarios, the margin grid) took
242 ms of CPU per episode one after another and 300 ms in lockstep batches of 8 (load
average 10, ``bench run`` in one process): joining the episodes' candidates copies them
into one set of arrays and evaluates them cold in cache, where one episode's evaluation
reads its rollouts hot, and the per-call overhead saved is tens of microseconds. What
running the MPC episodes here saves is what the process pool cost per episode (a pickled
task, results sent back, a worker loading the compiled kernels), not the episodes' own
Python per control instant (sampling with their own generators, the plant, the replayed
crowd, the conformal bookkeeping), which a compiled MPC engine would have to take over.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from typing import Any, cast

from ...core import registry
from ...core.spec import RunSpec
from ...data.scene import Scene
from ...families.mpc.batch import plan_all
from ...families.mpc.controller import SamplingMPC
from ..build import build_flagship
from ..results.episode import EpisodeResult
from .loop import loop_steps

__all__ = ["iter_mpc_batch", "mpc_batch_reason"]


def mpc_batch_reason(run: RunSpec) -> str | None:
    """Why episodes of ``run`` do not run here (:func:`iter_mpc_batch`), or None when they do: a
    single-robot run of a registered sampling-MPC family without ``on_interval``.

    Parameters
    ----------
    run : RunSpec
        The run's specification.
    """
    if run.robots is not None:
        return "a run with several robots runs as a fleet"
    family, _ = run.role("family")
    if family is None:
        return "the default family (cbf) is not a sampling MPC"
    if not isinstance(family, str):
        return "the family is not given by name (an instance would be shared by the episodes)"
    try:
        cls = registry.get("family", family)
    except (registry.UnknownPluginError, registry.PluginUnavailableError) as exc:
        return f"family {family!r}: {exc}"
    if not (isinstance(cls, type) and issubclass(cls, SamplingMPC)):
        return f"family {family!r} is not a sampling MPC"
    return None


def _plans(family: Any) -> bool:
    return isinstance(family, SamplingMPC) and family.will_plan()


def iter_mpc_batch(
    episodes: Iterable[tuple[Scene, RunSpec, dict[str, Any] | None]],
    *,
    lockstep: bool = False,
    batch_size: int = 8,
) -> Iterator[tuple[int, EpisodeResult]]:
    """Run ``episodes`` in this process and yield ``(index, result)`` as each ends.

    Parameters
    ----------
    episodes : iterable of (scene, run, extra_config)
        Each episode's scene, its run (seed and frame limit included; see
        :func:`mpc_batch_reason`) and what is merged into its configuration (or None);
        consumed as slots free up.
    lockstep : bool
        Plan the episodes of a batch together (see the module docstring: slower); False
        runs them one after another.
    batch_size : int
        Episodes alive at a time with ``lockstep`` (else one).

    Yields
    ------
    (int, EpisodeResult)
        The episode's index in ``episodes`` and its result, in the order they end. An
        episode that raises stops the iteration with its exception.
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    feed = enumerate(episodes)
    size = batch_size if lockstep else 1
    live: dict[int, Any] = {}  # index -> the episode's loop_steps generator
    waiting: dict[int, tuple[Any, Any, Any]] = {}  # index -> (family, state, lam)
    done: list[tuple[int, EpisodeResult]] = []

    def advance(i: int, share: float | None) -> None:
        steps = live[i]
        try:
            waiting[i] = next(steps) if share is None else steps.send(share)
        except StopIteration as end:
            del live[i]
            waiting.pop(i, None)
            result = cast(EpisodeResult, end.value)
            result.config["engine"] = "mpc_batch"
            done.append((i, result))

    def refill() -> None:
        # stop once an episode has ended: its result is yielded (and journaled by a sweep)
        # before the next episode starts; without lockstep an episode runs to its end
        # inside advance(), so refilling on would run the whole feed before yielding
        while len(live) < size and not done:
            item = next(feed, None)
            if item is None:
                return
            i, (scene, run, extra) = item
            why = mpc_batch_reason(run)
            if why is not None:
                raise ValueError(f"episode {i} does not run here: {why}")
            fl = build_flagship(run.on_scene(scene), run)
            live[i] = loop_steps(fl, run, extra_config=extra, pause=_plans if lockstep else False)
            advance(i, None)

    refill()
    while live or done:
        yield from done
        done.clear()
        if not live:
            refill()
            continue
        order = sorted(waiting)
        t0 = time.perf_counter()
        plan_all([waiting[i] for i in order])
        share = (time.perf_counter() - t0) / max(len(order), 1)
        for i in order:
            advance(i, share)
        refill()
