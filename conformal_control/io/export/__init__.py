"""Runs as files for the tools robotics people use: MCAP for Foxglove, ``.rrd`` for Rerun.

* :func:`export_run` -- ``conformal-control export RUN --format mcap|rerun``;
* :func:`~conformal_control.io.export.reader.read_run` -- a run directory as arrays;
* :func:`~conformal_control.io.export.to_mcap.write_mcap` -- the MCAP file (Foxglove's JSON
  schemas; needs the ``mcap`` package, a core dependency);
* :func:`~conformal_control.io.export.to_rerun.write_rerun` -- the Rerun recording (the
  ``rerun`` extra: ``pip install "conformal-control[rerun]"``);
* :func:`~conformal_control.io.export.to_ros2.write_ros2_mcap` and
  :func:`~conformal_control.io.export.to_ros2.write_ros2_bag` -- the run as ROS 2 messages,
  one MCAP file (``--schema ros2``) or a bag folder (``--format ros2-bag``) (the ``ros``
  extra);
* :func:`~conformal_control.io.export.destination.safe_output` -- the one way every exporter
  writes its file: never one of its inputs (a file of the run directory), never through a
  link, never a device, through an exclusively created temporary file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .destination import safe_output
from .reader import RobotTrack, RunRecord, read_run

__all__ = [
    "FORMATS",
    "SCHEMAS",
    "RobotTrack",
    "RunRecord",
    "default_output",
    "export_run",
    "read_run",
    "safe_output",
]

#: format -> file suffix (a ``ros2-bag`` is a folder)
FORMATS = {"mcap": ".mcap", "rerun": ".rrd", "ros2-bag": ""}
#: The message schemas of an MCAP export: Foxglove's JSON schemas, or ROS 2 messages.
SCHEMAS = ("foxglove", "ros2")


def default_output(run_dir: str | Path, format: str = "mcap", schema: str = "foxglove") -> Path:
    """Where :func:`export_run` writes by default: ``RUN_DIR/run.mcap``,
    ``RUN_DIR/run_ros2.mcap`` (``schema="ros2"``), ``RUN_DIR/run.rrd`` or the folder
    ``RUN_DIR/run_ros2_bag``.

    Parameters
    ----------
    run_dir : path
        The run directory.
    format : {"mcap", "rerun", "ros2-bag"}
        The export format.
    schema : {"foxglove", "ros2"}
        The MCAP file's schemas.
    """
    if format == "ros2-bag":
        return Path(run_dir) / "run_ros2_bag"
    if format == "mcap" and schema == "ros2":
        return Path(run_dir) / "run_ros2.mcap"
    return Path(run_dir) / f"run{FORMATS[format]}"


def export_run(
    run_dir: str | Path | RunRecord,
    out: str | Path | None = None,
    *,
    format: str = "mcap",
    schema: str = "foxglove",
    start_time: Any = None,
) -> Path:
    """Write a run directory as an MCAP file (Foxglove's schemas or ROS 2 messages), a
    ROS 2 bag folder or a Rerun recording.

    Parameters
    ----------
    run_dir : path or RunRecord
        A run directory (``conformal-control run``, ``--robots`` included), or the record
        :func:`read_run` read from one.
    out : path, optional
        The file (a new folder, for ``ros2-bag``) to write; default :func:`default_output`.
        Never a file of the run directory (but an earlier export of the same format), a
        link or a device (:mod:`conformal_control.io.export.destination`).
    format : {"mcap", "rerun", "ros2-bag"}
        The file format (``ros2-bag``: a bag folder as ``ros2 bag record`` writes it).
    schema : {"foxglove", "ros2"}
        For ``mcap``: Foxglove's JSON schemas, or ROS 2 messages (the ``ros`` extra).
    start_time : datetime or str, optional
        The date and time the run's ``t = 0`` is shown at (ISO 8601, e.g.
        ``"2026-05-04T09:30:00Z"``; without a time zone, UTC); None: the Unix epoch in an
        MCAP file (the same run, the same file), the time since the start in Rerun's. Not
        for the ROS 2 forms (their stamps start at the epoch).

    Returns
    -------
    Path
        The file written.
    """
    if format not in FORMATS:
        import difflib

        close = difflib.get_close_matches(str(format), FORMATS, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(
            f"unknown export format {format!r}{hint} (choose from {', '.join(FORMATS)})"
        )
    if schema not in SCHEMAS:
        raise ValueError(f"unknown export schema {schema!r} (choose from {', '.join(SCHEMAS)})")
    if schema == "ros2" and format == "rerun":
        raise ValueError("--schema ros2 applies to --format mcap (or give --format ros2-bag)")
    if start_time is not None and (schema == "ros2" or format == "ros2-bag"):
        raise ValueError(
            "--start-time applies to --format mcap with Foxglove's schemas and to --format "
            "rerun; the ROS 2 exports are stamped from the Unix epoch"
        )
    rec = run_dir if isinstance(run_dir, RunRecord) else read_run(run_dir)
    target = Path(out) if out is not None else default_output(rec.path, format, schema)
    if format == "ros2-bag":
        from .to_ros2 import write_ros2_bag

        return write_ros2_bag(rec, target)
    if format == "mcap" and schema == "ros2":
        from .to_ros2 import write_ros2_mcap

        return write_ros2_mcap(rec, target)
    if format == "mcap":
        from .to_mcap import write_mcap

        return write_mcap(rec, target, start_time=start_time)
    from .to_rerun import write_rerun

    return write_rerun(rec, target, start_time=start_time)
