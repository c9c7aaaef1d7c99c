"""Crowd-model step time for 100 pedestrians against the published packages, and for up to
10,000 pedestrians against the dense neighbour search.

Usage::

    python benchmarks/bench_crowds.py [--data-root ../shared/data] [--steps 400]
    python benchmarks/bench_crowds.py --scale-only [--quick]

Scenario: 100 pedestrians in a 40 m x 40 m square (at least 1 m apart at the start),
each walking at 1.3 m/s to a random goal (a new one when reached), a robot crossing the
middle at 1 m/s, steps of 1/120 s (SDD's 30 fps x 4 control instants). After 200
warm-up steps (a steady crowd), prints the median and 95th percentile of one step of

* ``social_force``  our numpy model, and ``pysocialforce`` 1.1.2's ``Simulator.step``
  on the same 100 pedestrians + the robot (its JIT compilation excluded);
* ``orca``          our numpy model, and ``pyrvo`` 0.4.3 (RVO2): the same state pushed
  in and read back agent by agent (what a wrapper must do every step), and its
  ``do_step`` alone;

in wall-clock and CPU (process) time, with our ratio to each package; the machine's
load average is printed since the machine is shared. Then two agreement checks (the
largest difference of the social force interaction against pysocialforce's, of the ORCA
velocities against RVO2's) and, with the data, nexus_4 episodes under each crowd.
The packages come with ``pip install -e '.[crowds]'``; without them their rows are
skipped with a message.

Scale (``measure_scale``, also run by ``run_all.py``): the same crowd at the same density
(100 pedestrians per 40 m x 40 m, so each has about 20 others within the 10 m cut-off) for
100, 1,000, 5,000 and 10,000 pedestrians, on a jittered lattice (at least 1 m apart), each
model stepped as shipped (the cell neighbour search; ORCA's half-planes and programs
compiled) and as before (the dense ``N x M`` search,
:func:`~conformal_control.world.crowds.neighbors.dense_neighbor_pairs`, and for ORCA the numpy
``orca_lines`` and ``solve_orca_lp``; not at 10,000: about 5 GB). Each figure comes from its own
subprocess: after warm-up steps (with the cell search, whose steps are identical), the
median wall and CPU time of a step and the peak memory of the steps (the process's peak
resident set size minus its resident set before them). The dense process also checks that
one step from the same state gives identical positions and velocities both ways.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from conformal_control.world.crowds import ORCAModel, SocialForceModel
from conformal_control.world.crowds.base import CrowdModel

ROOT = Path(__file__).resolve().parents[1]
N, L, DT, V0 = 100, 40.0, 1.0 / 120.0, 1.3
RADIUS, ROBOT_RADIUS = 0.3, 0.5


class World:
    """The benchmark crowd: positions, velocities, goals and the robot."""

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)
        pts: list[np.ndarray] = []  # no two pedestrians closer than 1 m at the start
        while len(pts) < N:
            p = self.rng.uniform(0.0, L, 2)
            if all(np.hypot(*(p - q)) >= 1.0 for q in pts):
                pts.append(p)
        self.pos = np.array(pts)
        self.vel = np.zeros((N, 2))
        self.goal = self.rng.uniform(0.0, L, (N, 2))
        self.robot = np.array([0.0, L / 2])
        self.robot_vel = np.array([1.0, 0.0])

    def pref(self) -> np.ndarray:
        d = self.goal - self.pos
        dist = np.hypot(d[:, 0], d[:, 1])
        arrived = dist < 0.5
        if arrived.any():
            self.goal[arrived] = self.rng.uniform(0.0, L, (int(arrived.sum()), 2))
            d = self.goal - self.pos
            dist = np.hypot(d[:, 0], d[:, 1])
        return d / np.maximum(dist, 1e-9)[:, None] * V0

    def advance_robot(self) -> None:
        self.robot = self.robot + DT * self.robot_vel
        if self.robot[0] > L:
            self.robot[0] = 0.0


def timed(step: Callable[[], None], n: int) -> tuple[np.ndarray, np.ndarray]:
    wall, cpu = [], []
    for _ in range(n):
        w0, c0 = time.perf_counter(), time.process_time()
        step()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return np.array(wall) * 1e6, np.array(cpu) * 1e6


def ours(model: CrowdModel, steps: int) -> tuple[np.ndarray, np.ndarray, World]:
    from conformal_control.core.jit import compile_now

    compile_now()  # timed compiled (see conformal_control.core.jit)
    model.reset(np.random.default_rng(0))
    w = World()
    rad, vmax = np.full(N, RADIUS), np.full(N, 1.3 * V0)

    def step() -> None:
        w.pos, w.vel = model.step(
            w.pos, w.vel, rad, w.pref(), vmax, w.robot[None], w.robot_vel[None],
            np.array([ROBOT_RADIUS]), DT,
        )  # fmt: skip
        w.advance_robot()

    timed(step, 200)
    wall, cpu = timed(step, steps)
    return wall, cpu, w


@contextlib.contextmanager
def quiet_import():
    """pysocialforce logs DEBUG to the root logger and writes ./file.log on import."""
    import matplotlib.pyplot  # noqa: F401  (imported first: its import then logs nothing)

    cwd = os.getcwd()
    with tempfile.TemporaryDirectory() as tmp:
        os.chdir(tmp)
        try:
            yield
        finally:
            os.chdir(cwd)
            root = logging.getLogger()
            for h in list(root.handlers):
                if isinstance(h, logging.FileHandler) or type(h) is logging.StreamHandler:
                    root.removeHandler(h)
                    h.close()
            root.setLevel(logging.WARNING)


def bench_pysocialforce(w: World, steps: int):
    try:
        with quiet_import():
            import pysocialforce as psf
    except ImportError:
        return None
    state = np.zeros((N + 1, 6))
    state[:N, :2], state[:N, 2:4], state[:N, 4:6] = w.pos, w.pref(), w.goal
    state[N, :2], state[N, 2:4] = w.robot, w.robot_vel
    state[N, 4:6] = w.robot + np.array([100.0, 0.0])  # the robot, driven by its 'goal'
    sim = psf.Simulator(state, groups=None, obstacles=None)
    sim.peds.step_width = DT
    sim.step(5)  # numba compilation
    sim.peds.ped_states.clear()

    def step() -> None:
        sim.step_once()
        sim.peds.ped_states.clear()  # it keeps every state otherwise

    return timed(step, steps)


def bench_pyrvo(w: World, steps: int):
    try:
        import pyrvo
    except ImportError:
        return None
    m = ORCAModel()
    sim = pyrvo.RVOSimulator()
    sim.set_time_step(DT)
    sim.set_agent_defaults(m.neighbor_dist, m.max_neighbors, m.time_horizon, m.time_horizon,
                           RADIUS, 1.3 * V0)  # fmt: skip
    for i in range(N):
        sim.add_agent(tuple(w.pos[i]))
    sim.add_agent(tuple(w.robot))
    sim.set_agent_radius(N, ROBOT_RADIUS)

    def sync_step() -> None:
        pref = w.pref()
        for i in range(N):
            sim.set_agent_position(i, (float(w.pos[i, 0]), float(w.pos[i, 1])))
            sim.set_agent_velocity(i, (float(w.vel[i, 0]), float(w.vel[i, 1])))
            sim.set_agent_pref_velocity(i, (float(pref[i, 0]), float(pref[i, 1])))
        sim.set_agent_position(N, (float(w.robot[0]), float(w.robot[1])))
        sim.set_agent_velocity(N, (1.0, 0.0))
        sim.set_agent_pref_velocity(N, (1.0, 0.0))
        sim.do_step()
        w.pos = np.array([sim.get_agent_position(i).to_tuple() for i in range(N)])
        w.vel = np.array([sim.get_agent_velocity(i).to_tuple() for i in range(N)])
        w.advance_robot()

    timed(sync_step, 50)
    return timed(sync_step, steps), timed(sim.do_step, steps)


def agreement_social_force() -> str:
    try:
        with quiet_import():
            import pysocialforce as psf
    except ImportError:
        return "pysocialforce not installed (pip install -e '.[crowds]')"
    rng = np.random.default_rng(1)
    model = SocialForceModel(neighbor_dist=np.inf, contact_stiffness=0.0)
    model.reset()
    same, wrapped = [], []
    for _ in range(500):  # pairs: the package's force on agent 0 from agent 1
        state = np.zeros((2, 6))
        state[:, :2] = rng.uniform(0, 5, (2, 2))
        state[:, 2:4] = rng.normal(0, 1.0, (2, 2))
        state[:, 4:6] = rng.uniform(0, 15, (2, 2))
        sim = psf.Simulator(state.copy(), groups=None, obstacles=None)
        force = next(f for f in sim.forces if type(f).__name__ == "SocialForce")
        force.factor = 4.5  # our A (its default 'factor' is 5.1)
        theirs = force.get_force()[0]
        (x0, y0, vx0, vy0), (x1, y1, vx1, vy1) = state[0, :4], state[1, :4]
        fx, fy = model.pair_forces(
            np.array([x1 - x0]), np.array([y1 - y0]), np.array([vx0 - vx1]), np.array([vy0 - vy1])
        )
        err = float(np.abs(np.array([fx[0], fy[0]]) - theirs).max())
        # the package takes the difference of two atan2 angles without wrapping it
        e = np.array([x0 - x1, y0 - y1])
        d = 2.0 * np.array([vx1 - vx0, vy1 - vy0]) + e / np.hypot(*e)
        raw = np.arctan2(d[1], d[0]) - np.arctan2(e[1], e[0])
        (same if -np.pi < raw <= np.pi else wrapped).append(err)
    return (
        f"social force interaction vs pysocialforce SocialForce (factor = A = 4.5), 500 random "
        f"pairs: max |difference| {max(same):.1e} m/s² on the {len(same)} whose angle needs no "
        f"wrapping; up to {max(wrapped, default=0.0):.1e} on the {len(wrapped)} where the "
        "package's unwrapped angle drops the force"
    )


def agreement_orca() -> str:
    try:
        import pyrvo
    except ImportError:
        return "pyrvo not installed (pip install -e '.[crowds]')"
    rng = np.random.default_rng(2)
    n, dt = 60, 0.1
    pos = np.column_stack([rng.uniform(0, 30, n), rng.uniform(0, 30, n)])
    vel, pref = rng.normal(0, 0.7, (n, 2)), rng.normal(0, 1.0, (n, 2))
    m = ORCAModel()
    m.reset()
    sim = pyrvo.RVOSimulator()
    sim.set_time_step(dt)
    for k in range(n):
        sim.add_agent(tuple(pos[k]), m.neighbor_dist, m.max_neighbors, m.time_horizon,
                      m.time_horizon, RADIUS, 1.5, tuple(vel[k]))  # fmt: skip
        sim.set_agent_pref_velocity(k, tuple(pref[k]))
    sim.do_step()
    v_rvo = np.array([sim.get_agent_velocity(k).to_tuple() for k in range(n)])
    none = np.zeros((0, 2))
    _, v = m.step(pos, vel, np.full(n, RADIUS), pref, np.full(n, 1.5), none, none, np.zeros(0), dt)
    return (
        f"ORCA velocities vs RVO2 (pyrvo), one step of 60 reciprocal agents: "
        f"max |difference| {np.abs(v - v_rvo).max():.2e} m/s (RVO2 computes in float32)"
    )


def row(name: str, wall: np.ndarray, cpu: np.ndarray, base: tuple | None = None) -> str:
    s = (
        f"  {name:<34} wall {np.median(wall):8.0f} / {np.percentile(wall, 95):8.0f} us   "
        f"cpu {np.median(cpu):8.0f} us"
    )
    if base is not None:
        r_wall, r_cpu = base[0] / np.median(wall), base[1] / np.median(cpu)
        s += f"   ours / this: {r_wall:.2f} (wall), {r_cpu:.2f} (cpu)"
    return s


def _wire(scene, params: dict):
    """The flagship's components (env, policy, loss, rule) with whichever builder exists."""
    try:  # the builder of later layouts
        from conformal_control.runs.build import build_flagship

        return build_flagship(scene, params)
    except ImportError:
        from conformal_control.core import registry
        from conformal_control.runs.episode import build_components
        from conformal_control.runs.params import resolve_params

        predictor = registry.create("predictor", "constant_velocity")
        return build_components(scene, resolve_params(scene, params), predictor)


def bench_episodes(data_root: Path) -> None:
    from conformal_control.core.loop import ConformalLoop
    from conformal_control.data import load_scene
    from conformal_control.world.reactive import make_environment_like

    scene = load_scene("nexus_4", data_root / "sdd")
    params = {"epsilon": -0.25, "eta": 1, "tau": 4, "a": 10, "K_rep": 40}
    print("\nnexus_4 episodes (constant velocity, a=10, tau=4, eta=1, eps=-0.25):")
    base = None
    for crowd, cp in (("replay", None), ("social_force", None), ("orca", None),
                      ("mixed", None), ("mixed", {"model": "orca"})):  # fmt: skip
        comp = _wire(scene, params)
        env = make_environment_like(comp.env, crowd, cp)
        t0 = time.perf_counter()
        family = getattr(comp, "family", None) or comp.policy  # earlier layouts: policy
        res = ConformalLoop(env, family, comp.loss, comp.rule).run()
        wall = time.perf_counter() - t0
        base = wall if base is None else base
        d = env.log.arrays()["d_min"]
        label = crowd + (f" ({cp['model']})" if cp else "")
        print(
            f"  {label:<14} wall {wall * 1e3:6.0f} ms (x{wall / base:4.1f} replay)  "
            f"t_goal {env.t_goal_ or float('nan'):5.2f} s  "
            f"n_collide {int(np.sum(d < env.scene.collision_distance)):3d}  "
            f"d_min {np.nanmin(d):.2f} m  l_avg {res.l_avg:+.3f}"
        )


# ------------------------------------------------------------------------------ scale
#: pedestrians -> (timed steps with the cell search, with the dense search or 0: not run)
SCALE_STEPS = {100: (400, 400), 1000: (100, 20), 5000: (30, 2), 10000: (20, 0)}
SCALE_QUICK = {100: (100, 100), 5000: (10, 1)}


def scale_world(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, float]:
    """``n`` pedestrians at the density of :class:`World` on a jittered lattice, their goals
    and the side of the square (m)."""
    rng = np.random.default_rng(seed)
    side = L * np.sqrt(n / N)
    k = int(np.ceil(np.sqrt(n)))
    s = side / k  # lattice step (4 m at the density of World): jitter keeps 1 m apart
    cells = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2)[:n]
    pos = (cells + 0.5) * s + rng.uniform(-(s - 1.0) / 2, (s - 1.0) / 2, (n, 2))
    return pos, rng.uniform(0.0, side, (n, 2)), side


def _rss_now() -> float:
    """Resident set size now (bytes); 0 where /proc is not available."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return 0.0


def _reset_peak() -> bool:
    """Reset the kernel's peak resident set size of this process (Linux >= 4.0)."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _rss_peak() -> float:
    """Peak resident set size (bytes) since :func:`_reset_peak`: ``VmHWM`` of this process.
    (Not ``ru_maxrss``: on Linux a child starts with its parent's, so a big parent would
    hide a small child's peak.)"""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    return float("nan")


def scale_child(model_name: str, n: int, method: str, steps: int) -> dict[str, float]:
    """One figure of the scale table (run in its own process; see the module docstring)."""
    from conformal_control.core.jit import compile_now
    from conformal_control.world.crowds import neighbors
    from conformal_control.world.crowds import orca as orca_module
    from conformal_control.world.crowds import social_force as sf_module

    compile_now()  # timed compiled (see conformal_control.core.jit)

    model: CrowdModel = SocialForceModel() if model_name == "social_force" else ORCAModel()
    model.reset(np.random.default_rng(0))
    pos, goal, side = scale_world(n)
    vel = np.zeros((n, 2))
    rad, vmax = np.full(n, RADIUS), np.full(n, 1.3 * V0)
    robot, robot_vel, robot_rad = (
        np.array([[0.0, side / 2]]),
        np.array([[1.0, 0.0]]),
        np.array([ROBOT_RADIUS]),
    )

    def pref() -> np.ndarray:
        d = goal - pos
        return d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)[:, None] * V0

    def step() -> tuple[np.ndarray, np.ndarray]:
        return model.step(pos, vel, rad, pref(), vmax, robot, robot_vel, robot_rad, DT)

    for _ in range(200 if n <= 1000 else 20):  # a moving crowd (the cell search)
        pos, vel = step()
    out: dict[str, float] = {}
    if method == "dense":
        fast = step()
        for mod in (sf_module, orca_module):
            mod.neighbor_pairs = neighbors.dense_neighbor_pairs  # type: ignore[attr-defined]
        if isinstance(model, ORCAModel):  # ORCA's step before: numpy lines and programs
            orca = model

            def numpy_step(*args: Any) -> tuple[np.ndarray, np.ndarray]:
                pos_, vel_, rad_, pref_, vmax_, o_pos, o_vel, o_rad, dt = args
                lines = orca.orca_lines(pos_, vel_, rad_, o_pos, o_vel, o_rad, dt)
                v, _ = orca_module.solve_orca_lp(*lines, pref_, vmax_)
                return pos_ + dt * v, v

            model.step = numpy_step  # type: ignore[method-assign]
        ref = step()
        out["identical"] = float(
            np.array_equal(fast[0], ref[0]) and np.array_equal(fast[1], ref[1])
        )
    wall, cpu = [], []
    rss0 = _rss_now()
    _reset_peak()
    for _ in range(steps):
        w0, c0 = time.perf_counter(), time.process_time()
        new = step()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    out["peak_mb"] = max(_rss_peak() - rss0, 0.0) / 1e6  # 0: below the page-level noise
    pos, vel = new
    out["wall_s"] = float(np.median(wall))
    out["cpu_s"] = float(np.median(cpu))
    return out


def measure_scale(quick: bool = False) -> list[dict[str, object]]:
    """Every (model, pedestrians, search) of the scale table, each from a subprocess."""
    import json
    import subprocess
    import sys

    rows: list[dict[str, object]] = []
    for model in ("social_force", "orca"):
        for n, (steps, dense_steps) in (SCALE_QUICK if quick else SCALE_STEPS).items():
            for method, k in (("cell", steps), ("dense", dense_steps)):
                if not k:
                    continue
                cmd = [sys.executable, __file__, "--scale-child", model, str(n), method, str(k)]
                proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
                if proc.returncode != 0:
                    raise RuntimeError(f"{' '.join(cmd[1:])} failed:\n{proc.stderr}")
                r = json.loads(proc.stdout.strip().splitlines()[-1])
                rows.append({"model": model, "n": n, "method": method, "steps": k, **r})
    return rows


def print_scale(rows: list[dict[str, object]]) -> None:
    print(
        f"\none crowd step at the density of 100 pedestrians per 40 m x 40 m, dt = {DT:.4f} s "
        "(median of the timed steps; peak memory of the steps):"
    )
    dense = {(r["model"], r["n"]): r for r in rows if r["method"] == "dense"}
    for r in rows:
        if r["method"] != "cell":
            continue
        line = (
            f"  {r['model']:<13} {r['n']:>6} pedestrians  wall {r['wall_s'] * 1e3:8.2f} ms  "
            f"cpu {r['cpu_s'] * 1e3:8.2f} ms  peak {r['peak_mb']:7.1f} MB"
        )
        d = dense.get((r["model"], r["n"]))
        if d is not None:
            line += (
                f"   dense: wall {d['wall_s'] * 1e3:8.1f} ms, cpu {d['cpu_s'] * 1e3:8.1f} ms, "
                f"peak {d['peak_mb']:7.1f} MB -> {d['wall_s'] / r['wall_s']:.0f}x faster"
                f" (cpu {d['cpu_s'] / r['cpu_s']:.0f}x), identical step: "
                f"{'yes' if d['identical'] else 'NO'}"
            )
        print(line)


def main() -> None:
    import json
    import sys

    if len(sys.argv) > 1 and sys.argv[1] == "--scale-child":
        model, n, method, steps = sys.argv[2], int(sys.argv[3]), sys.argv[4], int(sys.argv[5])
        print(json.dumps(scale_child(model, n, method, steps)))
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--data-root", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--scale-only", action="store_true", help="only the scale table")
    parser.add_argument("--quick", action="store_true", help="a smaller scale table")
    args = parser.parse_args()
    if args.scale_only:
        print(f"load average (1, 5, 15 min): {os.getloadavg()} on {os.cpu_count()} cores")
        print_scale(measure_scale(args.quick))
        return
    print(f"load average (1, 5, 15 min): {os.getloadavg()} on {os.cpu_count()} cores")
    print(f"one crowd step, {N} pedestrians + a robot, dt = {DT:.4f} s: median / p95")
    sf_wall, sf_cpu, w = ours(SocialForceModel(), args.steps)
    print(row("social_force (ours)", sf_wall, sf_cpu))
    psf = bench_pysocialforce(w, args.steps)
    if psf is None:
        print("  pysocialforce not installed (pip install -e '.[crowds]')")
    else:
        print(row("pysocialforce Simulator.step", *psf, (np.median(sf_wall), np.median(sf_cpu))))
    or_wall, or_cpu, w = ours(ORCAModel(), args.steps)
    print(row("orca (ours, compiled)", or_wall, or_cpu))
    rvo = bench_pyrvo(w, args.steps)
    if rvo is None:
        print("  pyrvo not installed (pip install -e '.[crowds]')")
    else:
        base = (np.median(or_wall), np.median(or_cpu))
        print(row("pyrvo: sync 101 agents + do_step", *rvo[0], base))
        print(row("pyrvo: do_step alone", *rvo[1], base))
    print("\nagreement:")
    print("  " + agreement_social_force())
    print("  " + agreement_orca())
    print_scale(measure_scale(args.quick))
    if (args.data_root / "sdd").is_dir():
        bench_episodes(args.data_root)
    else:
        print(f"\nno data at {args.data_root}: nexus_4 episodes skipped")


if __name__ == "__main__":
    main()
