"""The benchmark at the edges (issue 30): collisions, fallback, speed toward the goal by lambda.

Reads a ``bench run`` folder (its ``results.jsonl`` and the runs' ``metrics.json``) and
prints, per shift and method: scenarios, success, reach, collision frames per scenario,
collision events, the mean penetration depth of an event (its deepest intrusion
``d_c - d``, m), the mean duration of an event (s) and the fallback share (control
instants decided by the fallback). With ``--lambda-table`` it also re-runs, one by one
with the per-instant record (``run_episode`` on the loop engine), ``conformal`` under
``delay-0.5s`` in the scenarios where it misses the goal and the dev-tuned fixed lambda
reaches it (or the scenarios of ``--scenarios``), and prints the share of control
instants the fallback decided, lambda's median and the share of episodes below the
feasibility floor, and the robot's speed toward the goal binned by lambda (1/s), as
issue 30 measured them; ``--extend S`` re-runs them with a time limit of S seconds too.

    python benchmarks/edges.py BENCH_FOLDER [--lambda-table] [--extend 14] [--data-root DIR]

Set ``PYTHONPATH`` to another checkout to measure it (the figures of main before the edge
rule were taken that way).
"""

from __future__ import annotations

import argparse
import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

#: lambda bins (1/s) of the speed-toward-goal table, as issue 30 has them
BINS = ((-5.0, math.inf), (-15.0, -5.0), (-30.0, -15.0), (-50.0, -30.0), (-math.inf, -50.0))


def rows(folder: Path) -> list[dict[str, Any]]:
    out = []
    with (folder / "results.jsonl").open() as fh:
        for line in fh:
            r = json.loads(line)
            if r.get("status") == "ok":
                out.append(r)
    return out


def events(folder: Path, r: dict[str, Any]) -> list[dict[str, Any]]:
    if not r["metrics"].get("n_collision_events"):
        return []
    m = json.loads((folder / r["run_dir"] / "metrics.json").read_text())
    return list(m.get("collision_events") or [])


def summary(folder: Path) -> None:
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows(folder):
        meta = r["config"]["meta"]
        groups[(meta["shift"], meta["method"])].append(r)
    print(
        "| shift | method | n | success | reached | collision frames | events | "
        "mean penetration (m) | mean event duration (s) | fallback share |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for (shift, method), rs in sorted(groups.items()):
        m = [r["metrics"] for r in rs]
        ev = [e for r in rs for e in events(folder, r)]
        fps = float(rs[0]["config"]["meta"].get("lambda_unit_si") or 30.0)
        pen = np.mean([e["penetration"] for e in ev]) if ev else math.nan
        dur = np.mean([e["frames"] / fps for e in ev]) if ev else math.nan
        steps = sum(x["n_steps"] for x in m)
        share = sum(x["n_fallback"] for x in m) / steps if steps else math.nan
        print(
            f"| {shift} | {method} | {len(m)} | {np.mean([x['success'] for x in m]):.1%} | "
            f"{np.mean([x['goal_reached'] for x in m]):.1%} | "
            f"{np.mean([x['n_collide'] for x in m]):.2f} | {len(ev)} | {pen:.3f} | "
            f"{dur:.3f} | {share:.1%} |"
        )


def missed(folder: Path) -> list[dict[str, Any]]:
    """The delay-0.5s conformal rows whose scenario the dev-tuned fixed lambda reaches."""
    conf: dict[str, dict[str, Any]] = {}
    fixed: dict[str, bool] = {}
    for r in rows(folder):
        meta = r["config"]["meta"]
        if meta["shift"] != "delay-0.5s":
            continue
        if meta["family"] == "conformal":
            conf[meta["scenario"]] = r
    # the fixed family's dev-tuned setting (bench.json's tuned values)
    tuned = json.loads((folder / "bench.json").read_text()).get("tuned") or {}
    lam = (tuned.get("values") or {}).get("fixed")
    for r in rows(folder):
        meta = r["config"]["meta"]
        if meta["shift"] == "delay-0.5s" and meta["family"] == "fixed":
            if lam is not None and meta["method"] == f"fixed[lambda={lam:g}/s]":
                fixed[meta["scenario"]] = bool(r["metrics"]["goal_reached"])
    return [
        r
        for sc, r in sorted(conf.items())
        if not r["metrics"]["goal_reached"] and fixed.get(sc, False)
    ]


def rerun(cfg: dict[str, Any], data_root: str | None, seconds: float | None) -> Any:
    from conformal_control.experiments.plan import SweepRun
    from conformal_control.experiments.worker import cached_scene
    from conformal_control.runs.episode import run_episode

    run = SweepRun.from_dict(cfg)
    scene = cached_scene(run.scene, data_root or run.data_root, 0)
    frames = scene.meta.get("max_frames")
    if seconds is not None:
        frames = round(seconds * scene.fps)
    return run_episode(scene, run.spec_on(frames), engine="loop")


def lambda_table(folder: Path, data_root: str | None, extend: float | None) -> None:
    chosen = missed(folder)
    print(
        f"\ndelay-0.5s: {len(chosen)} scenarios where conformal misses the goal and the "
        "dev-tuned fixed lambda reaches it"
    )
    speed_by_bin: dict[int, list[float]] = defaultdict(list)
    total_by_bin: dict[int, list[float]] = defaultdict(list)
    med, low, below, fb, paths, reach_ext = [], [], [], [], [], 0
    for r in chosen:
        cfg = r["config"]
        unit = float(cfg["meta"].get("lambda_unit_si") or 1.0)
        res = rerun(cfg, data_root, None)
        floor = float(res.metrics.lambda_floor) * unit if res.metrics.lambda_floor else -math.inf
        goal = np.asarray(res.scene.goals[-1], dtype=float)
        t = np.asarray(res.steps["t"], dtype=float)
        x = np.asarray(res.steps["x"], dtype=float)
        iv = res.intervals
        starts = np.array([float(i["t"]) for i in iv])
        lams = np.array([float(i["lambda"]) for i in iv]) * unit
        k = np.clip(np.searchsorted(starts, t - 1e-9, side="right") - 1, 0, len(iv) - 1)
        lam_t = lams[k]
        to_goal = goal - x[:, :2]
        dist = np.hypot(to_goal[:, 0], to_goal[:, 1])
        v = x[:, 2:4]
        toward = np.einsum("ij,ij->i", v, to_goal) / np.maximum(dist, 1e-9)
        total = np.hypot(v[:, 0], v[:, 1])
        for b, (lo, hi) in enumerate(BINS):
            sel = (lam_t >= lo) & (lam_t < hi) if math.isfinite(hi) else lam_t >= lo
            speed_by_bin[b].extend(toward[sel].tolist())
            total_by_bin[b].extend(total[sel].tolist())
        med.append(float(np.median(lams)))
        low.append(float(lams.min()))
        below.append(bool((lams < floor).any()))
        fb.append(res.metrics.fallback_share)
        paths.append(res.metrics.path_length)
        if extend is not None:
            reach_ext += bool(rerun(cfg, data_root, extend).metrics.goal_reached)
    if not chosen:
        return
    print(f"fallback share (mean over the episodes): {np.mean(fb):.1%}")
    print(
        f"lambda: median over the episodes of their median {np.median(med):.1f}/s, of their "
        f"lowest {np.median(low):.1f}/s; below the feasibility floor in "
        f"{np.mean(below):.0%} of the episodes"
    )
    print(f"path length: mean {np.mean(paths):.1f} m")
    if extend is not None:
        print(f"reach the goal given {extend:g} s: {reach_ext} of {len(chosen)}")
    print("\n| lambda (1/s) | control instants | speed toward the goal (m/s) | speed (m/s) |")
    print("|---|---:|---:|---:|")
    for b, (lo, hi) in enumerate(BINS):
        s = speed_by_bin[b]
        name = (
            f"{lo:g} ... {hi:g}"
            if math.isfinite(lo) and math.isfinite(hi)
            else (f"above {lo:g}" if math.isfinite(lo) else f"below {hi:g}")
        )
        if s:
            print(f"| {name} | {len(s)} | {np.mean(s):+.2f} | {np.mean(total_by_bin[b]):.2f} |")
        else:
            print(f"| {name} | 0 | - | - |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("folder", type=Path)
    ap.add_argument("--lambda-table", action="store_true")
    ap.add_argument("--extend", type=float, default=None)
    ap.add_argument("--data-root", default=None)
    args = ap.parse_args()
    summary(args.folder)
    if args.lambda_table:
        lambda_table(args.folder, args.data_root, args.extend)


if __name__ == "__main__":
    main()
