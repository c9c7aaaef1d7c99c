"""The ADE/FDE table of docs/predictors.md: every predictor on the five ETH/UCY test
scenes and on nexus_4 (8 observed, 12 predicted samples at 2.5 fps), via
``conformal-control eval-predictor``; rows are appended to ``OUT/results.csv``.

Learned predictors (lstm, sklearn) are trained on first use, leave-one-scene-out (ETH/UCY)
or on all of ETH/UCY (nexus_4), and cached. darts' VARIMA (and the core ``var``, the same
model structure) needs >= 33 samples, so it is evaluated with 33 observed samples on a
seeded subsample, beside constant velocity and ``var`` on the same windows. Usage::

    python benchmarks/predictor_table.py --data-root ../shared/data --out results/predictors
"""

from __future__ import annotations

import argparse
import time

from conformal_control.cli import main as cli

DATASETS = [f"ethucy:{s}" for s in ("eth", "hotel", "univ", "zara1", "zara2")] + ["sdd:nexus_4"]
ROWS: list[tuple[str, str, list[str]]] = [
    ("cv", "constant_velocity", ["--param", "window=1"]),
    ("cv_w5", "constant_velocity", []),
    ("kalman_cv", "kalman", ["--param", "model=cv"]),
    ("kalman_ca", "kalman", ["--param", "model=ca"]),
    ("sklearn_ridge", "sklearn", []),
    ("lstm", "lstm", []),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--data-root", default=None)
    ap.add_argument("--out", required=True)
    ap.add_argument("--only", nargs="*", default=None, help="labels to run (default all)")
    ap.add_argument("--darts-windows", type=int, default=30)
    ap.add_argument("--n-jobs", type=int, default=2)
    args = ap.parse_args()
    root = [] if args.data_root is None else ["--data-root", args.data_root]
    jobs = [(label, name, extra) for label, name, extra in ROWS]
    for obs_label, name, extra in (
        ("cv_obs33", "constant_velocity", ["--param", "window=1"]),
        ("var_obs33", "var", []),
        ("darts_varima_obs33", "darts", ["--param", f"n_jobs={args.n_jobs}"]),
    ):
        jobs.append(
            (obs_label, name, [*extra, "--obs", "33", "--max-windows", str(args.darts_windows)])
        )
    for label, name, extra in jobs:
        if args.only and label not in args.only:
            continue
        for ds in DATASETS:
            t0 = time.perf_counter()
            cli(
                [
                    "eval-predictor",
                    "--predictor",
                    name,
                    "--label",
                    label,
                    "--dataset",
                    ds,
                    *root,
                    *extra,
                    "--out",
                    args.out,
                ]
            )
            print(f"  [{label} {ds}: {time.perf_counter() - t0:.1f} s]", flush=True)


if __name__ == "__main__":
    main()
