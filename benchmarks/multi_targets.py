"""The multi-robot page's command against each of its robots alone: the issue's targets.

Usage::

    python benchmarks/multi_targets.py [--data-root ../shared/data] [--robots 10]

Runs ``conformal-control run --scene sdd:nexus/video3 --start 0.05,0.5 --goal 0.95,0.5
--robots M`` (through :func:`~conformal_control.runs.fleet.run_multi`, the command's
defaults: reciprocal rows, broadcast plans), then every robot's task alone (the same
start, goals and seed, no other robot), and prints

* the fleet's robot-robot collision pair-frames (target 0), pedestrian collision frames
  (target: no more than the robots alone, summed), goal rate (target >= 0.9) and
  deadlocked robots (target 0);
* the same fleet without reciprocity (each robot predicting the others), for reference.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from conformal_control.data import load_scene
from conformal_control.runs.fleet import robot_tasks, run_multi

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--data-root", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--robots", type=int, default=10)
    args = ap.parse_args()
    scene = load_scene("sdd:nexus/video3", args.data_root, start=(0.05, 0.5), goals=[(0.95, 0.5)])
    n = args.robots
    fleet = run_multi(scene, n, record_animation=False)
    none = run_multi(scene, n, record_animation=False, reciprocity="none", lambda_scope="both")
    starts, goals = robot_tasks(scene, n)
    alone = []
    for i in range(n):
        r = run_multi(
            scene, starts=starts[i : i + 1], goals=goals[i : i + 1], seed=i, record_animation=False
        )
        alone.append(r.robots[0].metrics.n_collide)
    m = fleet.metrics
    print(f"sdd:nexus/video3, {n} robots (the command's defaults)")
    print(f"  robot-robot collision pair-frames   {m.n_collide_robot_pairs}  (target 0)")
    print(
        f"  pedestrian collision frames         {m.n_collide_pedestrian}  (target <= "
        f"{sum(alone)}, the robots alone: {alone})"
    )
    print(f"  goal rate                           {m.goal_rate:.2f}  (target >= 0.9)")
    print(f"  deadlocked robots                   {m.n_deadlocked}  (target 0)")
    print(f"  closest robot pair                  {m.d_min_robot:.3f} m")
    k = none.metrics
    print(
        f"without reciprocity: robot pair-frames {k.n_collide_robot_pairs}, pedestrian frames "
        f"{k.n_collide_pedestrian}, goal rate {k.goal_rate:.2f}, deadlocked {k.n_deadlocked}, "
        f"closest robot pair {k.d_min_robot:.3f} m"
    )


if __name__ == "__main__":
    main()
