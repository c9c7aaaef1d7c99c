"""``conformal-control export``: a run directory as an MCAP file (Foxglove) or a Rerun recording."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from . import command


@command("export", "write a run directory as an MCAP file (Foxglove) or a Rerun recording (.rrd)")
def _export_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN_DIR", help="run directory written by `run`")
    p.add_argument(
        "--format",
        choices=("mcap", "rerun", "ros2-bag"),
        default="mcap",
        help="mcap: for Foxglove (and any MCAP reader); rerun: a .rrd recording (needs the "
        "rerun extra: pip install 'conformal-control[rerun]'); ros2-bag: a ROS 2 bag folder "
        "of ROS 2 messages, as ros2 bag record writes it (needs the ros extra)",
    )
    p.add_argument(
        "--schema",
        choices=("foxglove", "ros2"),
        default="foxglove",
        help="for --format mcap: Foxglove's JSON schemas (default), or ROS 2 messages "
        "(geometry_msgs, std_msgs, visualization_msgs; needs the ros extra) for ros2 bag "
        "play, rqt and ROS-typed panels",
    )
    p.add_argument(
        "--out",
        default=None,
        help="output file (default RUN_DIR/run.mcap, RUN_DIR/run_ros2.mcap with --schema "
        "ros2, RUN_DIR/run.rrd) or, for ros2-bag, a new folder (default RUN_DIR/run_ros2_bag)",
    )
    p.add_argument(
        "--start-time",
        default=None,
        metavar="ISO8601",
        help="date and time the run's first frame is shown at, e.g. 2026-05-04T09:30:00Z "
        "(no time zone: UTC; `now`: this moment); unset: MCAP shows the run from the Unix "
        "epoch (1970-01-01, the same file for the same run), Rerun as time since the start",
    )


@_export_args.handler
def _export(args: argparse.Namespace) -> int:
    from ...io.export import export_run, read_run

    rec = read_run(args.run_dir)  # read once, checked (one-line errors for a damaged folder)
    start: Any = args.start_time
    if start is not None and start.strip().lower() == "now":
        import datetime

        start = datetime.datetime.now(datetime.timezone.utc)
    if start is not None:
        from ...io.export.to_mcap import start_time_ns

        start_time_ns(start)  # a bad date is one line, before anything is written
    out = export_run(rec, args.out, format=args.format, schema=args.schema, start_time=start)
    path = Path(out)
    files = [f for f in path.rglob("*") if f.is_file()] if path.is_dir() else [path]
    size = sum(f.stat().st_size for f in files)
    robots = ", ".join(r.name for r in rec.robots)
    frames = max(r.trajectory["t"].size for r in rec.robots)
    print(f"{rec.scene}: {robots}, {frames} frames -> {out} ({size / 1e3:.0f} kB)")
    if not rec.has_scene:
        print(
            "note: no animation.npz in the run directory: pedestrians, predictions and the "
            "robot's body are not in the file (only poses, states and intervals)"
        )
    return 0
