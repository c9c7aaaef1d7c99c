"""The core ``var`` predictor against darts' VARIMA on the same windows: fit time, forecasts.

Windows are the last ``fit_window`` = 50 positions (30 fps) of seeded random
(pedestrian, frame) pairs of an SDD scene (default nexus_4), kept when the paper's
VARIMA(10, 1, 'c') would be fitted on them (33+ finite samples, not degenerate). Prints

* ``var`` fit + 80-step forecast time per window (batched over all windows, and one
  window per call as the controller's per-agent cost);
* darts' time per window on the first ``--darts-windows`` windows, fitted in a
  subprocess (``cc_darts``' own worker, one BLAS thread), and the ratio, same run;
* the distance between the two forecasts over the first tau steps and over 80 steps
  (median and max over windows), and each one's ADE against the true future beside
  constant velocity's (window 5);
* how many windows conditional least squares (OLS, statsmodels ``VAR``'s estimator) fits
  with an explosive companion matrix (spectral radius >= 1), against Yule–Walker.

``benchmarks/run_all.py`` reuses :func:`windows_from_scene`, :func:`time_var` and
:func:`time_darts`. Usage::

    python benchmarks/bench_var.py --data-root ../shared/data --darts-windows 5
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from conformal_control.data.scenes import load_scene
from conformal_control.predictors.base import PredictionQuery
from conformal_control.predictors.var import VARPredictor, companion

DARTS_WORKER = """
import json, sys, time
import numpy as np
from cc_darts.predictor import _fit_one
data = np.load(sys.argv[1])
windows, horizon = data["windows"], int(data["horizon"])
out, wall, cpu, errors = [], [], [], []
for w in windows:
    t0, c0 = time.perf_counter(), time.process_time()
    pred, err = _fit_one("VARIMA", {"p": 10, "d": 1, "trend": "c"}, w, horizon)
    wall.append(time.perf_counter() - t0)
    cpu.append(time.process_time() - c0)
    errors.append(err)
    out.append(np.full((horizon, 2), np.nan) if pred is None else pred)
np.save(sys.argv[2], np.stack(out))
print(json.dumps({"wall": wall, "cpu": cpu, "errors": errors}))
"""


def windows_from_scene(
    scene, n: int, length: int, ahead: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Seeded (n, length, 2) windows VARIMA(10, 1) would be fitted on, and the (n, ahead, 2)
    true futures (windows whose pedestrian is observed for ``ahead`` more frames)."""
    pos = scene.positions  # (F, M, 2)
    ok = np.isfinite(pos).all(axis=-1)
    # a window ending at frame f is usable when frames f-length+1..f+ahead are all finite
    run = np.zeros_like(ok, dtype=int)
    for f in range(pos.shape[0]):
        run[f] = np.where(ok[f], (run[f - 1] if f else 0) + 1, 0)
    ends = np.argwhere(run >= length + ahead) - [ahead, 0]
    rng = np.random.default_rng(seed)
    hist, fut = [], []
    for f, m in ends[rng.permutation(len(ends))]:
        w = pos[f - length + 1 : f + 1, m]
        d = np.diff(w, axis=0)
        if np.ptp(w, axis=0).min() < 1e-9 or np.ptp(d, axis=0).min() < 1e-9:
            continue  # degenerate: both predictors fall back to constant velocity
        hist.append(w)
        fut.append(pos[f + 1 : f + 1 + ahead, m])
        if len(hist) == n:
            break
    return np.stack(hist), np.stack(fut)


def var_forecast(windows: np.ndarray, horizon: int, dt: float) -> np.ndarray:
    q = PredictionQuery(np.arange(len(windows)), windows, dt=dt, horizon=horizon)
    fc = VARPredictor().predict(q)
    assert fc.info["n_fitted"] == len(windows), fc.info
    return fc.positions


def ols_radius(windows: np.ndarray, p: int = 10) -> np.ndarray:
    """Spectral radius of conditional-least-squares VAR(p) fits (with a constant)."""
    radii = []
    for w in windows:
        d = np.diff(w, axis=0)
        y = d[p:]
        x = np.hstack([np.ones((len(y), 1))] + [d[p - k : len(d) - k] for k in range(1, p + 1)])
        beta = np.linalg.lstsq(x, y, rcond=None)[0]  # (1 + 2p, 2)
        coefs = beta[1:].reshape(p, 2, 2).transpose(0, 2, 1)
        radii.append(np.abs(np.linalg.eigvals(companion(coefs[None])[0])).max())
    return np.array(radii)


def constant_velocity(windows: np.ndarray, horizon: int, window: int = 5) -> np.ndarray:
    v = (windows[:, -1] - windows[:, -1 - window]) / window
    return windows[:, -1][:, None] + np.arange(1, horizon + 1)[None, :, None] * v[:, None]


def ade(pred: np.ndarray, truth: np.ndarray, steps: int) -> float:
    return float(np.linalg.norm(pred[:, :steps] - truth[:, :steps], axis=-1).mean())


def spread(a: np.ndarray, b: np.ndarray, steps: int) -> tuple[float, float]:
    """Median and max over windows of the largest distance over the first ``steps``."""
    dist = np.linalg.norm(a[:, :steps] - b[:, :steps], axis=-1).max(axis=1)
    return float(np.median(dist)), float(dist.max())


def time_var(windows: np.ndarray, horizon: int, dt: float) -> dict:
    """``var``'s fit + forecast time per window: all windows in one call, and one per call.

    Returns ``batched_s``, ``batched_cpu_s``, ``single_s``, ``single_cpu_s`` (seconds per
    window, wall and process CPU time) and the batched ``forecasts``.
    """
    var_forecast(windows[:2], horizon, dt)  # warm-up
    t0, c0 = time.perf_counter(), time.process_time()
    forecasts = var_forecast(windows, horizon, dt)
    batched = (time.perf_counter() - t0) / len(windows)
    batched_cpu = (time.process_time() - c0) / len(windows)
    k = min(len(windows), 100)
    t0, c0 = time.perf_counter(), time.process_time()
    for i in range(k):
        var_forecast(windows[i : i + 1], horizon, dt)
    single = (time.perf_counter() - t0) / k
    single_cpu = (time.process_time() - c0) / k
    return {
        "batched_s": batched,
        "batched_cpu_s": batched_cpu,
        "single_s": single,
        "single_cpu_s": single_cpu,
        "forecasts": forecasts,
    }


def time_darts(windows: np.ndarray, horizon: int) -> dict:
    """darts' VARIMA(10, 1, 'c') fit + forecast per window, in a subprocess (``cc_darts``).

    Returns ``wall_s`` and ``cpu_s`` (mean per window, imports excluded), ``process_s``
    (the whole subprocess), ``failed`` (fits that failed) and the ``forecasts`` (NaN rows
    for failed fits).
    """
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "in.npz"
        dst = Path(tmp) / "out.npy"
        np.savez(src, windows=windows, horizon=horizon)
        t0 = time.perf_counter()
        res = subprocess.run(
            [sys.executable, "-c", DARTS_WORKER, str(src), str(dst)],
            check=True,
            capture_output=True,
            text=True,
        )
        total = time.perf_counter() - t0
        stats = json.loads(res.stdout.strip().splitlines()[-1])
        forecasts = np.load(dst)
    return {
        "wall_s": float(np.mean(stats["wall"])),
        "cpu_s": float(np.mean(stats["cpu"])),
        "process_s": total,
        "failed": sum(1 for e in stats["errors"] if e),
        "forecasts": forecasts,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--data-root", default=None, help="folder holding sdd/ (default: ours)")
    ap.add_argument("--scene", default="nexus_4")
    ap.add_argument("--windows", type=int, default=500, help="windows for var and OLS")
    ap.add_argument("--darts-windows", type=int, default=5)
    ap.add_argument("--horizon", type=int, default=80)
    ap.add_argument("--taus", type=int, nargs="*", default=[4, 8])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--save", default=None, help="write the forecasts to this .npz")
    args = ap.parse_args()
    sdd = None if args.data_root is None else str(Path(args.data_root) / "sdd")
    scene = load_scene(args.scene, sdd)
    dt = 1.0 / scene.fps
    win, truth = windows_from_scene(scene, args.windows, 50, args.horizon, args.seed)
    print(
        f"{len(win)} windows of 50 samples with {args.horizon} true future samples, "
        f"{args.scene} at {scene.fps:g} fps, seed {args.seed}"
    )

    t = time_var(win, args.horizon, dt)
    var_all, batched, batched_cpu = t["forecasts"], t["batched_s"], t["batched_cpu_s"]
    single, single_cpu = t["single_s"], t["single_cpu_s"]
    print(
        f"var:   {1e6 * batched:8.1f} us/window batched ({len(win)} in one call; "
        f"{1e6 * batched_cpu:.1f} CPU-us), {1e6 * single:8.1f} us/window one per call "
        f"({1e6 * single_cpu:.1f} CPU-us)"
    )
    cv = constant_velocity(win, args.horizon)
    for steps in [*args.taus, args.horizon]:
        print(
            f"ADE vs truth over {steps:3d} steps, all {len(win)} windows: "
            f"var {100 * ade(var_all, truth, steps):6.2f} cm, "
            f"constant velocity {100 * ade(cv, truth, steps):6.2f} cm"
        )

    r_ols = ols_radius(win)
    yw = np.abs(np.linalg.eigvals(companion(_yw_coefs(win)))).max(axis=1)
    print(
        f"explosive fits (companion spectral radius >= 1): conditional least squares "
        f"{int((r_ols >= 1).sum())} of {len(win)}, Yule-Walker {int((yw >= 1).sum())} of "
        f"{len(win)} (largest radius {yw.max():.4f})"
    )

    nd = min(args.darts_windows, len(win))
    if nd == 0:
        return
    d = time_darts(win[:nd], args.horizon)
    darts, total, fit_wall, fit_cpu = d["forecasts"], d["process_s"], d["wall_s"], d["cpu_s"]
    failed = d["failed"]
    print(
        f"darts: {1e6 * fit_wall:8.0f} us/window wall ({1e6 * fit_cpu:.0f} CPU-us) on {nd} "
        f"windows (subprocess {total:.1f} s with imports; {failed} failed fits)"
    )
    print(
        f"ratio darts / var: x{fit_wall / batched:,.0f} wall (x{fit_cpu / batched_cpu:,.0f} CPU) "
        f"batched, x{fit_wall / single:,.0f} wall (x{fit_cpu / single_cpu:,.0f} CPU) one "
        "window per call"
    )
    good = np.isfinite(darts).all(axis=(1, 2))
    a, b, c, tr = var_all[:nd][good], darts[good], cv[:nd][good], truth[:nd][good]
    for steps in [*args.taus, args.horizon]:
        med, mx = spread(a, b, steps)
        print(
            f"|var - darts| over {steps:3d} steps: median {100 * med:6.2f} cm, "
            f"max {100 * mx:6.2f} cm; ADE vs truth: var {100 * ade(a, tr, steps):6.2f}, "
            f"darts {100 * ade(b, tr, steps):6.2f}, constant velocity "
            f"{100 * ade(c, tr, steps):6.2f} cm ({int(good.sum())} windows)"
        )
    if args.save:
        np.savez(args.save, windows=win[:nd], truth=truth[:nd], var=var_all[:nd], darts=darts)


def _yw_coefs(win: np.ndarray, p: int = 10) -> np.ndarray:
    from conformal_control.predictors.var import fit_var_yule_walker

    d = np.diff(win, axis=1)
    coefs, _, _ = fit_var_yule_walker(d, np.ones(d.shape[:2], bool), p)
    return coefs


if __name__ == "__main__":
    main()
