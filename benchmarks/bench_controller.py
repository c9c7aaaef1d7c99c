"""Controller latency (piqp path vs the compiled exact 2-D step), compile cost, episodes.

Usage::

    python benchmarks/bench_controller.py [--data-root ../shared/data] [--repeats 3000]

1. The median and 95th percentile latency of one control step of the conformal CBF
   controller (``decide``: reference velocity, interpolated predictions -> barrier values
   and exact gradients -> rows -> safety filter) for 1 to 200 sensed agents, with the piqp
   filter (``qp``, the generic Python path) and with the exact 2-D filter (``exact2d``,
   whose step is one compiled call with the APF barrier), timed in the same run; the ratio
   is piqp / exact. Three regimes:

   * ``sparse``    agents scattered 2-12 m around the robot, walking at it (the filter solves
                   when a constraint binds, returns the reference when it is safe);
   * ``active``    agents placed so the reference velocity violates constraints: every step
                   solves;
   * ``fallback``  lambda far below the feasibility floor: every step is infeasible and
                   uses the lambda-search fallback (lambda LP + projection).

   Then the exact step against its targets (20 agents: <= 10 us; 20 agents falling back:
   <= 15 us; 200 agents: <= 30 us) with the piqp / exact ratio. ``--clock cpu`` times the
   thread's CPU time instead of wall time (a shared, busy machine).

2. The first-call cost of the compiled kernels (numba, ``cache=True``): a fresh process
   with an empty cache directory (compilation) and one reusing it (loading).

3. The wall time of full episodes (nexus_4 with Table II settings and a = 10; the built-in
   crossing scene, where the filter is active) with each filter (``run_episode(...,
   safety_filter=name)``) and the peak memory of one episode.

``benchmarks/run_all.py`` reuses :func:`bench_steps` and :func:`measure_episode`.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from conformal_control.core.jit import compile_now
from conformal_control.families.cbf import (
    APFBarrier,
    AttractiveField,
    ConformalCBFController,
    ConformalConstraint,
    ControlState,
    Exact2DSafetyFilter,
    QPSafetyFilter,
)
from conformal_control.predictors import OraclePredictor, PredictionQuery

ROOT = Path(__file__).resolve().parents[1]
FILTERS = {"qp": QPSafetyFilter, "exact2d": Exact2DSafetyFilter}
REGIMES = ("sparse", "active", "fallback")


def make_controller(filter_cls: type, v_max: float = 2.0) -> ConformalCBFController:
    barrier = APFBarrier(K_rep=0.5, rho0=5.0, d_c=0.7)
    # the oracle returns the future attached to each query: the forecast is given, not timed
    ctrl = ConformalCBFController(
        OraclePredictor(),
        ConformalConstraint(barrier, a=2.0),
        filter_cls(v_max=v_max),
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


def bench_steps(filter_cls: type, n: int, regime: str, repeats: int) -> tuple[float, float, float]:
    """Median and p95 latency (us) and the share of steps that call a solver."""
    compile_now()  # timed compiled (see conformal_control.core.jit)
    rng = np.random.default_rng(n)
    ctrl = make_controller(filter_cls)
    lam = -10.0 if regime == "fallback" else 0.0
    goal = np.array([20.0, 0.0])
    states = [
        ControlState(x=np.array([0.0, 0.0, 1.0, 0.0]), t=0.0, step=i, goal=goal) for i in range(16)
    ]
    times = []
    statuses: list[str] = []
    clock = CLOCKS[CLOCK]
    for i in range(repeats):
        if i % 16 == 0:
            statuses += ctrl.interval_record().status
            ctrl.begin_interval(interval(n, regime, rng))
        st = states[i % 16]
        t0 = clock()
        ctrl.decide(st, lam)
        times.append(clock() - t0)
    share = float(np.mean([s != "unconstrained" for s in statuses[100:]]))
    times_us = np.array(times[100:]) * 1e6
    return float(np.median(times_us)), float(np.percentile(times_us, 95)), share


#: ``wall``: time.perf_counter; ``cpu``: the thread's CPU time (time.thread_time), which
#: leaves out the time the thread waits for a core on a busy machine.
CLOCKS = {"wall": time.perf_counter, "cpu": time.thread_time}
CLOCK = "wall"


COMPILE_SNIPPET = """
import time, numpy as np
t0 = time.perf_counter()
from conformal_control.families.cbf import (APFBarrier, AttractiveField, ConformalCBFController,
    ConformalConstraint, ControlState, Exact2DSafetyFilter)
from conformal_control.predictors import OraclePredictor, PredictionQuery
t1 = time.perf_counter()
c = ConformalCBFController(OraclePredictor(), ConformalConstraint(APFBarrier(), a=2.0),
    Exact2DSafetyFilter(), AttractiveField())
c.reset()
cur = np.array([[1.5, 0.1], [9.0, 0.0]]); vel = np.array([[-1.0, 0.0], [0.0, 0.0]])
hist = cur[:, None, :] - vel[:, None, :] * np.arange(5)[::-1][None, :, None] * 0.1
fut = cur[:, None, :] + vel[:, None, :] * np.arange(1, 5)[None, :, None] * 0.1
c.begin_interval(PredictionQuery(ids=np.arange(2), history=hist, dt=0.1, horizon=4,
    ground_truth=fut))
st = ControlState(x=np.array([0.0, 0.0, 1.0, 0.0]), t=0.0, step=0, goal=np.array([20.0, 0]))
c.decide(st, 0.0); c.decide(st, -50.0)
print(t1 - t0, time.perf_counter() - t1)
"""


def bench_compile() -> None:
    with tempfile.TemporaryDirectory() as cache:
        # compiled at the first call, as a process with enough work for it runs (a short run
        # interprets its kernels instead; see conformal_control.core.jit)
        env = {**os.environ, "NUMBA_CACHE_DIR": cache, "CONFORMAL_CONTROL_JIT": "always"}
        out = []
        for _ in range(2):
            t0 = time.perf_counter()
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            res = subprocess.run(
                [sys.executable, "-c", COMPILE_SNIPPET],
                env=env,
                capture_output=True,
                text=True,
                check=True,
            )
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            total = time.perf_counter() - t0
            cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
            imp, first = (float(x) for x in res.stdout.split())
            out.append((total, imp, first, cpu))
    (c_tot, c_imp, c_first, c_cpu), (w_tot, w_imp, w_first, w_cpu) = out
    print("\ncompiled kernels, first use in a fresh process (numba cache=True):")
    print(
        f"  empty cache (compiles): first reset + 2 steps {c_first:.2f} s "
        f"(import of conformal_control.families.cbf {c_imp:.2f} s, process {c_tot:.2f} s wall, "
        f"{c_cpu:.2f} s CPU)"
    )
    print(
        f"  warm cache  (loads):    first reset + 2 steps {w_first:.2f} s "
        f"(import {w_imp:.2f} s, process {w_tot:.2f} s wall, {w_cpu:.2f} s CPU); "
        f"compile / load = {c_first / w_first:.0f}x"
    )


def measure_episode(
    scene, params: dict, safety_filter: str, repeats: int = 3, engine: str = "auto"
) -> dict:
    """Median wall time of ``run_episode`` (and of its control loop alone) with one filter.

    A warm-up run first (it compiles or loads the kernels); then ``repeats`` timed runs and
    one more under tracemalloc for the peak Python memory. ``engine`` is run_episode's
    (``"loop"``: the per-episode loop; ``"auto"``: the compiled engine where it applies).
    Returns ``wall_s``, ``loop_s`` (medians), ``peak_bytes``, the ``metrics`` of the last
    timed run and the ``engine`` that ran.
    """
    compile_now()  # timed compiled (see conformal_control.core.jit)
    from conformal_control.runs.episode import run_episode

    kw = {"safety_filter": safety_filter, "engine": engine}
    run_episode(scene, "constant_velocity", params, **kw)  # warm-up (compiles)
    walls, loops = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = run_episode(scene, "constant_velocity", params, **kw)
        walls.append(time.perf_counter() - t0)
        loops.append(res.metrics["wall_s"])
    tracemalloc.start()
    run_episode(scene, "constant_velocity", params, **kw)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {
        "wall_s": statistics.median(walls),
        "loop_s": statistics.median(loops),
        "peak_bytes": peak,
        "metrics": res.metrics,
        "engine": res.config["engine"],
    }


def bench_episode(data_root: Path, repeats: int = 3) -> None:
    from conformal_control.data import load_scene

    scenes = [
        ("nexus_4", load_scene("nexus_4", data_root / "sdd"), PAPER_A10),
        ("crossing", load_scene("crossing", seed=0), {"a": 2.0, "epsilon": 0.1}),
    ]
    for label, scene, params in scenes:
        print(f"\n{label} episode (constant velocity, {params}), median of {repeats} runs:")
        base = None
        runs = [(name, "loop") for name in FILTERS] + [("exact2d", "auto")]
        for name, engine in runs:
            r = measure_episode(scene, params, name, repeats, engine)
            m, wall, loop, peak = r["metrics"], r["wall_s"], r["loop_s"], r["peak_bytes"]
            base = base or loop
            label = f"{name} ({r['engine']})"
            print(
                f"  {label:>16}: episode {wall * 1e3:6.1f} ms, control loop {loop * 1e3:6.1f} ms "
                f"(piqp / this {base / loop:4.1f}x), peak memory {peak / 2**20:.1f} MiB; "
                f"{m['n_steps']} steps, {m['n_qp_solves']} solves, {m['n_fallback']} fallbacks, "
                f"t_goal {m['t_goal'] or float('nan'):.2f} s, n_collide {m['n_collide']}, "
                f"d_min {m['d_min']:.3f} m, l_avg {m['l_avg']:.4f}"
            )


#: Table II settings with the published code's a = 10 (scene units).
PAPER_A10 = {"epsilon": -0.25, "eta": 1, "tau": 4, "a": 10, "K_rep": 40}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--data-root", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--repeats", type=int, default=3000)
    parser.add_argument("--no-episode", action="store_true")
    parser.add_argument(
        "--clock",
        choices=sorted(CLOCKS),
        default="wall",
        help="per-step clock: wall time, or the thread's CPU time (on a shared machine)",
    )
    args = parser.parse_args()
    global CLOCK
    CLOCK = args.clock
    for cls in FILTERS.values():  # compile / load the kernels before timing
        bench_steps(cls, 5, "fallback", 200)
    print(
        f"control step latency (us, {args.clock} clock): median / p95 "
        "[share of steps calling a solver]"
    )
    print(f"{'agents':>6} {'filter':>8} | {'sparse':>21} | {'active':>21} | {'fallback':>21}")
    med: dict[tuple[str, int, str], float] = {}
    for n in (1, 10, 20, 50, 200):
        rows = {}
        for name, cls in FILTERS.items():
            rows[name] = [
                bench_steps(cls, n, r, args.repeats) for r in ("sparse", "active", "fallback")
            ]
            for r, cell in zip(REGIMES, rows[name], strict=True):
                med[(name, n, r)] = cell[0]
        for name, cells in rows.items():
            text = " | ".join(f"{m:6.1f} / {p:6.1f} [{s:4.0%}]".rjust(21) for m, p, s in cells)
            print(f"{n:>6} {name:>8} | {text}")
        ratio = [med[("qp", n, r)] / med[("exact2d", n, r)] for r in REGIMES]
        print(f"{n:>6} {'ratio':>8} | " + " | ".join(f"{x:20.1f}x" for x in ratio))
    print("\nexact2d (compiled step) against the targets, with piqp / exact2d in this run:")
    for n, r, target in ((20, "active", 10), (20, "fallback", 15), (200, "active", 30)):
        e, q = med[("exact2d", n, r)], med[("qp", n, r)]
        print(
            f"  {n:>3} agents, {r:<8}: {e:6.1f} us (target <= {target} us), piqp {q:7.1f} us, "
            f"ratio {q / e:5.1f}x"
        )
    bench_compile()
    if not args.no_episode:
        bench_episode(args.data_root)


if __name__ == "__main__":
    main()
