"""The prediction error of each predictor shift at the CBF's horizon, on the test split.

Not a speed benchmark: the figures the Benchmark page quotes for its shift table. For every
pedestrian present at every 4th frame of every test scenario of ``crossings-v2`` (and 4
frames later), the distance between the position each shift's predictor predicts 4 frames
(0.133 s) ahead and the true one; ``learned`` on the scenarios it covers only.

Run: ``python benchmarks/shift_prediction_error.py [DATA_ROOT]``.
"""

from __future__ import annotations

import collections
import sys

import numpy as np

from conformal_control.core import registry
from conformal_control.experiments.bench import load_scenario, load_suite
from conformal_control.experiments.bench.shifts import SHIFTS
from conformal_control.predictors.base import PredictionQuery


def main(data_root: str = "../shared/data") -> None:
    suite = load_suite("crossings-v2")
    scs = suite.scenarios_for("test")
    preds = {}
    for name, sh in SHIFTS.items():
        pred, params = sh.predictor_for("constant_velocity", None, data_root)
        preds[name] = registry.create("predictor", pred, **(params or {}))
        preds[name].reset()
    err: dict[str, list[float]] = collections.defaultdict(list)
    H, T = 4, 120
    for sc in scs:
        scene = load_scenario(sc, data_root)
        pos = scene.positions
        f0 = scene.start_index
        for f in range(f0, min(f0 + sc.max_frames, scene.n_frames - H - 1), 4):
            ids = np.flatnonzero(np.isfinite(pos[f, :, 0]) & np.isfinite(pos[f + H, :, 0]))
            if not ids.size:
                continue
            lo = f - T + 1
            hist = np.full((ids.size, T, 2), np.nan)
            a = max(lo, 0)
            hist[:, a - lo :] = pos[a : f + 1, ids].transpose(1, 0, 2)
            q = PredictionQuery(
                scene.agent_ids[ids], hist, 1 / scene.fps, H,
                frame=scene.first_frame + f, scene=scene.name,
            )  # fmt: skip
            for name, p in preds.items():
                if not SHIFTS[name].covers(sc.recording):
                    continue
                out = p.predict(q).positions
                e = np.hypot(*(out[:, H - 1] - pos[f + H, ids]).T).tolist()
                err[name].extend(e)
                if name == "nominal" and SHIFTS["learned"].covers(sc.recording):
                    err["nominal (learned's)"].extend(e)
    for name, e in err.items():
        x = np.asarray(e)
        print(f"{name:20s} n {x.size:7d}  mean {x.mean():.3f} m  median {np.median(x):.3f} m")
    cov = [sc for sc in scs if SHIFTS["learned"].covers(sc.recording)]
    print(f"(learned covers {len(cov)} of the {len(scs)} test scenarios)")


if __name__ == "__main__":
    main(*sys.argv[1:])
