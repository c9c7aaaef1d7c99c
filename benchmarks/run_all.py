"""Every headline benchmark figure in one run, each with its ratio to a baseline timed in
the same run.

Usage::

    python benchmarks/run_all.py [--quick] [--data-root ../shared/data] [--only SECTION ...]
    python benchmarks/run_all.py --write-docs docs/benchmarks.md    # also write the page
    python benchmarks/run_all.py --skip suite shift ...              # leave sections out

The machine is often shared and busy, so absolute times move from run to run; the ratio
of each figure to its baseline (timed in the same run, on the same machine, under the
same load) is the figure to compare across runs. Targets are printed beside the figures
as goals, never asserted. Sections (``--only`` picks some):

* ``controller`` -- one control step with the compiled exact 2-D filter against the piqp
  filter (``bench_controller.bench_steps``): 20 agents with the filter active, 20 agents
  falling back, 200 agents;
* ``episode``    -- a full nexus_4 episode in this process (``run_episode``, which takes the
  compiled engine) against the per-episode loop (``engine="loop"``) and the piqp filter
  (``bench_controller.measure_episode``);
* ``startup``    -- the command line as a subprocess, as a user's set-up runs it (bytecode
  written, its own cache folder): ``import conformal_control.cli``, ``--help``, ``run
  --scene nexus_4`` with its plots (target: twice the floor of a plot alone, numpy +
  matplotlib saving an empty figure) and without (target: four times ``python -c "import
  numpy"``), against ``python -c pass``, ``python -c "import numpy"`` and those floors;
* ``reproduce``  -- ``reproduce table2 --predictor var`` from a cold forecast cache, against
  the same command with constant-velocity predictions (no predictor cost);
* ``predictors`` -- ``var``'s fit + forecast per window against darts' VARIMA on the same
  windows (``bench_var.time_var`` / ``time_darts``);
* ``synthetic``  -- the vectorised crossing-scene generator against the loop generator it
  replaced (``bench_synthetic.measure``);
* ``sweep``      -- a sweep with one summary plot against per-run plots
  (``bench_sweep_plots.measure``);
* ``batch``      -- 1,000 crossing seeds on the batch engine against the per-episode loop,
  from ``bench_batch.measure(quick=..., data_root=...)`` when that function exists (it
  returns figure dicts as below or ``(name, value, unit, baseline, ratio)`` rows), else a
  line saying it is not available;
* ``crowds``     -- one social force and one ORCA step for 100, 1,000, 5,000 and 10,000
  pedestrians with the cell neighbour search against the dense search
  (``bench_crowds.measure_scale``, each in its own process, with its peak memory);
* ``suite``      -- the benchmark's default suite, ``conformal-control bench run --split
  test -j 2`` (every method, 4,368 episodes; ``--quick``: the first 40 scenarios), against
  one episode per task on a 2-worker process pool for the first scenarios (target 120 s);
* ``crowds``     -- one social-force / ORCA step at 100 to 5,000 pedestrians, the cell
  neighbour search against the dense one (``bench_crowds.measure_scale``);
* ``shift``      -- ``bench run --shift all`` when the command has it (target 15 min), then
  ``bench report`` on its 14,040 rows (target 10 s) against reading the rows alone;
* ``report``     -- ``bench report`` on ``--report-folder PATH`` (the same figure on a
  folder at hand; not run without it);
* ``round4``     -- per episode under ``delay-0.5s`` and ``learned`` against nominal (target
  1.3x), a robot of a 5-robot reciprocal fleet (target 3x) and an ``mpc`` episode (target 5x)
  against a single-robot CBF episode, one worker (``bench_round4.measure``);
* ``mpc``        -- one sampling-MPC step, N = 500, H = 12, 20 pedestrians (target 2 ms),
  against its numpy reference and the CBF step (``bench_mpc.measure``);
* ``scene``      -- a 100,000-frame scene of 9,000 passers-by: the memory it holds, the peak
  of building it and of a 600-frame episode on it (target 200 MB), against the dense array;
* ``sweep_scale`` -- a 100,000-run sweep whose runs are stubs: the time per run over the last
  tenth against the first (target: within 20 %). The longest sections (minutes): ``suite``
  and ``sweep_scale``.

A figure is a dict: ``section``, ``name``, ``value`` (seconds), ``unit`` (display unit:
``us``, ``ms`` or ``s``), optional ``target`` (seconds; the goal is value <= target),
``ratios`` (a list of ``(baseline name, baseline seconds, kind)``: kind ``faster`` prints
baseline / value, "x faster than"; kind ``times`` prints value / baseline, "x the
baseline") and ``note``.

``--write-docs PATH`` writes the figures as tables, with the machine and the date, into
PATH between the markers ``<!-- run_all:begin -->`` and ``<!-- run_all:end -->`` (the rest
of the page is kept; without the markers the section is inserted after the title).
"""

from __future__ import annotations

import argparse
import datetime as dt
import importlib.metadata
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(HERE) not in sys.path:  # the bench_* modules sit beside this script
    sys.path.insert(0, str(HERE))

Figure = dict[str, Any]
SCALE = {"us": 1e6, "ms": 1e3, "s": 1.0}
BEGIN, END = "<!-- run_all:begin -->", "<!-- run_all:end -->"


def figure(
    section: str,
    name: str,
    value: float,
    unit: str,
    *,
    target: float | None = None,
    ratios: list[tuple[str, float, str]] | None = None,
    note: str = "",
) -> Figure:
    return {
        "section": section,
        "name": name,
        "value": float(value),
        "unit": unit,
        "target": target,
        "ratios": list(ratios or []),
        "note": note,
    }


def fmt_time(seconds: float, unit: str) -> str:
    """``seconds`` in ``unit``, or in a larger unit when that would need 5+ digits (a unit
    that is not a time, e.g. ``MB``: the value as it is)."""
    if unit not in SCALE:
        return f"{seconds:,.0f} {unit}" if seconds >= 100 else f"{seconds:g} {unit}"
    units = list(SCALE)
    while seconds * SCALE[unit] >= 1e4 and unit != units[-1]:
        unit = units[units.index(unit) + 1]
    v = seconds * SCALE[unit]
    return f"{v:.1f} {unit}" if v < 100 else f"{v:,.0f} {unit}"


def fmt_ratio(value: float, base_name: str, base: float, kind: str, unit: str) -> str:
    r = base / value if kind == "faster" else value / base
    r_text = f"{r:.1f}" if r < 100 else f"{r:,.0f}"
    # the baseline in its own unit (a 0.07 s python start-up reads better as 68 ms)
    b_unit = "us" if base < 1e-3 else "ms" if base < 1.0 else "s"
    if kind == "faster":
        return f"{r_text}x faster than {base_name} ({fmt_time(base, b_unit)})"
    return f"{r_text}x {base_name} ({fmt_time(base, b_unit)})"


def fmt_target(f: Figure) -> str:
    if f["target"] is None:
        return ""
    met = "met" if f["value"] <= f["target"] else "not met"
    return f"<= {fmt_time(f['target'], f['unit'])} ({met})"


def print_figures(figs: list[Figure]) -> None:
    for f in figs:
        line = f"  {f['name']:<46} {fmt_time(f['value'], f['unit']):>10}"
        if f["target"] is not None:
            line += f"  target {fmt_target(f)}"
        print(line)
        for base_name, base, kind in f["ratios"]:
            print(f"  {'':<46} {'':>10}  {fmt_ratio(f['value'], base_name, base, kind, f['unit'])}")
        if f["note"]:
            print(f"  {'':<46} {'':>10}  ({f['note']})")


# --------------------------------------------------------------------------- sections


def sec_controller(args: argparse.Namespace) -> list[Figure]:
    import bench_controller as bc

    repeats = 600 if args.quick else 3000
    for cls in bc.FILTERS.values():  # compile / load the kernels before timing
        bc.bench_steps(cls, 5, "fallback", 200)
    out = []
    cases = (
        (20, "active", 10e-6, "control step, 20 agents (filter active)"),
        (20, "fallback", 15e-6, "fallback step, 20 agents (lambda search)"),
        (200, "active", 30e-6, "control step, 200 agents (filter active)"),
    )
    for n, regime, target, name in cases:
        exact = bc.bench_steps(bc.FILTERS["exact2d"], n, regime, repeats)
        qp = bc.bench_steps(bc.FILTERS["qp"], n, regime, repeats)
        out.append(
            figure(
                "controller",
                name,
                exact[0] * 1e-6,
                "us",
                target=target,
                ratios=[("the piqp filter", qp[0] * 1e-6, "faster")],
                note=f"median of {repeats - 100} steps; p95 {exact[1]:.1f} us, piqp p95 "
                f"{qp[1]:.1f} us; solver called on {exact[2]:.0%} of steps",
            )
        )
    return out


def sec_episode(args: argparse.Namespace) -> list[Figure]:
    import bench_controller as bc

    from conformal_control.data import load_scene

    repeats = 2 if args.quick else 5
    scene = load_scene("nexus_4", args.data_root / "sdd")
    exact = bc.measure_episode(scene, bc.PAPER_A10, "exact2d", repeats)
    loop = bc.measure_episode(scene, bc.PAPER_A10, "exact2d", repeats, engine="loop")
    qp = bc.measure_episode(scene, bc.PAPER_A10, "qp", repeats, engine="loop")
    m = exact["metrics"]
    return [
        figure(
            "episode",
            f"nexus_4 episode in process (exact2d filter, {exact['engine']} engine)",
            exact["wall_s"],
            "ms",
            target=20e-3,
            ratios=[
                ("the per-episode loop", loop["wall_s"], "faster"),
                ("the piqp filter's loop", qp["wall_s"], "faster"),
            ],
            note=f"median of {repeats}; control loop {exact['loop_s'] * 1e3:.1f} ms "
            f"(per-episode loop {loop['loop_s'] * 1e3:.1f} ms); "
            f"{m['n_steps']} control steps, t_goal {m['t_goal']:.2f} s, "
            f"peak Python memory {exact['peak_bytes'] / 2**20:.1f} MiB",
        )
    ]


def _cli() -> list[str]:
    script = Path(sys.executable).parent / "conformal-control"
    return [str(script)] if script.exists() else [sys.executable, "-m", "conformal_control.cli"]


def time_command(cmd: list[str], repeats: int, env: dict | None = None) -> tuple[float, float]:
    """Median wall time and median CPU time (user + system, children) of a command."""
    walls, cpus = [], []
    for _ in range(repeats):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
        wall = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
            raise RuntimeError(f"{' '.join(cmd)} exited with {proc.returncode}: {tail}")
        walls.append(wall)
        cpus.append((r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime))
    return statistics.median(walls), statistics.median(cpus)


def _user_env(cache: str) -> dict[str, str]:
    """A user's environment: bytecode written (``PYTHONDONTWRITEBYTECODE`` unset; an
    installed package has its ``.pyc`` files), this run's own cache folder, kernels compiled
    as a user's process decides (``CONFORMAL_CONTROL_JIT`` unset)."""
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("PYTHONDONTWRITEBYTECODE", "CONFORMAL_CONTROL_JIT")
    }
    env["CONFORMAL_CONTROL_CACHE"] = cache
    return env


def sec_startup(args: argparse.Namespace) -> list[Figure]:
    with tempfile.TemporaryDirectory(prefix="cc-run-all-cache-") as cache:
        return _startup(args, _user_env(cache))


def _startup(args: argparse.Namespace, env: dict[str, str]) -> list[Figure]:
    n = 3 if args.quick else 7
    py = sys.executable
    time_command([py, "-c", "import numpy, matplotlib.pyplot"], 1, env)  # bytecode written
    p_pass, c_pass = time_command([py, "-c", "pass"], n, env)
    p_np, c_np = time_command([py, "-c", "import numpy"], n, env)
    base = [("python -c pass", p_pass, "times"), ("python -c 'import numpy'", p_np, "times")]
    out = [
        figure(
            "startup",
            "python -c pass",
            p_pass,
            "ms",
            note=f"median of {n}; CPU {c_pass * 1e3:.0f} ms",
        ),
        figure("startup", "python -c 'import numpy'", p_np, "ms", note=f"CPU {c_np * 1e3:.0f} ms"),
    ]
    imp, imp_cpu = time_command([py, "-c", "import conformal_control.cli"], n, env)
    out.append(
        figure(
            "startup",
            "python -c 'import conformal_control.cli'",
            imp,
            "ms",
            ratios=base,
            note=f"CPU {imp_cpu * 1e3:.0f} ms",
        )
    )
    hlp, hlp_cpu = time_command([*_cli(), "--help"], n, env)
    out.append(
        figure(
            "startup",
            "conformal-control --help",
            hlp,
            "ms",
            ratios=base,
            note=f"CPU {hlp_cpu * 1e3:.0f} ms",
        )
    )
    k = 2 if args.quick else 3
    with tempfile.TemporaryDirectory(prefix="cc-run-all-") as tmp:
        # the floor of any command that runs a compiled step and saves a figure: the
        # interpreter, numpy, numba's first compiled call (it initialises LLVM, as loading
        # a cached kernel does) and matplotlib saving an empty figure
        png = str(Path(tmp) / "floor.png")
        floor_code = (
            "import numpy, numba, matplotlib; matplotlib.use('Agg'); "
            "import matplotlib.pyplot as plt; numba.njit(lambda x: x + 1.0)(1.0); "
            f"plt.figure().savefig({png!r})"
        )
        floor, floor_cpu = time_command([py, "-c", floor_code], n, env)
        out.append(
            figure(
                "startup",
                "floor: numpy + numba's first call + matplotlib saving a figure",
                floor,
                "s",
                ratios=base,
                note=f"median of {n}; CPU {floor_cpu:.2f} s; `python -c` with no project "
                "code: what any command with a compiled step and a plot pays first",
            )
        )
        mpl_code = (
            "import numpy, matplotlib; matplotlib.use('Agg'); "
            f"import matplotlib.pyplot as plt; plt.figure().savefig({png!r})"
        )
        mpl, mpl_cpu = time_command([py, "-c", mpl_code], n, env)
        out.append(
            figure(
                "startup",
                "floor of the plot alone: numpy + matplotlib saving an empty figure",
                mpl,
                "s",
                ratios=base,
                note=f"median of {n}; CPU {mpl_cpu:.2f} s; what any command that saves a "
                "matplotlib figure pays, before drawing anything",
            )
        )
        run = [*_cli(), "run", "--scene", "nexus_4", "--data-root", str(args.data_root), "-q"]
        for plot in (True, False):
            cmd = [*run, "--out", str(Path(tmp) / f"run-{plot}")]
            cmd += [] if plot else ["--no-plot"]
            time_command(cmd, 1, env)  # warm-up: bytecode, the parsed scene's cache
            wall, cpu = time_command(cmd, k, env)
            name = "conformal-control run --scene nexus_4" + ("" if plot else " --no-plot")
            # the targets: with plots 2x the plot's floor, without 4x python + numpy
            ref = ("the plot's floor", mpl, "times") if plot else base[1]
            out.append(
                figure(
                    "startup",
                    name,
                    wall,
                    "s",
                    target=2.0 * mpl if plot else 4.0 * p_np,
                    ratios=[ref, ("python -c 'import numpy'", p_np, "times")] if plot else base,
                    note=f"median of {k} after a warm-up; CPU {cpu:.2f} s; "
                    + ("episode, run directory, plot.png and guarantee.png" if plot else
                       "episode and run directory, no figures")
                    + (f"; target 2x the plot's floor ({2.0 * mpl:.2f} s)" if plot else
                       f"; target 4x python -c 'import numpy' ({4.0 * p_np:.2f} s)"),
                )
            )  # fmt: skip
    return out


def sec_reproduce(args: argparse.Namespace) -> list[Figure]:
    times = {}
    with tempfile.TemporaryDirectory(prefix="cc-run-all-") as tmp:
        for pred in ("constant_velocity", "var"):
            cache = Path(tmp) / f"cache-{pred}"
            cache.mkdir()
            env = {**os.environ, "CONFORMAL_CONTROL_CACHE": str(cache)}
            cmd = [*_cli(), "reproduce", "table2", "--predictor", pred, "-q"]
            cmd += ["--data-root", str(args.data_root), "--out", str(Path(tmp) / pred)]
            times[pred] = time_command(cmd, 1, env)
    (cv, cv_cpu), (var, var_cpu) = times["constant_velocity"], times["var"]
    return [
        figure(
            "reproduce",
            "reproduce table2 --predictor var (cold cache)",
            var,
            "s",
            target=10.0,
            ratios=[("the same with constant_velocity", cv, "times")],
            note=f"one run each, subprocess, fresh forecast cache and output folder; "
            f"CPU {var_cpu:.1f} s (constant_velocity {cv_cpu:.1f} s), the command and its "
            "worker processes",
        )
    ]


def sec_predictors(args: argparse.Namespace) -> list[Figure]:
    import bench_var as bv

    from conformal_control.data.scenes import load_scene

    scene = load_scene("nexus_4", str(args.data_root / "sdd"))
    n_win, n_darts = (100, 2) if args.quick else (500, 5)
    win, _ = bv.windows_from_scene(scene, n_win, 50, 80, 0)
    v = bv.time_var(win, 80, 1.0 / scene.fps)
    d = bv.time_darts(win[:n_darts], 80)
    darts = [("darts VARIMA(10, 1, 'c')", d["wall_s"], "faster")]
    note = (
        f"darts on {n_darts} windows in a subprocess ({d['process_s']:.1f} s with its "
        f"imports, {d['failed']} failed fits); 80-step forecasts from 50 samples"
    )
    return [
        figure(
            "predictors",
            f"var fit + forecast per window ({len(win)} in one call)",
            v["batched_s"],
            "us",
            ratios=darts,
            note=note,
        ),
        figure(
            "predictors",
            "var fit + forecast, one window per call",
            v["single_s"],
            "us",
            ratios=darts,
        ),
    ]


def sec_synthetic(args: argparse.Namespace) -> list[Figure]:
    import bench_synthetic as bs

    seeds, repeat = (list(range(3)), 1) if args.quick else (list(range(10)), 3)
    r = bs.measure(seeds, repeat)
    return [
        figure(
            "synthetic",
            "crossing scene generation (vectorised), per seed",
            r["vectorised_s"],
            "ms",
            ratios=[("the loop generator", r["loop_s"], "faster")],
            note=f"best of {repeat} over {len(seeds)} seeds; outputs bit-identical; "
            f"{r['n_tracks']} tracks for seed {seeds[0]}",
        )
    ]


def sec_sweep(args: argparse.Namespace) -> list[Figure]:
    import bench_sweep_plots as bsp

    runs, frames, repeat = (4, 50, 1) if args.quick else (12, 100, 2)
    n, best = bsp.measure(runs, frames, repeat)
    new = best["summary plot only (new default)"]
    return [
        figure(
            "sweep",
            f"sweep of {n} crossing runs, summary plot (default)",
            new,
            "s",
            ratios=[
                ("per-run plots", best["per-run plots (old default)"], "faster"),
                ("no plots at all", best["no plots"], "times"),
            ],
            note=f"{frames} frames per run, serial executor, best of {repeat}",
        )
    ]


def _from_row(row: Any) -> Figure:
    """A figure from a ``(name, value, unit, baseline, ratio)`` row (``bench_batch``'s form):
    times get the baseline as "faster", 1,000-seed wall times the 15 s target; other rows
    (memory, counts) are shown as they are, with their baseline as a note."""
    if isinstance(row, dict):
        return row
    name, value, unit, base, ratio = row
    if unit in SCALE:
        target = 15.0 if name.endswith("1000 seeds wall") else None
        ratios = [("the per-episode loop", float(base), "faster")] if ratio is not None else []
        return figure("batch", name, value, unit, target=target, ratios=ratios)
    note = f"of {base:g}" if base is not None else ""
    return figure("batch", name, value, unit, note=note)


def sec_crowds(args: argparse.Namespace) -> list[Figure]:
    import bench_crowds as bc

    rows = bc.measure_scale(quick=args.quick)
    dense = {(r["model"], r["n"]): r for r in rows if r["method"] == "dense"}
    figs: list[Figure] = []
    for r in rows:
        if r["method"] != "cell":
            continue
        n, model = int(r["n"]), str(r["model"])
        d = dense.get((model, n))
        target = {100: 0.5e-3, 5000: 50e-3}.get(n)
        note = f"CPU {r['cpu_s'] * 1e3:.2f} ms; peak memory {r['peak_mb']:.0f} MB"
        ratios = []
        if d is not None:
            ratios = [("the step before (dense search)", float(d["wall_s"]), "faster")]
            same = "identical" if d["identical"] else "NOT identical"
            note += f" (before: {d['peak_mb']:.0f} MB); a step {same} to the one before"
        if n == 5000:
            note += "; target 200 MB"
        figs.append(
            figure(
                "crowds",
                f"{model} step, {n:,} pedestrians",
                float(r["wall_s"]),
                "ms",
                target=target,
                ratios=ratios,
                note=note,
            )
        )
    return figs


def sec_batch(args: argparse.Namespace) -> list[Figure] | str:
    try:
        import bench_batch
    except ImportError:
        return "batch engine: not available on this branch"
    measure = getattr(bench_batch, "measure", None)
    if measure is None:
        return "batch engine: benchmarks/bench_batch.py has no measure() function to call"
    return [_from_row(r) for r in measure(quick=args.quick, data_root=args.data_root)]


def _bench_run(args: argparse.Namespace, out: Path, extra: list[str]) -> tuple[float, int, str]:
    """``conformal-control bench run --split test -j 2 EXTRA`` into ``out``: wall time,
    episodes run and the summary line (with the CPU time of the command and its worker
    processes: on a shared machine the wall time depends on the load)."""
    import re

    cmd = [*_cli(), "bench", "run", "--split", "test", "-j", "2", "--progress", "off"]
    cmd += ["--data-root", str(args.data_root), "--out", str(out), *extra]
    t0 = time.perf_counter()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"{' '.join(cmd)} exited with {proc.returncode}: {tail}")
    line = next(
        (x for x in proc.stdout.splitlines() if re.search(r"\d+ episodes: ", x)), proc.stdout
    )
    m = re.search(r"(\d+) ran \((\d+) failed\)", line)
    if m is None or int(m.group(2)):
        raise RuntimeError(f"unexpected bench run output: {line.strip()}")
    line = line.split("; results in")[0]  # not the temporary folder's path
    return wall, int(m.group(1)), f"{line.strip()}; CPU {cpu:.0f} s"


def sec_suite(args: argparse.Namespace) -> list[Figure]:
    """The benchmark's default suite (every method on the test split), against one
    episode per task on a process pool for its first scenarios, timed in the same run."""
    base_limit = 4 if args.quick else 8
    with tempfile.TemporaryDirectory(prefix="cc-run-all-") as tmp:
        b_wall, b_n, _ = _bench_run(
            args, Path(tmp) / "pool", ["--executor", "process", "--limit", str(base_limit)]
        )
        extra = ["--limit", "40"] if args.quick else []
        wall, n, line = _bench_run(args, Path(tmp) / "suite", extra)
    per_base = b_wall / b_n
    name = (
        "bench run, first 40 test scenarios (quick)"
        if args.quick
        else "bench run --split test (the default suite)"
    )
    return [
        figure(
            "suite",
            name,
            wall,
            "s",
            target=None if args.quick else 120.0,
            note=f"{line}; -j 2; the process pool ran the first {base_limit} scenarios "
            f"({b_n} episodes) in {b_wall:.0f} s, {per_base * 1e3:.0f} ms per episode",
        ),
        figure(
            "suite",
            "time per episode in the suite",
            wall / n,
            "ms",
            ratios=[("one episode per task on a 2-worker pool", per_base, "faster")],
        ),
    ]


def _long_scene(frames: int = 100_000, agents: int = 9_000, life: int = 300) -> Any:
    """A ``frames``-frame scene of ``agents`` passers-by, each seen for ``life`` frames
    (30 fps), walking straight across a 30 m square; the robot crosses it at the start."""
    import numpy as np

    from conformal_control.data.scene import scene_from_tracks
    from conformal_control.data.synthetic import crossing_scene
    from conformal_control.data.tracks import Tracks

    rng = np.random.default_rng(0)
    starts = rng.integers(0, frames - life, size=agents)
    a = rng.uniform(0.0, 2.0 * np.pi, size=agents)
    centre = rng.uniform(5.0, 25.0, size=(agents, 2))
    t = (np.arange(life) - life / 2) / 30.0
    tracks = {}
    for i in range(agents):
        v = 1.3 * np.array([np.cos(a[i]), np.sin(a[i])])
        tracks[i] = (np.arange(starts[i], starts[i] + life), centre[i] + t[:, None] * v)
    return scene_from_tracks(
        Tracks(30.0, tracks, source="run_all long scene"),
        name="long",
        start=np.array([2.0, 15.0]),
        goals=np.array([[28.0, 15.0]]),
        start_frame=120,  # the scene starts at frame 0 (120 frames of history)
        v_max=2.0,
        defaults=dict(crossing_scene(seed=0, duration=1.0).defaults),  # the crossing's
    )


def sec_scene(args: argparse.Namespace) -> list[Figure]:
    """A 100,000-frame scene: its memory (sparse) against the dense array it replaced, and
    one episode on it (the batch engine) under tracemalloc."""
    import gc
    import tracemalloc
    import warnings

    from conformal_control.data.synthetic import crossing_scene
    from conformal_control.runs.engines.batch import run_batch

    frames = 20_000 if args.quick else 100_000
    agents = frames * 9 // 100
    with warnings.catch_warnings():  # kernels compiled (loaded) before memory is traced
        warnings.simplefilter("ignore")
        run_batch([crossing_scene(seed=0, duration=2.0)], "constant_velocity")
    gc.collect()
    tracemalloc.start()
    t0 = time.perf_counter()
    scene = _long_scene(frames, agents)
    build = time.perf_counter() - t0
    _, peak_build = tracemalloc.get_traced_memory()
    tracemalloc.reset_peak()
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        [m] = run_batch([scene], "constant_velocity", max_frames=600)
    episode = time.perf_counter() - t0
    _, peak_run = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    dense = scene.n_frames * scene.n_agents * 2 * 8
    held = scene.nbytes()
    note = (
        f"{scene.n_frames:,} frames, {scene.n_agents:,} agents seen for 300 frames each; "
        f"the dense (frames x agents) array would take {dense / 2**30:.1f} GiB"
    )
    return [
        figure(
            "scene",
            f"{frames:,}-frame scene, positions held",
            round(held / 1e6, 1),
            "MB",
            note=note,
        ),
        figure(
            "scene",
            f"{frames:,}-frame scene, peak memory of building it from its tracks",
            round(peak_build / 1e6, 1),
            "MB",
            target=None if args.quick else 200.0,
            note=f"tracemalloc (the tracks themselves included); {build:.1f} s",
        ),
        figure(
            "scene",
            f"{frames:,}-frame scene, peak memory of a 600-frame episode on it",
            round(peak_run / 1e6, 1),
            "MB",
            target=None if args.quick else 200.0,
            note=f"tracemalloc, batch engine, the scene held; {episode:.1f} s; "
            f"t_goal {m.t_goal}, n_collide {m.n_collide}",
        ),
    ]


def _sweep_per_run(n: int) -> tuple[float, float, float]:
    """Time per run over the first and the last tenth of an ``n``-run sweep whose runs are
    stubs (a fixed record), and its wall time."""
    from conformal_control.experiments.executors.base import Executor
    from conformal_control.experiments.plan import SweepRun
    from conformal_control.experiments.runner import run_sweep

    stamps: list[float] = []

    class Stub(Executor):
        name = "stub"

        def run(self, fn: Any, tasks: Any) -> Any:
            for i, (_cfg, key, _out, _plot) in enumerate(tasks):
                stamps.append(time.perf_counter())
                yield i, {"key": key, "status": "ok", "run_dir": None, "metrics": {"t_goal": 1.0}}

    configs = [
        SweepRun.from_settings("crossing", {"epsilon": -i * 1e-6}, max_frames=5) for i in range(n)
    ]
    with tempfile.TemporaryDirectory(prefix="cc-run-all-") as tmp:
        t0 = time.perf_counter()
        report = run_sweep(configs, Path(tmp) / "sweep", Stub(), summary_plot=False, progress=False)
        wall = time.perf_counter() - t0
    if len(stamps) != n or report.failed:
        raise RuntimeError(f"{len(stamps)} of {n} runs delivered, {len(report.failed)} failed")
    k = n // 10
    return (stamps[k] - stamps[0]) / k, (stamps[-1] - stamps[-k - 1]) / k, wall


def sec_sweep_scale(args: argparse.Namespace) -> list[Figure]:
    """The sweep's own bookkeeping (validating, journaling, tables) at 100,000 runs, the runs
    stubs: the time per run over the last tenth against the first. A 2,000-run sweep first:
    if its last tenth is already more than twice as slow as its first (tables rewritten
    after every run grow with the sweep), 100,000 runs would take hours and are not run."""
    n = 10_000 if args.quick else 100_000
    first, last, wall = _sweep_per_run(2_000)
    probe = (
        f"a 2,000-run sweep: {last * 1e3:.1f} ms per run over its last tenth, "
        f"{first * 1e3:.1f} ms over its first ({wall:.0f} s)"
    )
    if last > 2.0 * first:
        return [
            figure(
                "sweep_scale",
                "2,000-run sweep, time per run, last 10 %",
                last,
                "ms",
                target=1.2 * first,
                ratios=[("the first 10 %", first, "times")],
                note=f"runs are stubs; {probe}: not linear, so the {n:,}-run sweep was not run",
            )
        ]
    first, last, wall = _sweep_per_run(n)
    return [
        figure(
            "sweep_scale",
            f"{n:,}-run sweep, time per run, last 10 %",
            last,
            "ms",
            target=None if args.quick else 1.2 * first,
            ratios=[("the first 10 %", first, "times")],
            note=f"runs are stubs (a fixed record): validating, keys, journaling (fsync once a "
            f"second), tables; {wall:.0f} s in all; target: within 20 % of the first 10 %; {probe}",
        )
    ]


def sec_mpc(args: argparse.Namespace) -> list[Figure]:
    """One sampling-MPC control step, N = 500 samples, H = 12 steps, 20 pedestrians, against
    the numpy reference and the CBF step (``bench_mpc.measure``)."""
    import bench_mpc

    rows = bench_mpc.measure(repeats=100 if args.quick else 400, data_root=args.data_root)
    out = []
    for name, ms, base_name, base_ms, _ in rows:
        faster = base_ms > ms
        out.append(
            figure(
                "mpc",
                name + (" (N=500, H=12, 20 peds)" if name.startswith("mpc, v") else ""),
                ms / 1e3,
                "ms",
                target=2e-3 if name == "mpc, velocity plant" else None,
                ratios=[(base_name, base_ms / 1e3, "faster" if faster else "times")],
            )
        )
    return out


def sec_round4(args: argparse.Namespace) -> list[Figure]:
    """What an episode costs under a predictor shift, as a fleet robot and with the MPC
    family, each against the plain single-robot CBF episode timed in the same run
    (``bench_round4.measure``: one worker, the first test scenarios)."""
    import bench_round4

    out = []
    for f in bench_round4.measure(str(args.data_root), quick=args.quick):
        out.append(
            figure(
                "round4",
                f["name"],
                f["value"],
                f["unit"],
                target=None if args.quick else f["target"],
                ratios=list(f["ratios"]),
                note=f["note"],
            )
        )
    return out


def sec_shift(args: argparse.Namespace) -> list[Figure] | str:
    """The benchmark's shift axis as its page runs it: the test split, nominal and four
    shifts (``bench run --shift nominal,delay-0.2s,delay-0.5s,noise-0.25m,frozen``, the
    shipped tuned settings)."""
    probe = subprocess.run([*_cli(), "bench", "run", "--help"], capture_output=True, text=True)
    if "--shift" not in probe.stdout:
        return "not available: `bench run` has no --shift option in this version"
    shifts = "nominal,delay-0.2s,delay-0.5s,noise-0.25m,frozen"
    with tempfile.TemporaryDirectory(prefix="cc-run-all-") as tmp:
        extra = ["--shift", shifts] + (["--limit", "10"] if args.quick else [])
        wall, n, line = _bench_run(args, Path(tmp) / "shift", extra)
        report = _report_figures(Path(tmp) / "shift", "shift", repeats=1 if args.quick else 3)
    return [
        figure(
            "shift",
            "bench run --split test, five shifts (the shift benchmark)",
            wall,
            "s",
            target=None if args.quick else 15 * 60.0,
            note=f"{line}; {n} episodes",
        ),
        *report,
    ]


def _report_figures(folder: Path, section: str, repeats: int) -> list[Figure]:
    """``conformal-control bench report`` on a benchmark folder (subprocess, its own output
    folder), against reading the folder's rows alone in a fresh process (the floor of any
    report: Python, the imports and the journal's JSON), timed in the same run."""
    from conformal_control.experiments.bench.suite import read_rows

    n_rows = len(read_rows(folder))
    with tempfile.TemporaryDirectory(prefix="cc-run-all-report-") as tmp:
        cmd = [*_cli(), "bench", "report", str(folder), "--out", str(Path(tmp) / "report")]
        wall, cpu = time_command(cmd, repeats)
    read = (
        "from conformal_control.experiments.bench.suite import read_rows; "
        f"read_rows({str(folder)!r})"
    )
    r_wall, r_cpu = time_command([sys.executable, "-c", read], repeats)
    return [
        figure(
            section,
            f"bench report on {n_rows:,} rows",
            wall,
            "s",
            target=10.0 if n_rows >= 14_000 else None,
            ratios=[("reading the rows alone (fresh process)", r_wall, "times")],
            note=f"median of {repeats}; CPU {cpu:.1f} s (the command and its figure "
            f"processes), reading alone {r_cpu:.1f} s; every table and figure of the report",
        )
    ]


def sec_report(args: argparse.Namespace) -> list[Figure] | str:
    """``bench report`` on the benchmark folder ``--report-folder`` (the shift section
    times it on its own 14,040 rows)."""
    if args.report_folder is None:
        return "not run: needs --report-folder (the shift section times the report on its rows)"
    return _report_figures(args.report_folder, "report", repeats=1 if args.quick else 3)


#: key -> (title, function); a function returns its figures, or a sentence saying why
#: there are none
SECTIONS: dict[str, tuple[str, Callable[[argparse.Namespace], list[Figure] | str]]] = {
    "controller": ("Control step: compiled exact 2-D filter vs piqp", sec_controller),
    "episode": ("Full episode in process", sec_episode),
    "startup": ("Command line, end to end (subprocess)", sec_startup),
    "reproduce": ("Reproducing Table II with the var predictor", sec_reproduce),
    "predictors": ("The var predictor vs darts", sec_predictors),
    "synthetic": ("Synthetic crossing scenes", sec_synthetic),
    "sweep": ("Sweeps: summary plot vs per-run plots", sec_sweep),
    "batch": ("Many episodes: batch engine vs per-episode loop", sec_batch),
    "crowds": ("Reactive crowds: cell neighbour search vs dense", sec_crowds),
    "suite": ("The benchmark's default suite", sec_suite),
    "shift": ("The benchmark's shift axis", sec_shift),
    "mpc": ("Sampling MPC: one control step", sec_mpc),
    "round4": ("Per episode: shifted predictors, fleets, the MPC family", sec_round4),
    "scene": ("Scenes stored sparsely: a 100,000-frame scene", sec_scene),
    "sweep_scale": ("Sweeps at 100,000 runs: the bookkeeping's throughput", sec_sweep_scale),
    "report": ("bench report on a given folder", sec_report),
}


# --------------------------------------------------------------------------- machine


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "absent"


def machine() -> dict[str, str]:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                mem = f"{int(line.split()[1]) / 2**20:.0f} GB RAM"
                break
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    try:
        commit = subprocess.run(
            ["git", "-C", str(ROOT), "describe", "--always", "--dirty"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    libs = ", ".join(
        f"{d} {_version(d)}" for d in ("numpy", "numba", "piqp", "matplotlib", "darts")
    )
    return {
        "cpu": f"{cores} cores available, {cpu}" + (f", {mem}" if mem else ""),
        "python": f"Python {platform.python_version()} on {platform.system()}; {libs}",
        "commit": commit,
        "load": " ".join(f"{x:.1f}" for x in os.getloadavg()),
    }


# --------------------------------------------------------------------------- docs


def markdown(results: list[tuple[str, list[Figure], str]], info: dict, quick: bool) -> str:
    lines = [
        BEGIN,
        "## All figures, one run",
        "",
        "Generated by `python benchmarks/run_all.py"
        + (" --quick" if quick else "")
        + " --write-docs docs/benchmarks.md`; do not edit by hand between the markers.",
        "",
        f"Measured {info['date']} on {info['cpu']}; {info['python']}; commit "
        f"`{info['commit']}`. Load average {info['load']} at the start, {info['load_end']} at "
        "the end: the machine was shared, so compare the ratios (each baseline is timed in the "
        "same run) rather than the absolute times. Targets are goals, not guarantees.",
        "",
    ]
    for title, figs, message in results:
        lines += [f"### {title}", ""]
        if message:
            lines += [message[0].upper() + message[1:] + ".", ""]
        if not figs:
            continue
        lines += ["| figure | value | target | against a baseline timed in the same run |"]
        lines += ["|---|---:|---|---|"]
        for f in figs:
            ratios = "; ".join(fmt_ratio(f["value"], n, b, k, f["unit"]) for n, b, k in f["ratios"])
            cells = [f["name"], fmt_time(f["value"], f["unit"]), fmt_target(f), ratios]
            lines.append("| " + " | ".join(cells) + " |")
        notes = [f"*{f['name']}*: {f['note']}." for f in figs if f["note"]]
        if notes:
            lines += [""] + [f"* {n}" for n in notes]
        lines.append("")
    lines.append(END)
    return "\n".join(lines)


def write_docs(path: Path, block: str) -> None:
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        tail = rest.split(END, 1)[1]
        text = head + block + tail
    else:  # after the title (and the paragraph under it)
        parts = text.split("\n\n", 2)
        if len(parts) == 3 and parts[0].startswith("# "):
            text = f"{parts[0]}\n\n{parts[1]}\n\n{block}\n\n{parts[2]}"
        else:
            text = f"{text.rstrip()}\n\n{block}\n"
    path.write_text(text)


# --------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--quick", action="store_true", help="fewer repetitions (noisier)")
    ap.add_argument("--data-root", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--only", nargs="+", choices=list(SECTIONS), default=None)
    ap.add_argument(
        "--skip",
        nargs="+",
        choices=list(SECTIONS),
        default=[],
        help="sections not run (the page says so)",
    )
    ap.add_argument("--write-docs", type=Path, default=None, metavar="PATH")
    ap.add_argument(
        "--report-folder",
        type=Path,
        default=None,
        help="a `bench run` folder the report section times `bench report` on",
    )
    args = ap.parse_args(argv)
    if args.write_docs is not None and args.only is not None:
        ap.error("--write-docs rewrites the whole section: run every section (no --only)")
    if not (args.data_root / "sdd").is_dir():
        ap.error(f"no sdd/ folder under --data-root {args.data_root}")
    args.data_root = args.data_root.resolve()
    info = machine()
    info["date"] = dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    print(f"run_all {'--quick ' if args.quick else ''}{info['date']}")
    print(f"machine: {info['cpu']}\n         {info['python']}")
    print(f"commit {info['commit']}, load average {info['load']}")
    results: list[tuple[str, list[Figure], str]] = []
    t_all = time.perf_counter()
    for key in args.only or list(SECTIONS):
        title, fn = SECTIONS[key]
        print(f"\n== {title}", flush=True)
        t0 = time.perf_counter()
        message = ""
        try:
            got = "not measured in this run (--skip)" if key in args.skip else fn(args)
        except Exception as exc:  # one broken section must not hide the others
            traceback.print_exc()
            got = f"failed: {type(exc).__name__}: {exc}"
        figs = [] if isinstance(got, str) else got
        if isinstance(got, str):
            message = got
            print(f"  {message}")
        print_figures(figs)
        print(f"  [{time.perf_counter() - t0:.0f} s]", flush=True)
        results.append((title, figs, message))
    info["load_end"] = " ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"\nall sections in {time.perf_counter() - t_all:.0f} s; load average {info['load_end']}")
    if args.write_docs is not None:
        write_docs(args.write_docs, markdown(results, info, args.quick))
        print(f"wrote {args.write_docs}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
