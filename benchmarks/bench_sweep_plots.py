"""What per-run plots cost a sweep, and what the single summary plot costs instead.

    python benchmarks/bench_sweep_plots.py [--runs 12] [--frames 100] [--repeat 2]

Runs the same grid on the built-in ``crossing`` scene with the serial executor (in this
process, so pool start-up does not blur the figures) three ways, into fresh folders:
per-run plots and no summary (the old default), no per-run plots and no summary, and no
per-run plots with the summary plot (the new default). Prints the best wall time of each
and its ratio to the run without any plot, timed in the same process after a warm-up run
that pays the imports.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from conformal_control.experiments import SweepSpec, run_sweep

#: the three ways the grid is run: run_sweep's plot keywords
WAYS = {
    "per-run plots (old default)": {"plot": True, "summary_plot": False},
    "no plots": {"plot": False, "summary_plot": False},
    "summary plot only (new default)": {"plot": False, "summary_plot": True},
}


def measure(runs: int, frames: int, repeat: int) -> tuple[int, dict[str, float]]:
    """The number of runs and the best wall time (s) of the grid for each of :data:`WAYS`."""
    eps = [-0.2, -0.1, 0.0, 0.1]
    seeds = list(range(max(1, runs // len(eps))))
    spec = SweepSpec(
        base={"scene": "crossing", "frames": frames}, grid={"epsilon": eps, "seed": seeds}
    )
    n = len(spec.expand())
    with tempfile.TemporaryDirectory() as tmp:
        # warm-up: imports, matplotlib, scene generation caches
        run_sweep(spec, Path(tmp) / "warm", "serial", plot=True, progress=False)
        best: dict[str, float] = {}
        for r in range(repeat):
            for i, (name, kw) in enumerate(WAYS.items()):
                out = Path(tmp) / f"{r}-{i}"
                t0 = time.perf_counter()
                run_sweep(spec, out, "serial", progress=False, **kw)
                wall = time.perf_counter() - t0
                best[name] = min(best.get(name, wall), wall)
    return n, best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, allow_abbrev=False)
    ap.add_argument("--runs", type=int, default=12, help="grid size (epsilons x seeds)")
    ap.add_argument("--frames", type=int, default=100, help="frames simulated per run")
    ap.add_argument("--repeat", type=int, default=2, help="best of N")
    args = ap.parse_args()
    n, best = measure(args.runs, args.frames, args.repeat)
    base = best["no plots"]
    print(f"{n} runs of {args.frames} frames on crossing, serial executor, best of {args.repeat}")
    for name, wall in best.items():
        print(f"  {name:34s} {wall:7.2f} s  ({wall / n:5.3f} s/run; {wall / base:5.2f}x no plots)")
    share = 1 - base / best["per-run plots (old default)"]
    print(f"  share of the old default's time spent on per-run plots: {share:.0%}")


if __name__ == "__main__":
    main()
