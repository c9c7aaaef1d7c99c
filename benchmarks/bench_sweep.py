"""Sweep throughput: the same grid on the serial, process-pool and Dask executors.

    python benchmarks/bench_sweep.py --data-root ../shared/data/sdd [--runs 16] [--workers 2]

Prints wall time and runs per second for each executor (fresh output folders, no plots),
and the time of a resumed sweep (every run skipped). Needs the `sweep` extra for Dask.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from conformal_control.experiments import SweepSpec, run_sweep


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, allow_abbrev=False)
    ap.add_argument("--data-root", default=None)
    ap.add_argument("--runs", type=int, default=16, help="grid size (seeds x epsilons)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--executors", default="serial,process,dask")
    args = ap.parse_args()
    eps = [-0.3, -0.25, -0.2, -0.1]
    seeds = list(range(max(1, args.runs // len(eps))))
    spec = SweepSpec(
        base={"scene": "nexus_4", "data_root": args.data_root, "a": 10, "tau": 4, "eta": 1},
        grid={"epsilon": eps, "seed": seeds},
    )
    n = len(spec.expand())
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.executors.split(","):
            out = Path(tmp) / name
            t0 = time.perf_counter()
            rep = run_sweep(spec, out, name, workers=args.workers, plot=False, progress=False)
            wall = time.perf_counter() - t0
            t1 = time.perf_counter()
            run_sweep(spec, out, "serial", plot=False, progress=False)
            resume = time.perf_counter() - t1
            print(
                f"{name:8s} {n} runs in {wall:6.2f} s ({n / wall:5.2f} runs/s; "
                f"{len(rep.failed)} failed) on {rep.executor}; resume (all skipped) {resume:.2f} s"
            )


if __name__ == "__main__":
    main()
