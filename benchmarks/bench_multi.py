"""Time per robot of a 20-robot run against the single-robot episode, same scene, same run.

Usage::

    python benchmarks/bench_multi.py [--data-root ../shared/data] [--robots 20] [--repeat 3]

Scene: SDD ``nexus_4`` (the paper's Table II scene and parameters), pedestrians replayed.
Baseline: the single-robot episode on the scene's own task (the flagship built by
``build_flagship``, its ``ConformalLoop`` timed). Multi-robot
(:func:`~conformal_control.runs.fleet.run_multi`, ``--robots`` robots, each its own
controller and lambda), in two layouts:

* ``swap``  -- the default layout: the scene's task rotated about its midpoint, so all the
  robots cross the centre together among the pedestrians (the worst case: the robots'
  constraints bind, QPs and fallbacks are frequent, episodes are longer);
* ``lanes`` -- the scene's task (right to left) and its reverse, alternately, on lanes
  evenly spaced over the middle half of the scene's height.

Timed: the control loop only (sensing, predicting, deciding, learning, stepping the world;
not building or measuring), best of ``--repeat``, in process CPU time and wall-clock time
(the machine may be shared: the load average is printed; CPU time is the figure to read).
Printed per layout: the time per robot and its ratio to the single-robot episode (target
<= 2), the time per robot-control-instant and its ratio (what one decision costs, whatever
the episode lengths), and the share of the loop spent outside the robots' controllers (the
world: plants, sensors, logs).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from conformal_control.core.jit import compile_now
from conformal_control.core.loop import ConformalLoop
from conformal_control.data import load_scene
from conformal_control.runs.build import build_flagship
from conformal_control.runs.fleet import run_multi

ROOT = Path(__file__).resolve().parents[1]


def single(scene) -> tuple[float, float, int]:
    """(CPU s, wall s, control instants) of the single-robot episode's loop."""
    fl = build_flagship(scene)
    loop = ConformalLoop(fl.env, fl.family, fl.loss, fl.rule)
    w0, c0 = time.perf_counter(), time.process_time()
    loop.run()
    return time.process_time() - c0, time.perf_counter() - w0, fl.family.n_steps_


def lanes(scene, n: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """Alternate right-to-left and left-to-right tasks on lanes over the middle half."""
    (x0, _), (x1, _) = scene.start, scene.goals[-1]
    h = scene.extent[1]
    ys = np.linspace(0.25 * h, 0.75 * h, n)
    starts = np.array([(x0 if i % 2 == 0 else x1, y) for i, y in enumerate(ys)])
    goals = [np.array([[x1 if i % 2 == 0 else x0, y]]) for i, y in enumerate(ys)]
    return starts, goals


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--data-root", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--scene", default="nexus_4")
    ap.add_argument("--robots", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    compile_now()  # timed compiled (see conformal_control.core.jit)
    scene = load_scene(args.scene, Path(args.data_root) / "sdd")
    n = args.robots
    print(
        f"scene {scene.name}: {scene.n_agents} pedestrians, {n} robots, load average "
        f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}"
    )
    layouts = {"swap": {"robots": n}}
    s, g = lanes(scene, n)
    layouts["lanes"] = {"starts": s, "goals": g}

    best_single = (np.inf, np.inf, 0)
    best = {k: None for k in layouts}
    for _ in range(args.repeat):
        best_single = min(best_single, single(scene))
        for name, kw in layouts.items():
            res = run_multi(scene, record_animation=False, **kw)
            m = res.metrics
            key = (m.cpu_s, m.wall_s)
            if best[name] is None or key < (best[name].metrics.cpu_s, best[name].metrics.wall_s):
                best[name] = res
    cpu1, wall1, steps1 = best_single
    print(f"single robot: loop {cpu1:.3f} s CPU ({wall1:.3f} s wall), {steps1} control instants")
    for name, res in best.items():
        m = res.metrics
        own = sum(r.metrics.wall_s for r in res.robots)
        print(
            f"{name:<6} {n} robots: loop {m.cpu_s:.3f} s CPU ({m.wall_s:.3f} s wall), "
            f"{m.n_steps} robot-instants, goal rate {m.goal_rate:.2f}, "
            f"QP solves {m.n_qp_solves}, fallbacks {m.n_fallback}, "
            f"robot-robot pair-frames {m.n_collide_robot_pairs}, "
            f"robot-pedestrian frames {m.n_collide_pedestrian}"
        )
        print(
            f"  per robot   : {m.cpu_s / n:.3f} s CPU vs {cpu1:.3f} s  ratio "
            f"{m.cpu_s / n / cpu1:.2f} (target <= 2); wall ratio {m.wall_s / n / wall1:.2f}"
        )
        print(
            f"  per instant : {1e6 * m.cpu_s / m.n_steps:.0f} us CPU vs "
            f"{1e6 * cpu1 / steps1:.0f} us  ratio {m.cpu_s / m.n_steps / (cpu1 / steps1):.2f}"
        )
        print(f"  world share : {1 - own / m.wall_s:.0%} of the loop's wall time")


if __name__ == "__main__":
    main()
