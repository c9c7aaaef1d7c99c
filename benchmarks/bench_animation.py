"""Peak memory of ``conformal-control animate`` against the number of frames (GIF or MP4).

A run of the built-in ``crossing`` scene (no data needed) is recorded once; its animation
record is then repeated end to end to N frames (time keeps increasing, the intervals with
their predictions are shifted along) and rendered at the scene's frame rate, so every run
frame becomes one output frame. Each N is rendered in a fresh subprocess, whose peak
resident set size (``ru_maxrss``) is printed with its ratio to the smallest N. A writer
that streams frames to the file keeps the peak flat; one that accumulates them grows
linearly. Usage::

    python benchmarks/bench_animation.py                      # GIF at 50, 200, 800 frames
    python benchmarks/bench_animation.py --frames 50 200 800 --format mp4
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np


def tile_record(rec: dict[str, Any], n_frames: int) -> dict[str, Any]:
    """The animation record repeated end to end until it has ``n_frames`` frames."""
    n = len(rec["t"])
    reps = -(-n_frames // n)
    out = dict(rec)
    dt = 1.0 / float(rec["fps"])
    span = n * dt
    out["t"] = np.concatenate([rec["t"] + r * span for r in range(reps)])[:n_frames]
    out["frame"] = np.arange(n_frames)
    for key in ("robot", "peds", "status", "h_true_min"):
        out[key] = np.concatenate([rec[key]] * reps)[:n_frames]
    k_start = np.concatenate([rec["k_start"] + r * n for r in range(reps)])
    keep = k_start < n_frames
    out["k_start"] = k_start[keep]
    for key in ("pred", "pred_cols", "lam", "loss"):
        out[key] = np.concatenate([rec[key]] * reps)[keep]
    return out


def _peak_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def child(run_dir: str, n_frames: int, out: str, dpi: int) -> None:
    """Render ``n_frames`` frames to ``out`` and print a JSON line with the figures."""
    import matplotlib

    matplotlib.use("Agg")
    from conformal_control.io.plotting.animation import load_record, render_animation

    rec = tile_record(load_record(run_dir), n_frames)
    before = _peak_rss_mb()
    t0 = time.perf_counter()
    n = render_animation(rec, out, fps=float(rec["fps"]), dpi=dpi, progress=False)
    wall = time.perf_counter() - t0
    print(
        json.dumps(
            {
                "frames": n,
                "peak_rss_mb": _peak_rss_mb(),
                "rss_before_mb": before,
                "wall_s": wall,
                "size_mb": Path(out).stat().st_size / 1e6,
            }
        )
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--frames", type=int, nargs="+", default=[50, 200, 800])
    ap.add_argument("--format", choices=("gif", "mp4"), default="gif")
    ap.add_argument("--dpi", type=int, default=80, help="80 = the CLI default (768 x 346 px)")
    ap.add_argument("--child", nargs=3, metavar=("RUN_DIR", "N", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child[0], int(args.child[1]), args.child[2], args.dpi)
        return

    from conformal_control.cli import main as cli

    with tempfile.TemporaryDirectory(prefix="cc-bench-anim-") as tmp:
        run = os.path.join(tmp, "run")
        if cli(["run", "--no-plot", "--out", run]) != 0:
            raise SystemExit("the crossing run failed")
        rows = []
        for n in sorted(args.frames):
            out = os.path.join(tmp, f"anim-{n}.{args.format}")
            cmd = [sys.executable, __file__, "--child", run, str(n), out, "--dpi", str(args.dpi)]
            proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
            if proc.returncode != 0:
                raise SystemExit(f"rendering {n} frames failed:\n{proc.stderr}")
            rows.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    base = rows[0]
    print(f"\n{args.format.upper()} output, dpi {args.dpi}, one subprocess per row")
    print("frames | peak RSS (MB) | ratio | RSS before rendering (MB) | wall (s) | file (MB)")
    print("---:|---:|---:|---:|---:|---:")
    for r in rows:
        ratio = r["peak_rss_mb"] / base["peak_rss_mb"]
        print(
            f"{r['frames']} | {r['peak_rss_mb']:.0f} | x{ratio:.2f}"
            f" | {r['rss_before_mb']:.0f} | {r['wall_s']:.1f} | {r['size_mb']:.2f}"
        )


if __name__ == "__main__":
    main()
