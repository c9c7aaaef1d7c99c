"""The floor margin of people-first fleets on issue 36's subset: fleets against their robots
alone, with and without the margin.

Usage::

    python benchmarks/fleet_floor.py OUT [--robots 10] [--methods nolearn,conformal]
        [--margins 0.1,0] [--cores always,inside,none] [--data-root DIR] [--workers 1]
        [--whole-split] [--entries ID,ID] [--predicted] [--grids mpc=0]

The subset is the first scenario of each test recording of the shipped multi-robot suite
(``multi-crossings-v1``) under the ``swap`` and ``cross`` layouts: 28 entries. For each
method it runs the robots alone (``solo``) once and the reciprocal fleet (people first,
the default) once per floor margin (with ``--cores``: per margin and floor-core setting),
each in its own folder under ``OUT`` (a run already there resumes), and prints one row
per (robots, method, arm): pedestrian collision frames (with the ratio to the robots
alone), of them avoidable / with another robot within 2.5 m, robot pair-frames (episodes
with any), goal rate and deadlocked robots, summed over the entries every arm of that
method has. ``--predicted`` adds the fleet whose robots predict each other like
pedestrians (``none``); ``--grids`` gives the methods' settings (e.g. ``mpc=0``, the
sampling MPC with margin 0). ``--whole-split``: every test entry of the suite (96)
instead of the subset; ``--entries``: only these test entries (ids of the suite, e.g. the
whole split's worst).
"""

from __future__ import annotations

import argparse
import json
import os
from collections import defaultdict
from pathlib import Path
from typing import Any

from conformal_control.core.spec import Robots, RunSpec
from conformal_control.experiments.bench.multi import _manifest_dir, run_multi_bench

ROOT = Path(__file__).resolve().parents[1]
LAYOUTS = ("swap", "cross")


def subset_manifest(path: Path, whole: bool = False, only: list[str] | None = None) -> Path:
    """Write the 28-entry subset (first scenario of each test recording x swap, cross), or
    with ``whole`` every test entry, or with ``only`` those test entries."""
    m = json.loads((_manifest_dir() / "multi-crossings-v1.json").read_text())
    if whole or only:
        m["entries"] = [e for e in m["entries"] if e["split"] == "test"]
        if only:
            missing = sorted(set(only) - {e["id"] for e in m["entries"]})
            if missing:
                raise SystemExit(f"no test entry {', '.join(missing)} in multi-crossings-v1")
            m["entries"] = [e for e in m["entries"] if e["id"] in only]
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(m, indent=1))
        return path
    first: dict[str, str] = {}
    for e in m["entries"]:
        if e["split"] == "test":
            first.setdefault(e["recording"], e["scenario"])
    keep = set(first.values())
    m["entries"] = [e for e in m["entries"] if e["scenario"] in keep and e["layout"] in LAYOUTS]
    m["rule"] = "issue 36 subset: " + ", ".join(LAYOUTS) + " of the first test scenario each"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(m, indent=1))
    return path


def table(folders: list[Path], entries: set[str]) -> list[str]:
    """Markdown rows: sums over the entries every arm of a (robots, method) has."""
    rows: dict[tuple[Any, ...], dict[str, Any]] = {}
    for folder in folders:
        arm_name = folder.name
        for line in (folder / "results.jsonl").read_text().splitlines():
            r = json.loads(line)
            if r.get("status") != "ok" or r["entry"] not in entries:
                continue
            arm = r["reciprocity"] if r["reciprocity"] in ("solo", "none") else arm_name
            rows[(r["robots"], r["method"], arm, r["entry"])] = r
    by: dict[tuple[Any, Any], dict[str, set[str]]] = defaultdict(lambda: defaultdict(set))
    for n, method, arm, entry in rows:
        by[(n, method)][arm].add(entry)
    out = []
    for (n, method), arms in sorted(by.items()):
        common = set.intersection(*arms.values())
        solo = sum(rows[(n, method, "solo", e)]["n_collide_pedestrian"] for e in common)
        for arm in sorted(arms):
            rs = [rows[(n, method, arm, e)] for e in sorted(common)]
            ped = sum(r["n_collide_pedestrian"] for r in rs)
            ratio = f"{ped / solo:.2f}" if solo and arm != "solo" else "-"
            pairs = sum(r["n_collide_robot_pairs"] for r in rs)
            n_ep = sum(r["n_collide_robot_pairs"] > 0 for r in rs)
            out.append(
                f"| {n} | {method} | {arm} | {len(rs)} | {ped} ({ratio}) | "
                f"{sum(r['n_collide_pedestrian_avoidable'] for r in rs)} / "
                f"{sum(r['n_collide_pedestrian_robot_near'] for r in rs)} | "
                f"{pairs} ({n_ep}) | {sum(r['goal_rate'] for r in rs) / len(rs):.3f} | "
                f"{sum(r['n_deadlocked'] for r in rs)} |"
            )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("out")
    ap.add_argument("--robots", default="10")
    ap.add_argument("--methods", default="nolearn,conformal")
    ap.add_argument("--margins", default="0.1,0")
    ap.add_argument(
        "--data-root",
        default=None,
        help="the data folder (default: $CONFORMAL_CONTROL_DATA, else ../shared/data)",
    )
    ap.add_argument(
        "--cores",
        default="",
        help="floor_core settings to run (comma-separated, e.g. always,inside,none; "
        "default: the run's default only)",
    )
    ap.add_argument(
        "--predicted",
        action="store_true",
        help="also the fleet whose robots predict each other like pedestrians (arm none)",
    )
    ap.add_argument(
        "--grids",
        default="",
        help="settings per family, e.g. 'mpc=0' (';' between families; default: the "
        "benchmark's tuned settings)",
    )
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--table-only", action="store_true", help="print the table of OUT only")
    ap.add_argument("--whole-split", action="store_true", help="every test entry, not the subset")
    ap.add_argument("--entries", default="", help="only these test entries (comma-separated ids)")
    args = ap.parse_args()
    data_root = args.data_root or os.environ.get("CONFORMAL_CONTROL_DATA")
    data_root = data_root or str(ROOT.parent / "shared" / "data")
    out = Path(args.out)
    only = [e for e in args.entries.split(",") if e]
    suite = subset_manifest(out / "subset.json", args.whole_split, only)
    entries = {e["id"] for e in json.loads(suite.read_text())["entries"]}
    robots = [int(x) for x in args.robots.split(",")]
    methods = args.methods.split(",")
    folders = [out / "solo"]
    cores = [c for c in args.cores.split(",") if c]
    arms: dict[str, dict[str, Any]] = {}
    for m in args.margins.split(","):
        for c in cores or [None]:
            name = f"floor_margin={float(m):g}" + ("" if c is None else f"-floor_core={c}")
            arms[name] = {"floor_margin": float(m), **({} if c is None else {"floor_core": c})}
    folders += [out / name for name in arms]
    if args.predicted:
        folders.append(out / "none")
    grids: dict[str, list[float]] = {}
    for g in [g for g in args.grids.split(";") if g]:
        fam, _, values = g.partition("=")
        grids[fam] = [float(v) for v in values.split(",")]
    for folder in folders if not args.table_only else []:
        arm = arms.get(folder.name)
        reciprocity = [folder.name] if folder.name in ("solo", "none") else ["reciprocal"]
        res = run_multi_bench(
            folder,
            robots=robots,
            suite=str(suite),
            split="test",
            methods=methods,
            reciprocity=reciprocity,
            grids=grids or None,
            base=None if arm is None else RunSpec(robots=Robots(**arm)),
            data_root=data_root,
            workers=args.workers,
            progress=print,
        )
        print(res.summary(), flush=True)
    print(
        "| robots | method | arm | entries | pedestrian frames (÷ solo) | avoidable / robot "
        "near | robot pair-frames (episodes) | goal rate | deadlocked |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    print("\n".join(table([f for f in folders if (f / "results.jsonl").exists()], entries)))


if __name__ == "__main__":
    main()
