"""What a worker does with one run: load the scene, run the episode, write the run directory.

:func:`execute_run` never raises: an error becomes a ``status: "failed"`` record with the
exception and its traceback, so one bad run does not stop a sweep. It is a plain module-level
function of plain arguments, so every executor (in-process, process pool, Dask) ships it
the same way.
"""

from __future__ import annotations

import contextlib
import functools
import os
import time
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..runs.results.metrics import EpisodeMetrics

if TYPE_CHECKING:
    from ..data.scene import Scene
    from .plan import SweepRun

__all__ = ["METRIC_COLUMNS", "execute_run", "load_run_scene", "run_dir_name"]

#: Metrics copied from ``metrics.json`` into the results table (scalars only).
METRIC_COLUMNS = EpisodeMetrics.columns()


def run_dir_name(run: SweepRun, key: str) -> str:
    """Directory name of a run: readable prefix (label or scene) + its key.

    Parameters
    ----------
    run : SweepRun
        The run.
    key : str
        Its key.
    """
    stem = run.label or run.scene
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in str(stem))[:60]
    return f"{safe}-{key}"


@contextlib.contextmanager
def _single_threaded_blas() -> Iterator[None]:
    """Limit BLAS/OpenMP pools to one thread for the run (threadpoolctl, if installed).

    One run per core is how sweeps use a machine; a multi-threaded BLAS inside each run
    oversubscribes it badly (a darts VARIMA fit on a busy 2-core machine: ~30 CPU-s with
    default threads against ~0.9 CPU-s single-threaded).
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        yield
        return
    with threadpool_limits(limits=1):
        yield


def load_run_scene(run: SweepRun) -> Scene:
    """The scene of a run (uncached; the built-in scene depends on the seed).

    Parameters
    ----------
    run : SweepRun
        The run.
    """
    return _load_scene(run.scene, run.data_root, run.spec.seed)


def _load_scene(name: str, data_root: str | None, seed: int) -> Scene:
    from ..data import load_scene

    return load_scene(name, data_root, seed=seed if name == "crossing" else 0)


@functools.lru_cache(maxsize=8)
def cached_scene(name: str, data_root: str | None, seed: int) -> Scene:
    """:func:`load_run_scene`, the last eight scenes kept (a serial sweep reuses them)."""
    return _load_scene(name, data_root, seed)


def execute_run(run: SweepRun, key: str, out_dir: str, plot: bool | str = False) -> dict[str, Any]:
    """Run one run of a sweep.

    Parameters
    ----------
    run : SweepRun
        The run (:class:`~conformal_control.experiments.plan.SweepRun`).
    key : str
        The run's key (names its directory).
    out_dir : str
        The sweep's output folder; the run directory is ``out_dir/runs/<name>``. With a
        remote Dask cluster it must be a path the workers can write (a shared file system).
    plot : bool or str
        What each run writes: True or ``"plots"`` (the whole run directory with
        ``plot.png`` and ``guarantee.png``), False or ``"full"`` (the run directory without
        plots; default: plotting takes most of a short run's time), ``"metrics"``
        (``config.json`` and ``metrics.json`` only: large benchmarks) or ``"none"`` (the
        journal record only).

    Returns
    -------
    dict
        ``key``, ``status`` ("ok" or "failed"), ``run_dir``, ``metrics`` (the scalar
        metrics), ``error`` and ``traceback`` (failed runs), ``worker`` (host:pid),
        ``elapsed_s``.
    """
    t0 = time.perf_counter()
    rec: dict[str, Any] = {
        "key": key,
        "status": "failed",
        "run_dir": None,
        "metrics": {},
        "error": None,
        "traceback": None,
        "worker": f"{os.uname().nodename}:{os.getpid()}",
    }
    try:
        from ..runs.episode import run_episode
        from ..runs.results.rundir import write_run_dir

        seed = run.spec.seed if run.scene == "crossing" else 0  # one cache entry
        cached = cached_scene(run.scene, run.data_root, seed)
        # a shallow copy per run: building an episode sets radii and v_max on the scene
        # it gets, and runs in one process share the cached scene
        scene = cached.replace(meta=dict(cached.meta), defaults=dict(cached.defaults))
        with _single_threaded_blas():
            result = run_episode(
                # a benchmark scenario carries its time limit
                scene,
                run.spec_on(scene.meta.get("max_frames")),
                extra_config={"sweep": {"key": key, "run": run.as_dict()}},
            )
        files = plot if isinstance(plot, str) else ("plots" if plot else "full")
        run_dir: Path | None = Path(out_dir) / "runs" / run_dir_name(run, key)
        assert run_dir is not None
        if files in ("plots", "full"):
            write_run_dir(result, run_dir, plot=files == "plots")
        elif files == "metrics":
            write_run_dir(result, run_dir, plot=False, only=("config.json", "metrics.json"))
        elif files == "none":
            run_dir = None
        else:
            raise ValueError(f"unknown run files option {files!r}")
        m = result.metrics
        rec.update(
            status="ok",
            run_dir=None if run_dir is None else str(run_dir),
            metrics={k: m.get(k) for k in METRIC_COLUMNS},
        )
    except Exception as exc:  # a failed run is data, not a crash
        rec["error"] = f"{type(exc).__name__}: {exc}"
        rec["traceback"] = traceback.format_exc()
    rec["elapsed_s"] = time.perf_counter() - t0
    return rec
