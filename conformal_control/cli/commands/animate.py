"""``conformal-control animate``: render a finished run as a GIF or an MP4."""

from __future__ import annotations

import argparse
from pathlib import Path

from . import command


@command("animate", "render a finished run (its run directory) as a GIF or MP4 animation")
def _animate_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN_DIR", help="run directory written by `run`")
    p.add_argument(
        "--out",
        default=None,
        help="output file, .gif or .mp4 (default RUN_DIR/animation.gif)",
    )
    p.add_argument("--start", type=float, default=None, help="start of the time window (s)")
    p.add_argument("--end", type=float, default=None, help="end of the time window (s)")
    p.add_argument(
        "--fps", type=float, default=10.0, help="output frames per second (real-time playback)"
    )
    p.add_argument("--width", type=float, default=9.6, help="figure width in inches")
    p.add_argument("--dpi", type=int, default=80, help="pixels per inch")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


@_animate_args.handler
def _animate(args: argparse.Namespace) -> int:
    from ...io.plotting.animation import render_animation

    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"run directory {run_dir} does not exist")
    out = Path(args.out) if args.out else run_dir / "animation.gif"
    n = render_animation(  # one robot or several (--robots): the record says which
        run_dir,
        out,
        start=args.start,
        end=args.end,
        fps=args.fps,
        width=args.width,
        dpi=args.dpi,
        progress=not (args.no_progress or getattr(args, "quiet", False)),
    )
    size = out.stat().st_size
    print(f"{n} frames written to {out} ({size / 1e6:.2f} MB)")
    return 0
