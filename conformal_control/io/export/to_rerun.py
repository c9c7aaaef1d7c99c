"""A run as a Rerun recording (``conformal-control export RUN --format rerun``).

Needs the ``rerun`` extra (``pip install "conformal-control[rerun]"``: ``rerun-sdk``).
Everything is on one timeline, ``time`` (seconds since the start of the run), and sent
column-wise (one call per entity, not one per frame). Entities, for a single robot
(``<r>`` = ``robot``) or each robot of a ``--robots`` run (``robot_0``, ...):

=============================  ====================  =====================================
entity                         archetype             content
=============================  ====================  =====================================
``world/<r>``                  ``Points2D``          per frame: the robot (radius: its body;
                                                     colour: green free, orange constrained,
                                                     red fallback or contact, grey finished)
``world/<r>/sensing``          ``Ellipses2D``        per frame: the sensing radius
``world/pedestrians``          ``Points2D``          per frame: every pedestrian present
``world/predictions``          ``LineStrips2D``      per interval (single robot): predicted
                                                     paths of the agents sensed
``world/map/<r>``              ``LineStrips2D``      static: the whole path; ``.../goals``
                                                     (``Points2D``) the goals
``plots/<r>/lambda``           ``Scalars``           per interval: lambda_k (scene units, as
                                                     in ``intervals.csv``)
``plots/<r>/loss``             ``Scalars``           per scored interval: l_k
``plots/<r>/epsilon``          ``Scalars``           per interval: the target epsilon
``plots/<r>/d_min``            ``Scalars``           per frame: distance to the nearest
                                                     pedestrian (m)
``plots/<r>/speed``            ``Scalars``           per frame: the robot's speed (m/s)
=============================  ====================  =====================================

The ``world`` entities need the run's ``animation.npz``; the plots and the map do not.
Rerun stores positions in single precision (``float32``), scalars in double precision.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .destination import safe_output_path
from .reader import RunRecord, read_run
from .to_mcap import start_time_ns

__all__ = ["write_rerun"]

GREEN, ORANGE, RED, GREY = (51, 179, 77), (255, 153, 26), (230, 38, 38), (140, 140, 140)
PED, SENSED, BLUE, PATH = (89, 140, 204), (242, 140, 26), (64, 115, 217), (60, 60, 60)
STATUS_RGB = {0: GREEN, 1: ORANGE, 2: RED}


def _import_rerun() -> Any:
    try:
        import rerun as rr
    except ImportError as exc:
        raise ImportError(
            'export --format rerun needs rerun-sdk: pip install "conformal-control[rerun]"'
        ) from exc
    return rr


def _time(rr: Any, t: np.ndarray, origin: int | None) -> Any:
    """The ``time`` column: seconds since the start, rounded to whole nanoseconds (as in the
    MCAP export; Rerun would truncate a float); a timestamp from ``origin`` (ns since the
    epoch, :func:`write_rerun`'s ``start_time``) when one is given."""
    ns = np.round(np.asarray(t, dtype=float) * 1e9).astype(np.int64)
    if origin is not None:
        return rr.TimeColumn("time", timestamp=(origin + ns).astype("datetime64[ns]"))
    return rr.TimeColumn("time", duration=ns.astype("timedelta64[ns]"))


def _scalars(
    rr: Any, rec: Any, path: str, t: np.ndarray, values: np.ndarray, origin: int | None
) -> None:
    keep = np.isfinite(values)
    if keep.any():
        rec.send_columns(
            path,
            indexes=[_time(rr, t[keep], origin)],
            columns=rr.Scalars.columns(scalars=values[keep]),
        )


def _plots(rr: Any, rec: Any, run: RunRecord, origin: int | None) -> None:
    for r in run.robots:
        iv, tr = r.intervals, r.trajectory
        base = f"plots/{r.name}"
        _scalars(rr, rec, f"{base}/lambda", iv["t"], iv["lambda"], origin)
        _scalars(rr, rec, f"{base}/loss", iv["t"], iv["loss"], origin)
        _scalars(rr, rec, f"{base}/epsilon", iv["t"], np.full(iv["t"].size, run.epsilon), origin)
        _scalars(rr, rec, f"{base}/d_min", tr["t"], tr["d_min"], origin)
        _scalars(rr, rec, f"{base}/speed", tr["t"], np.hypot(tr["vx"], tr["vy"]), origin)


def _map(rr: Any, rec: Any, run: RunRecord) -> None:
    for m, r in enumerate(run.robots):
        tr = r.trajectory
        rec.log(
            f"world/map/{r.name}",
            rr.LineStrips2D([np.column_stack([tr["x"], tr["y"]])], colors=[PATH], radii=0.03),
            static=True,
        )
        goals = run.goals[m] if m < len(run.goals) else np.zeros((0, 2))
        if goals.size:
            rec.log(
                f"world/map/{r.name}/goals",
                rr.Points2D(goals, radii=run.goal_radius, colors=[BLUE]),
                static=True,
            )


def _world(rr: Any, rec: Any, run: RunRecord, origin: int | None) -> None:
    assert run.frame_t is not None and run.robots_xy is not None and run.peds is not None
    t = run.frame_t
    n = t.size
    time = [_time(rr, t, origin)]
    for m, r in enumerate(run.robots):
        if run.kind == "single":
            codes = r.status if r.status is not None else np.zeros(n, dtype=np.int8)
            colors = np.array([STATUS_RGB.get(int(c), RED) for c in codes[:n]], dtype=np.uint8)
        else:
            assert run.active is not None and run.contact is not None
            colors = np.array(
                [
                    RED if run.contact[f, m] else GREEN if run.active[f, m] else GREY
                    for f in range(n)
                ],
                dtype=np.uint8,
            )
        xy = run.robots_xy[:, m, :]
        rec.send_columns(
            f"world/{r.name}",
            indexes=time,
            columns=rr.Points2D.columns(
                positions=xy, radii=np.full(n, run.robot_radius), colors=colors
            ),
        )
        if np.isfinite(run.sensing_radius):
            rec.send_columns(
                f"world/{r.name}/sensing",
                indexes=time,
                columns=rr.Ellipses2D.columns(
                    centers=xy, half_sizes=np.full((n, 2), run.sensing_radius)
                ),
            )
    present = np.isfinite(run.peds[..., 0])
    lengths = present.sum(axis=1)
    sensed = np.zeros_like(present)
    if run.predictions:  # the agents sensed at the last sampling time, per frame
        starts = np.array([p[0] for p in run.predictions])
        idx = np.searchsorted(starts, t, side="right") - 1
        for f in np.flatnonzero(idx >= 0):
            sensed[f, run.predictions[idx[f]][1]] = True
    colors = np.where(sensed[present][:, None], np.array(SENSED), np.array(PED)).astype(np.uint8)
    rec.send_columns(
        "world/pedestrians",
        indexes=time,
        columns=rr.Points2D.columns(
            positions=run.peds[present],
            radii=np.full(int(lengths.sum()), run.agent_radius),
            colors=colors,
        ).partition(lengths),
    )
    if run.kind == "single" and run.predictions:
        strips, counts, times = [], [], []
        for tk, _cols, pred in run.predictions:
            paths = [p[np.isfinite(p[:, 0])] for p in pred]
            paths = [p for p in paths if len(p) >= 2]
            strips.extend(paths)
            counts.append(len(paths))
            times.append(tk)
        rec.send_columns(
            "world/predictions",
            indexes=[_time(rr, np.array(times), origin)],
            columns=rr.LineStrips2D.columns(strips=strips, colors=[SENSED] * len(strips)).partition(
                counts
            ),
        )


def write_rerun(run: str | Path | RunRecord, out: str | Path, *, start_time: Any = None) -> Path:
    """Write a run directory (or a record read by :func:`read_run`) as a ``.rrd`` file.

    Parameters
    ----------
    run : path or RunRecord
    out : path
        The ``.rrd`` file to write (its folder is created), through
        :func:`~conformal_control.io.export.destination.safe_output_path`: never a file of
        the run directory but an earlier ``.rrd``, never a link or a device.
    start_time : datetime or str, optional
        The date and time the run's ``t = 0`` is shown at (the ``time`` timeline is then a
        timestamp; :func:`~conformal_control.io.export.to_mcap.start_time_ns`); None: the
        time since the start (a duration).

    Returns
    -------
    Path
        ``out``.
    """
    rr = _import_rerun()
    record = run if isinstance(run, RunRecord) else read_run(run)
    out = Path(out)
    # Rerun's save opens a path itself: it writes into a private folder, whose file
    # safe_output_path copies into an exclusively created one beside ``out``
    with safe_output_path(out, inputs=(record.path,), suffix=".rrd") as staged:
        rid = f"{record.scene}:{record.path.name}"
        rec = rr.RecordingStream("conformal-control", recording_id=rid)
        rec.save(staged)
        _map(rr, rec, record)
        origin = None if start_time is None else start_time_ns(start_time)
        _plots(rr, rec, record, origin)
        if record.has_scene:
            _world(rr, rec, record, origin)
        rec.flush()
        rec.disconnect()
    return out
