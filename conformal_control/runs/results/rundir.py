"""Run directories: config, metrics, trace, intervals, trajectory and plot of a run."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from ...core.fileio import atomic_write, atomic_write_json, atomic_write_text

if TYPE_CHECKING:  # annotations only (no circle: none of these imports a result)
    import numpy as np

    from ...core.loop import LoopResult
    from ...data.scene import Scene
    from .metrics import EpisodeMetrics

__all__ = ["RunResult", "csv_cell", "csv_text", "finite_or_none", "write_run_dir"]


class RunResult(Protocol):
    """What a run directory is written from (an
    :class:`~conformal_control.runs.results.episode.EpisodeResult` is one): typed by what it
    holds, so this module needs no result class (and no import circle ties it to one)."""

    scene: Scene
    config: dict[str, Any]
    metrics: EpisodeMetrics
    intervals: list[dict[str, Any]]
    trajectory: dict[str, np.ndarray]
    loop: LoopResult | None


def finite_or_none(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by None (JSON has no NaN or inf)."""
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [finite_or_none(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def csv_cell(v: Any) -> Any:
    """A CSV cell: floats in full precision (``repr``), None and non-finite as empty."""
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ""
    return v


def csv_text(header: list[str], rows: Iterable[list[Any]]) -> str:
    """A CSV file's text (``header`` then ``rows``), as :mod:`csv` writes it."""
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


def write_run_dir(
    result: RunResult,
    out: str | Path,
    *,
    plot: bool = True,
    only: tuple[str, ...] | None = None,
) -> Path:
    """Write the files of a run into ``out`` (created if needed) and return it.

    * ``config.json`` - every parameter as given, as used (scene units) and in SI, the
      scene, predictor (with its parameters), seed and version;
    * ``metrics.json`` - the run's metrics (see the README for each key);
    * ``trace.csv`` - ``k,t,lambda,loss``: one row per scored interval (lambda_k in the
      scene's units, t in s since the start);
    * ``intervals.csv`` - every interval with extra columns (loss with the applied lambda,
      the largest constraint gap, agents sensed, control steps);
    * ``trajectory.csv`` - ``frame,t,x,y,vx,vy,d_min`` per video frame (m, m/s);
    * ``animation.npz`` - what ``conformal-control animate`` renders (if the episode kept
      it; see :mod:`conformal_control.runs.results.record`);
    * ``plot.png`` - the scene with the path, lambda(t), loss(t) and the distance to the
      nearest pedestrian;
    * ``guarantee.png`` - running average loss against epsilon and the rule's bounds.

    Each file is written to a temporary name and renamed into place, ``metrics.json``
    after every other data file (before the plots): a run directory holding
    ``metrics.json`` is complete, and a crash or a full disk never leaves a half-written or
    empty file; a write error is an
    :class:`~conformal_control.core.exceptions.OutputNotWritableError` naming the file.

    Parameters
    ----------
    result : EpisodeResult
        The episode.
    out : path
        The run directory.
    plot : bool
        Draw ``plot.png`` and ``guarantee.png``.
    only : tuple of str, optional
        Restrict the files to these, e.g. ``("config.json", "metrics.json")`` (what large
        benchmarks keep).

    Returns
    -------
    Path
        ``out``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if only is not None:
        unknown = set(only) - {"config.json", "metrics.json"}
        if unknown:
            raise ValueError(
                f"write_run_dir(only=...) takes config.json and metrics.json, got {unknown}"
            )
    # every file is written to a temporary name and renamed (never half-written, errors
    # name the file); metrics.json comes last of the data files: its presence marks a
    # complete run directory (an interrupted sweep journals such directories)
    atomic_write_json(out / "config.json", finite_or_none(result.config))
    metrics = result.metrics.as_dict()
    if only is not None:
        atomic_write_json(out / "metrics.json", metrics)
        return out
    trace = csv_text(
        ["k", "t", "lambda", "loss"],
        (
            [iv["k"], csv_cell(iv["t"]), csv_cell(iv["lambda"]), csv_cell(iv["loss"])]
            for iv in result.intervals
            if iv["loss"] is not None
        ),
    )
    atomic_write_text(out / "trace.csv", trace)
    cols = ["k", "t", "lambda", "loss", "loss_applied", "max_gap", "n_sensed", "n_steps"]
    rows = ([csv_cell(iv.get(c)) for c in cols] for iv in result.intervals)
    atomic_write_text(out / "intervals.csv", csv_text(cols, rows))
    tr = result.trajectory
    traj = (
        [
            int(tr["frame"][i]),
            *(csv_cell(float(tr[c][i])) for c in ("t", "x", "y", "vx", "vy", "d_min")),
        ]
        for i in range(len(tr["frame"]))
    )
    atomic_write_text(
        out / "trajectory.csv", csv_text(["frame", "t", "x", "y", "vx", "vy", "d_min"], traj)
    )
    animation = getattr(result, "animation", None)
    if animation is not None:
        import numpy as np

        def save_npz(tmp: Path) -> None:
            with tmp.open("wb") as fh:  # a file object: numpy would append .npz to a name
                np.savez_compressed(fh, **animation)

        atomic_write(out / "animation.npz", save_npz)
    atomic_write_json(out / "metrics.json", metrics)
    if plot:
        from ...io.plotting.jobs import FigureJob, draw_all
        from ...io.plotting.run import plot_run

        jobs: list[FigureJob] = [(plot_run, (result, out / "plot.png"), {})]
        if result.loop is not None and result.loop.monitor.n:
            from ...io.plotting.guarantee import plot_guarantee

            units = result.scene.units
            kwargs = {
                "lambda_unit": units.factor("lambda_init"),
                "lambda_label": f"lambda (1/{units.time_name})",
            }
            jobs.append((plot_guarantee, (result.loop.monitor, out / "guarantee.png"), kwargs))
        draw_all(jobs)  # the two figures on two cores where possible
    return out
