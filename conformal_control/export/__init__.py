"""Runs as files for the tools robotics people use: MCAP for Foxglove, ``.rrd`` for Rerun.

* :func:`export_run` -- ``conformal-control export RUN --format mcap|rerun``;
* :func:`~conformal_control.export.reader.read_run` -- a run directory as arrays;
* :func:`~conformal_control.export.to_mcap.write_mcap` -- the MCAP file (Foxglove's JSON
  schemas; needs the ``mcap`` package, a core dependency);
* :func:`~conformal_control.export.to_rerun.write_rerun` -- the Rerun recording (the
  ``rerun`` extra: ``pip install "conformal-control[rerun]"``);
* :func:`~conformal_control.export.destination.safe_output` -- the one way every exporter
  writes its file: never one of its inputs (a file of the run directory), never through a
  link, never a device, through an exclusively created temporary file.
"""

from __future__ import annotations

from pathlib import Path

from .destination import safe_output
from .reader import RobotTrack, RunRecord, read_run

__all__ = ["FORMATS", "RobotTrack", "RunRecord", "export_run", "read_run", "safe_output"]

#: format -> file suffix
FORMATS = {"mcap": ".mcap", "rerun": ".rrd"}


def export_run(
    run_dir: str | Path | RunRecord, out: str | Path | None = None, *, format: str = "mcap"
) -> Path:
    """Write a run directory as an MCAP file (Foxglove) or a Rerun recording.

    Parameters
    ----------
    run_dir : path or RunRecord
        A run directory (``conformal-control run``, ``--robots`` included), or the record
        :func:`read_run` read from one.
    out : path, optional
        The file to write; default ``RUN_DIR/run.mcap`` or ``RUN_DIR/run.rrd``. Never a
        file of the run directory (but an earlier export of the same format), a link or
        a device (:mod:`conformal_control.export.destination`).
    format : {"mcap", "rerun"}

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
    rec = run_dir if isinstance(run_dir, RunRecord) else read_run(run_dir)
    target = Path(out) if out is not None else rec.path / f"run{FORMATS[format]}"
    if format == "mcap":
        from .to_mcap import write_mcap

        return write_mcap(rec, target)
    from .to_rerun import write_rerun

    return write_rerun(rec, target)
