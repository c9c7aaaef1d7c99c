"""Controller latency and episode wall time.

Usage::

    python benchmarks/bench_controller.py [--data-root ../shared/data] [--repeats 2000]

Prints, for 1, 10, 20 and 50 sensed agents, the median and 95th percentile latency of
one control step of the conformal CBF controller (interpolated predictions -> barrier
values and exact gradients -> constraint assembly -> piqp QP), in three regimes:

* ``sparse``    agents scattered 2-12 m around the robot, walking at it (the QP is solved
                when a constraint binds, skipped when the reference velocity is safe);
* ``active``    agents placed so the reference velocity violates constraints: every step
                calls piqp;
* ``fallback``  lambda far below the feasibility floor: every step is infeasible and uses
                the lambda-search fallback (one LP + one QP).

Then the wall time of full nexus_4 episodes (constant-velocity predictions, Table II
settings with a = 10) and the peak memory of one episode.
"""

from __future__ import annotations

import argparse
import statistics
import time
import tracemalloc
from pathlib import Path

import numpy as np

from conformal_control.cbf import (
    APFBarrier,
    AttractiveField,
    ConformalCBFController,
    ConformalConstraint,
    ControlState,
    QPSafetyFilter,
)
from conformal_control.predictors import OraclePredictor, PredictionQuery

ROOT = Path(__file__).resolve().parents[1]


def make_controller(v_max: float = 2.0) -> ConformalCBFController:
    barrier = APFBarrier(K_rep=0.5, rho0=5.0, d_c=0.7)
    # the oracle returns the future attached to each query: the forecast is given, not timed
    ctrl = ConformalCBFController(
        OraclePredictor(),
        ConformalConstraint(barrier, a=2.0),
        QPSafetyFilter(v_max=v_max),
        AttractiveField(K_att=1.0, v_max=v_max),
    )
    ctrl.reset()
    return ctrl


def interval(n: int, regime: str, rng: np.random.Generator):
    if regime == "active":  # a wall of agents ahead of the robot, walking at it
        ang = rng.uniform(-0.6, 0.6, n)
        r = rng.uniform(1.2, 3.0, n)
    else:
        ang = rng.uniform(-np.pi, np.pi, n)
        r = rng.uniform(2.0, 12.0, n)
    cur = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    vel = -0.8 * cur / np.linalg.norm(cur, axis=1, keepdims=True)
    hist = cur[:, None, :] - vel[:, None, :] * (np.arange(5)[::-1][None, :, None] * 0.1)
    fut = cur[:, None, :] + vel[:, None, :] * (np.arange(1, 5)[None, :, None] * 0.1)
    return PredictionQuery(ids=np.arange(n), history=hist, dt=0.1, horizon=4, ground_truth=fut)


def bench_steps(n: int, regime: str, repeats: int) -> tuple[float, float, float]:
    rng = np.random.default_rng(n)
    ctrl = make_controller()
    lam = -10.0 if regime == "fallback" else 0.0
    times = []
    goal = np.array([20.0, 0.0])
    solves0 = 0
    for i in range(repeats):
        if i % 16 == 0:
            ctrl.begin_interval(interval(n, regime, rng))
        st = ControlState(x=np.array([0.0, 0.0, 1.0, 0.0]), t=0.0, step=i % 16, goal=goal)
        t0 = time.perf_counter()
        ctrl.decide(st, lam)
        times.append(time.perf_counter() - t0)
        if i == 100:
            solves0 = ctrl.safety_filter.n_solves_
    qp_share = (ctrl.safety_filter.n_solves_ - solves0) / max(repeats - 101, 1)
    times_us = np.array(times[100:]) * 1e6
    return float(np.median(times_us)), float(np.percentile(times_us, 95)), qp_share


def bench_episode(data_root: Path, repeats: int = 5) -> None:
    from conformal_control.data import load_scene
    from conformal_control.sim import run_episode

    t0 = time.perf_counter()
    scene = load_scene("nexus_4", data_root / "sdd")
    load_s = time.perf_counter() - t0
    params = {"epsilon": -0.25, "eta": 1, "tau": 4, "a": 10, "K_rep": 40}
    walls, loops = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = run_episode(scene, "constant_velocity", params)
        walls.append(time.perf_counter() - t0)
        loops.append(res.metrics["wall_s"])
    m = res.metrics
    tracemalloc.start()
    run_episode(scene, "constant_velocity", params)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(
        f"\nnexus_4 episode (constant velocity, a=10, tau=4, eta=1, eps=-0.25): "
        f"{m['frames']} frames, {m['n_steps']} control steps, {m['n_qp_solves']} QP solves"
    )
    print(f"  scene load (raw annotations -> dense array): {load_s * 1e3:.0f} ms")
    print(
        f"  episode wall time  median {statistics.median(walls) * 1e3:.0f} ms, "
        f"min {min(walls) * 1e3:.0f} ms over {repeats} runs "
        f"(control loop alone: median {statistics.median(loops) * 1e3:.0f} ms)"
    )
    print(f"  peak Python memory of one episode (tracemalloc): {peak / 2**20:.1f} MiB")
    print(
        f"  metrics: t_goal {m['t_goal']:.2f} s, n_collide {m['n_collide']}, "
        f"d_min {m['d_min']:.2f} m, l_avg {m['l_avg']:.3f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-root", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--repeats", type=int, default=3000)
    args = parser.parse_args()
    print("control step latency (us): median / p95 [share of steps calling piqp]")
    print(f"{'agents':>7} | {'sparse':>22} | {'active':>22} | {'fallback':>22}")
    for n in (1, 10, 20, 50):
        cells = []
        for regime in ("sparse", "active", "fallback"):
            med, p95, share = bench_steps(n, regime, args.repeats)
            cells.append(f"{med:6.1f} / {p95:6.1f} [{share:4.0%}]")
        print(f"{n:>7} | " + " | ".join(f"{c:>22}" for c in cells))
    bench_episode(args.data_root)


if __name__ == "__main__":
    main()
