"""Cold vs warm darts forecasts on nexus_4: the persistent cache skips every refit.

Runs the flagship episode twice with the darts predictor (the paper's VARIMA) and a fresh
cache folder, and prints the wall time and fit counts of each run. Usage::

    python benchmarks/bench_darts_cache.py --data-root ../shared/data --frames 40 --n-jobs 2
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--data-root", default=None)
    ap.add_argument("--scene", default="nexus_4")
    ap.add_argument("--frames", type=int, default=40, help="simulated frames (short window)")
    ap.add_argument("--n-jobs", type=int, default=2)
    ap.add_argument("--cache-dir", default=None, help="default: a fresh temporary folder")
    args = ap.parse_args()
    cache = args.cache_dir or tempfile.mkdtemp(prefix="cc-darts-cache-")
    os.environ["CONFORMAL_CONTROL_CACHE"] = cache

    from conformal_control.data import load_scene
    from conformal_control.runs.episode import run_episode

    scene = load_scene(args.scene, args.data_root)
    rows = []
    for label in ("cold", "warm"):
        t0 = time.perf_counter()
        res = run_episode(
            scene, "darts", max_frames=args.frames, predictor_params={"n_jobs": args.n_jobs}
        )
        wall = time.perf_counter() - t0
        info = res.metrics.get("predictor_info", {})
        rows.append((label, wall, info))
        print(
            f"{label}: {wall:7.2f} s  fitted={info.get('n_fitted')} cached={info.get('n_cached')} "
            f"short={info.get('n_short_history')} degenerate={info.get('n_degenerate')} "
            f"failed={info.get('n_fit_failed')}  l_avg={res.metrics['l_avg']:.4f}"
        )
    print(f"cache: {cache}; speed-up x{rows[0][1] / max(rows[1][1], 1e-9):.1f}")


if __name__ == "__main__":
    main()
