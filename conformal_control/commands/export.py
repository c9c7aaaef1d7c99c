"""``conformal-control export``: a run directory as an MCAP file (Foxglove) or a Rerun recording."""

from __future__ import annotations

import argparse
from pathlib import Path

from . import command


@command("export", "write a run directory as an MCAP file (Foxglove) or a Rerun recording (.rrd)")
def _export_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN_DIR", help="run directory written by `run`")
    p.add_argument(
        "--format",
        choices=("mcap", "rerun"),
        default="mcap",
        help="mcap: for Foxglove (and any MCAP reader); rerun: a .rrd recording (needs the "
        "rerun extra: pip install 'conformal-control[rerun]')",
    )
    p.add_argument(
        "--out", default=None, help="output file (default RUN_DIR/run.mcap or RUN_DIR/run.rrd)"
    )


@_export_args.handler
def _export(args: argparse.Namespace) -> int:
    from ..export import export_run, read_run

    rec = read_run(args.run_dir)  # read once, checked (one-line errors for a damaged folder)
    out = export_run(rec, args.out, format=args.format)
    size = Path(out).stat().st_size
    robots = ", ".join(r.name for r in rec.robots)
    frames = max(r.trajectory["t"].size for r in rec.robots)
    print(f"{rec.scene}: {robots}, {frames} frames -> {out} ({size / 1e3:.0f} kB)")
    if not rec.has_scene:
        print(
            "note: no animation.npz in the run directory: pedestrians, predictions and the "
            "robot's body are not in the file (only poses, states and intervals)"
        )
    return 0
