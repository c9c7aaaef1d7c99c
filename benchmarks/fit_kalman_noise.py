"""Fit the Kalman predictor's noise on ETH/UCY training windows (maximum likelihood).

For each model (cv, ca) and each (process_noise, measurement_noise) on a grid, sums the
one-step-ahead predictive log-likelihood of every 20-sample window (0.4 s apart) of a
seeded subsample of ``<scene>/train`` (default ``eth``: the other four scenes), and
prints the best pair and its 8 -> 12 ADE/FDE on the same windows. Usage::

    python benchmarks/fit_kalman_noise.py --data-root ../shared/data --windows 1000
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np
from cc_kalman import KalmanPredictor

from conformal_control.predictors.base import PredictionQuery
from conformal_control.predictors.evaluation import evaluate_predictor, training_windows

Q_GRID = (0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)
R_GRID = (0.001, 0.003, 0.01, 0.03, 0.1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-root", default=None)
    ap.add_argument("--scene", default="eth", help="use <scene>/train")
    ap.add_argument("--windows", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    win = training_windows(f"ethucy:{args.scene}", args.data_root).subsample(
        args.windows, args.seed
    )
    full = np.concatenate([win.history, win.future], axis=1)
    query = PredictionQuery(np.arange(len(win)), full, dt=win.dt, horizon=1)
    print(f"{len(win)} windows of {win.source}")
    for model in ("cv", "ca"):
        best = None
        for q, r in itertools.product(Q_GRID, R_GRID):
            _, ll = KalmanPredictor(model, q, r).filter(query)
            if best is None or ll > best[0]:
                best = (ll, q, r)
        ll, q, r = best
        res = evaluate_predictor(KalmanPredictor(model, q, r), win)
        print(
            f"{model}: process_noise={q} measurement_noise={r} "
            f"loglik/obs={ll / (full.shape[0] * (full.shape[1] - 1)):.3f}  "
            f"train ADE {res['ade']:.3f} FDE {res['fde']:.3f}"
        )


if __name__ == "__main__":
    main()
