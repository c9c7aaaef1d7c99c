"""Latency of one control step of the sampling MPC, with its baselines from the same run.

One control step = one plan: N sampled command sequences of H steps rolled out through the
plant, cost and clearance against M predicted agents, the choice (what
``SamplingMPC.decide`` does when it plans). Timed for the issue's target configuration
(N = 500, H = 12, M = 20) with

* a velocity-command plant (the velocity-tracking double integrator of the paper's scenes),
* the unicycle of the ETH/UCY planar protocol,
* ``acp_mpc`` on the unicycle (its regions from 2,000 past errors per step),
* ``ecp_mpc`` on the unicycle (egocentric regions of every candidate from 15 past times),

the ETH/UCY planar protocol's 13 scenarios of ``cc_mpc`` (1,200 samples, H = 12) run in
lockstep (``planar.run_scenarios``: every scenario's plans at a decision evaluated in one
compiled call, ``mpc.batch.plan_all``) against the same scenarios one at a time
(``planar.run_scenario``), per decided step (CPU time of this process: the two paths do the
same work on one thread, and the machine's other jobs do not enter), with identical results
(``tests/families/mpc/test_batch.py``),

and, in the same run on the same inputs,

* the **numpy reference** of the same step (the plant's rollout as a loop of ``step`` calls
  replaced by ``Dynamics.rollout``'s default only for the unicycle's vectorised numpy form,
  and the cost/clearance by ``kernels.evaluate_numpy``), the baseline the compiled path
  is measured against;
* the **CBF family's control step** with 20 agents (exact 2-D filter, the flagship), the
  other decision family's cost per step.

Medians over ``--repeats`` steps (each on a fresh crowd every 12 steps), after warm-up,
of the wall clock (``--clock wall``, default) or of this process's CPU time (``--clock
cpu``: what a step costs when other jobs share the cores; every timed path runs on one
thread). Usage::

    python benchmarks/bench_mpc.py [--repeats 400] [--samples 500] [--horizon 12] [--agents 20]
                                   [--clock wall|cpu] [--data-root DATA] [--planar]

``--planar`` instead times, in one run on the CPU clock, the unicycle MPC's step at the
planar protocol's budget (1,200 samples x 12 steps, ``--agents`` pedestrians) and each planar
method's CPU time per decided step over the first scenario of every dataset (everything the
protocol's loop does for the method -- predictions, the conformal bookkeeping, the plan, the
loss and rule -- divided by the decided steps), with their ratio to that step.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time
from typing import Any

import numpy as np

from conformal_control.core.jit import compile_now
from conformal_control.families.cbf import (
    APFBarrier,
    AttractiveField,
    ConformalCBFController,
    ConformalConstraint,
    ControlState,
    Exact2DSafetyFilter,
)
from conformal_control.families.cbf.dynamics import Unicycle, VelocityTrackingDoubleIntegrator
from conformal_control.families.cbf.roles import Dynamics
from conformal_control.families.mpc import ACPMPC, ECPMPC, Limits, Sampling, SamplingMPC
from conformal_control.families.mpc.kernels import evaluate_numpy
from conformal_control.predictors import ConstantVelocityPredictor, PredictionQuery

DT = 0.4
#: The clock steps are timed with (``--clock``).
CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}
clock = CLOCKS["wall"]


def crowd(rng: np.random.Generator, m: int, t: float) -> PredictionQuery:
    cur = rng.uniform([-6.0, -6.0], [6.0, 6.0], (m, 2))
    vel = rng.normal(0.0, 1.0, (m, 2))
    hist = cur[:, None, :] - vel[:, None, :] * DT * np.arange(7, -1, -1)[None, :, None]
    return PredictionQuery(ids=np.arange(m), history=hist, dt=DT, horizon=1, t=t)


class NumpyMPC(SamplingMPC):
    """The same step with numpy arithmetic for the cost/clearance (the baseline)."""

    def plan(self, state: ControlState, lam: float) -> Any:  # same code path, numpy kernel
        import conformal_control.families.mpc.controller as ctl

        compiled = ctl.evaluate
        ctl.evaluate = evaluate_numpy  # type: ignore[assignment]
        try:
            return super().plan(state, lam)
        finally:
            ctl.evaluate = compiled


class LoopRollout(Unicycle):
    """The unicycle with the generic rollout (a loop over ``step``) for the baseline."""

    def rollout(self, state: np.ndarray, commands: np.ndarray, dt: float) -> np.ndarray:
        return Dynamics.rollout(self, state, commands, dt)


def time_steps(make: Any, plant: Dynamics, m: int, repeats: int, warm: int = 20) -> float:
    """Median latency (ms) of ``decide`` when it plans."""
    rng = np.random.default_rng(0)
    fam = make()
    fam.reset()
    x = plant.initial_state(np.zeros(2), 0.3)
    goal = np.array([20.0, 5.0])
    times = []
    for i in range(repeats + warm):
        if i % 12 == 0:
            fam.begin_interval(crowd(rng, m, t=i * DT))
        st = ControlState(x=x, t=i * DT, step=0, goal=goal)
        t0 = clock()
        fam.decide(st, -0.2)
        times.append(clock() - t0)
        fam._plan = None  # plan again at the next instant
    return float(np.median(times[warm:]) * 1e3)


def time_cbf(m: int, repeats: int) -> float:
    rng = np.random.default_rng(1)
    ctrl = ConformalCBFController(
        ConstantVelocityPredictor(),
        ConformalConstraint(APFBarrier(K_rep=0.5, rho0=20.0, d_c=1.0), a=2.0),
        Exact2DSafetyFilter(v_max=1.5),
        AttractiveField(K_att=1.0, v_max=1.5),
        substeps=4,
    )
    ctrl.reset()
    times = []
    goal = np.array([20.0, 5.0])
    for i in range(repeats + 20):
        if i % 4 == 0:
            q = crowd(rng, m, t=i * 0.1)
            ctrl.begin_interval(PredictionQuery(q.ids, q.history, 0.1, 1, q.t))
        st = ControlState(x=np.array([0.0, 0.0, 1.0, 0.0]), t=i * 0.1, step=i % 4, goal=goal)
        t0 = clock()
        ctrl.decide(st, 0.0)
        times.append(clock() - t0)
    return float(np.median(times[20:]) * 1e3)


def time_lockstep(method: str = "cc_mpc", data_root: Any = None, repeats: int = 2) -> tuple:
    """CPU ms per decided step of the planar protocol's scenarios of ``method``, one at a
    time and in lockstep (the better of ``repeats`` passes each, alternated)."""
    from conformal_control.experiments.bench import planar

    planar.warm_up_kernels()
    m = planar.PLANAR_METHODS[method]
    best = {"alone": math.inf, "lockstep": math.inf}
    for _ in range(repeats):
        for mode in best:
            t0 = time.process_time()
            steps = 0
            for task in planar.TASKS.values():
                starts = list(task.start_timesteps)
                if mode == "alone":
                    runs = [planar.run_scenario(task, s, m, data_root=data_root) for s in starts]
                else:
                    runs = planar.run_scenarios(task, starts, m, data_root=data_root)
                steps += sum(bool(s["recorded"]) for r in runs for s in r.steps)
            best[mode] = min(best[mode], (time.process_time() - t0) / steps * 1e3)
    return best["lockstep"], best["alone"]


#: The planar methods timed per decided step (``--planar``).
PLANAR_TIMED = ("mpc", "cc_mpc", "cc_mpc_pub", "acp_mpc", "ecp_mpc", "fcp_mpc_hard_pub")


def time_planar(method: str, data_root: Any = None) -> float:
    """CPU ms per decided step of a planar method over the first scenario of every dataset
    (constant-velocity predictions; an ``fcp_mpc`` method's offline calibration done before
    the clock starts): everything the protocol's loop does, divided by its decided steps.
    Before the clock starts every recording is read and the method runs the first dataset's
    scenario once untimed, which compiles (or loads) its kernels: a run right after numba's
    cache was cleared otherwise timed compilation (9-15 ms/step)."""
    from conformal_control.experiments.bench import planar

    planar.warm_up_kernels()
    m = planar.PLANAR_METHODS[method]
    for task in planar.TASKS.values():  # read every recording once (cached per process)
        planar.recording(task, data_root)
    first = next(iter(planar.TASKS.values()))
    start, cv = first.start_timesteps[0], "constant_velocity"
    if m.calibration is not None:
        planar.scenario_envelope(first, start, m, cv, data_root)
    planar.run_scenario(first, start, m, cv, data_root=data_root)
    spent, steps = 0.0, 0
    for task in planar.TASKS.values():
        start = task.start_timesteps[0]
        if m.calibration is not None:
            planar.scenario_envelope(task, start, m, "constant_velocity", data_root)
        t0 = time.process_time()
        res = planar.run_scenario(task, start, m, "constant_velocity", data_root=data_root)
        spent += time.process_time() - t0
        steps += sum(bool(s["recorded"]) for s in res.steps)
    return spent / steps * 1e3


def measure(
    samples: int = 500,
    horizon: int = 12,
    agents: int = 20,
    repeats: int = 400,
    data_root: Any = None,
) -> list:
    """Rows ``(name, ms, baseline name, baseline ms, ratio)``."""
    compile_now()  # timed compiled (see conformal_control.core.jit)
    vt = VelocityTrackingDoubleIntegrator(K_acc=60.0)
    uni = Unicycle()
    common = {"sampling": Sampling(n_samples=samples, horizon=horizon, dt_plan=DT), "substeps": 1}
    cv = ConstantVelocityPredictor

    def mpc(plant: Dynamics, cls: type = SamplingMPC, **kw: Any) -> Any:
        return lambda: cls(cv(), plant, limits=Limits(v_max=1.5), **common, **kw)

    def acp() -> ACPMPC:
        fam = ACPMPC(cv(), uni, **common, max_inflation=1.0)
        fam.reset()
        rng = np.random.default_rng(2)
        for s in fam.scores_:
            s.extend(np.abs(rng.normal(0.0, 0.4, 2000)).tolist())
        fam.reset = lambda: None  # type: ignore[method-assign]  # keep the scores
        return fam

    rows = []
    cbf = time_cbf(agents, repeats * 4)
    v = time_steps(mpc(vt), vt, agents, repeats)
    v_np = time_steps(mpc(vt, NumpyMPC), vt, agents, repeats)
    u = time_steps(mpc(uni), uni, agents, repeats)
    u_np = time_steps(mpc(LoopRollout(), NumpyMPC), uni, agents, repeats // 4)
    a = time_steps(acp, uni, agents, repeats)
    e = time_steps(mpc(uni, ECPMPC, calibration_size=15), uni, agents, repeats)
    rows.append(("mpc, velocity plant", v, "numpy reference", v_np, v_np / v))
    rows.append(("mpc, unicycle", u, "numpy + step loop", u_np, u_np / u))
    rows.append(("acp_mpc, unicycle", a, "mpc, unicycle", u, a / u))
    rows.append(("ecp_mpc, unicycle", e, "mpc, unicycle", u, e / u))
    rows.append(("mpc, unicycle", u, "cbf (exact2d) step", cbf, u / cbf))
    lock, alone = time_lockstep(data_root=data_root)  # the ETH/UCY recordings
    rows.append(("cc_mpc planar, 13 scenarios in lockstep, per step (CPU)", lock,
                 "one scenario at a time", alone, alone / lock))  # fmt: skip
    return rows


def measure_planar(agents: int = 20, repeats: int = 400, data_root: Any = None) -> list:
    """Rows: the unicycle MPC's step at the planar budget (1,200 samples x 12 steps,
    ``agents`` pedestrians), then each planar method's CPU ms per decided step against it."""
    compile_now()
    uni = Unicycle(v_min=-0.8, v_max=0.8, omega_max=0.7, integrator="euler")
    budget = Sampling(n_samples=1200, horizon=12, dt_plan=DT)

    def make() -> SamplingMPC:
        return SamplingMPC(ConstantVelocityPredictor(), uni, sampling=budget, substeps=1)

    step = time_steps(make, uni, agents, repeats)
    rows = [("mpc step, 1,200 x 12, unicycle", step, "target", 2.0, step / 2.0)]
    for name in PLANAR_TIMED:
        ms = time_planar(name, data_root)
        rows.append((f"planar {name} per decided step", ms, "mpc step", step, ms / step))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--repeats", type=int, default=400)
    ap.add_argument("--samples", type=int, default=500)
    ap.add_argument("--horizon", type=int, default=12)
    ap.add_argument("--agents", type=int, default=20)
    ap.add_argument("--clock", choices=sorted(CLOCKS), default="wall")
    ap.add_argument("--data-root", default=None, help="the data folder (the ETH/UCY recordings)")
    ap.add_argument(
        "--planar",
        action="store_true",
        help="time the planar protocol's methods per decided step (CPU) against the MPC step "
        "at their budget (1,200 x 12), both in this run",
    )
    args = ap.parse_args()
    global clock
    clock = CLOCKS[args.clock]
    if args.planar:
        clock = CLOCKS["cpu"]
        rows = measure_planar(args.agents, args.repeats, args.data_root)
        print(
            f"planar protocol per decided step against the MPC step at 1,200 x 12, "
            f"{args.agents} agents (CPU clock, load average {os.getloadavg()[0]:.1f})"
        )
        for name, ms, base, base_ms, ratio in rows:
            print(f"  {name:40s} {ms:8.3f} ms   {base:10s} {base_ms:8.3f} ms   ratio {ratio:6.2f}")
        step = rows[0][1]
        print(f"target MPC step <= 2 ms: {'met' if step <= 2.0 else 'NOT met'} ({step:.3f} ms)")
        worst = max(r[4] for r in rows[1:])
        print(f"target planar <= 1.5x the step: worst ratio {worst:.2f}")
        return
    rows = measure(args.samples, args.horizon, args.agents, args.repeats, args.data_root)
    print(
        f"one control step, N = {args.samples} samples x H = {args.horizon} steps, "
        f"{args.agents} agents ({platform.processor() or platform.machine()}, "
        f"{platform.python_version()}; {args.clock} clock, load average "
        f"{os.getloadavg()[0]:.1f})"
    )
    for name, ms, base, base_ms, ratio in rows:
        print(f"  {name:22s} {ms:7.3f} ms   {base:20s} {base_ms:9.4f} ms   ratio {ratio:7.2f}")
    target = rows[1][1]
    print(f"target <= 2 ms (unicycle): {'met' if target <= 2.0 else 'NOT met'} ({target:.3f} ms)")


if __name__ == "__main__":
    main()
