"""Lockstep batch engine (``run_batch``) against the per-episode loop (``run_episode``).

Usage::

    python benchmarks/bench_batch.py [--seeds 1000] [--baseline 40] [--batch-size 128]
                                     [--data-root ../shared/data] [--cache DIR] [--no-suite]
                                     [--scenarios N] [--reactive N]

1. ``crossing``: the built-in scene with seeds ``0 .. seeds-1`` (learning, the scene's
   defaults). The batch engine runs all of them in a fresh child process, the scenes
   streamed to it from a disk cache (generating one scene takes ~0.5 s of Python, so
   they are generated once, in parallel, into ``--cache``; the time spent loading them
   is measured inside the stream and subtracted). The per-episode loop
   (``run_episode(engine="loop")``, no animation record) runs on the first ``--baseline``
   seeds in this process; its time
   per episode is extrapolated to all the seeds (printed as such). Both report wall time
   and CPU time (``time.process_time``: the machine is shared). The child's peak memory
   is its peak resident set size (``ru_maxrss``) minus its size before the run. The
   metrics of the baseline seeds are compared field by field (everything but ``wall_s``).
2. The benchmark suite's ``dev`` split (each scenario with its own ``max_frames``) with the
   ``nolearn`` method (every scenario), the ``acp`` method (adaptive conformal prediction
   regions; the first ``--scenarios-acp``) and the ``fallback:relax`` method (its LP
   decided in Python; the first ``--scenarios-relax``): each scenario through the
   per-episode loop and through the batch engine, episodes per second, and the same
   comparison of the metrics.
3. Reactive crowds (``social_force``, ``orca``; ``mixed`` from the command line) on the
   first ``--reactive`` scenarios of the dev split with the ``conformal`` method (learning):
   the per-episode loop against the batch engine, wall and CPU time, and the metrics
   compared field by field (target: 8x faster).

:func:`measure` returns the same figures as ``(name, value, unit, baseline, ratio)``
rows (for ``benchmarks/run_all.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import resource
import subprocess
import sys
import time
import warnings
import zlib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _cache_dir(arg: str | None) -> Path:
    if arg:
        return Path(arg)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "conformal-control" / "bench-batch-crossing"


def _scene_path(cache: Path, seed: int) -> Path:
    return cache / f"crossing-seed{seed}.pkl.z"


def _make_scene(args: tuple[str, int]) -> int:
    from conformal_control.data import load_scene

    cache, seed = Path(args[0]), args[1]
    path = _scene_path(cache, seed)
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(zlib.compress(pickle.dumps(load_scene("crossing", seed=seed)), 1))
    tmp.replace(path)
    return seed


def ensure_scenes(cache: Path, n: int, workers: int) -> None:
    """Generate the missing crossing scenes 0 .. n-1 into ``cache`` (in parallel)."""
    cache.mkdir(parents=True, exist_ok=True)
    missing = [s for s in range(n) if not _scene_path(cache, s).exists()]
    if not missing:
        return
    print(f"generating {len(missing)} crossing scenes into {cache} ({workers} processes) ...")
    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers) as pool:
        for i, _ in enumerate(pool.map(_make_scene, [(str(cache), s) for s in missing]), 1):
            if i % 100 == 0 or i == len(missing):
                print(f"  {i}/{len(missing)} ({time.perf_counter() - t0:.0f} s)", flush=True)


def load_cached(cache: Path, seed: int):
    return pickle.loads(zlib.decompress(_scene_path(cache, seed).read_bytes()))


def _rss_mb() -> float:
    """Current resident set size (MB), from /proc (Linux)."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def child_crossing(cache: Path, n: int, batch_size: int) -> None:
    """Run the batch engine on the cached scenes 0 .. n-1; print a JSON line."""
    warnings.simplefilter("ignore")
    from conformal_control.runs.engines.batch import run_batch

    run_batch([load_cached(cache, 0)], batch_size=batch_size)  # load the compiled kernels
    load = {"wall": 0.0, "cpu": 0.0}

    def stream():
        for seed in range(n):
            w, c = time.perf_counter(), time.process_time()
            scene = load_cached(cache, seed)
            load["wall"] += time.perf_counter() - w
            load["cpu"] += time.process_time() - c
            yield scene

    rss0 = _rss_mb()
    w, c = time.perf_counter(), time.process_time()
    metrics = run_batch(stream(), batch_size=batch_size)
    wall, cpu = time.perf_counter() - w, time.process_time() - c
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    out = {
        "wall": wall - load["wall"],
        "cpu": cpu - load["cpu"],
        "load_wall": load["wall"],
        "peak_mb": peak - rss0,
        "rss0_mb": rss0,
        "metrics": [m.as_dict() for m in metrics],
    }
    print(json.dumps(out))


def same_metrics(ref, got) -> list[str]:
    """Fields that differ (exactly; NaN equals NaN), ``wall_s`` excepted."""
    bad = []
    for key in ref:
        if key == "wall_s":
            continue
        a, b = ref[key], got[key]
        if a == b or (isinstance(a, float) and isinstance(b, float) and a != a and b != b):
            continue
        bad.append(key)
    return bad


def _fmt(wall: float, cpu: float) -> str:
    return f"{wall:8.2f} s wall {cpu:8.2f} s CPU"


def bench_crossing(args: argparse.Namespace) -> dict[str, float]:
    """Print and return the crossing figures (see the module docstring)."""
    from conformal_control.core.jit import compile_now
    from conformal_control.runs.episode import run_episode

    compile_now()  # the per-episode loop's kernels compiled too (see conformal_control.core.jit)
    cache = _cache_dir(args.cache)
    ensure_scenes(cache, args.seeds, args.workers)
    print(f"\n== crossing: {args.seeds} seeds, learning (fixed_eta), batch_size={args.batch_size}")
    cmd = [sys.executable, __file__, "--child", "--seeds", str(args.seeds)]
    cmd += ["--batch-size", str(args.batch_size), "--cache", str(cache)]
    res = subprocess.run(cmd, capture_output=True, text=True, check=True)
    child = json.loads(res.stdout.strip().splitlines()[-1])
    n_base = min(args.baseline, args.seeds)
    warnings.simplefilter("ignore")
    run_episode(
        load_cached(cache, 0), record_animation=False, engine="loop"
    )  # warm: compiled kernels
    wall = cpu = 0.0
    differing = 0
    for seed in range(n_base):
        scene = load_cached(cache, seed)
        w, c = time.perf_counter(), time.process_time()
        m = run_episode(scene, record_animation=False, engine="loop").metrics
        wall += time.perf_counter() - w
        cpu += time.process_time() - c
        differing += bool(same_metrics(m.as_dict(), child["metrics"][seed]))
    per_wall, per_cpu = wall / n_base, cpu / n_base
    ext_wall, ext_cpu = per_wall * args.seeds, per_cpu * args.seeds
    bw, bc = child["wall"], child["cpu"]
    print(f"per-episode loop, {n_base} seeds measured:     {_fmt(wall, cpu)}")
    print(
        f"per-episode loop, extrapolated to {args.seeds}:  {_fmt(ext_wall, ext_cpu)}  "
        f"({per_cpu * 1e3:.1f} ms CPU per episode)"
    )
    print(
        f"batch engine, {args.seeds} seeds (child):       {_fmt(bw, bc)}  "
        f"({bc / args.seeds * 1e3:.1f} ms CPU per episode; scene loading "
        f"{child['load_wall']:.1f} s subtracted)"
    )
    print(
        f"speed-up: {ext_wall / bw:.1f}x wall, {ext_cpu / bc:.1f}x CPU; "
        f"{args.seeds / bw:.0f} episodes/s batched vs {1 / per_wall:.1f} episodes/s per episode"
    )
    print(
        f"batch engine peak memory: {child['peak_mb']:.0f} MB above its "
        f"{child['rss0_mb']:.0f} MB before the run (peak RSS)"
    )
    print(
        f"metrics of the {n_base} baseline seeds: "
        + ("identical (every field but wall_s)" if not differing else f"{differing} differ")
    )
    return {
        "n": args.seeds,
        "n_base": n_base,
        "wall": bw,
        "cpu": bc,
        "base_wall": ext_wall,
        "base_cpu": ext_cpu,
        "peak_mb": child["peak_mb"],
        "differing": differing,
    }


def bench_suite(
    args: argparse.Namespace, method: str = "nolearn", scenarios: int | None = None
) -> dict[str, float]:
    """Print and return the figures of the suite's dev split with ``method`` on its first
    ``scenarios`` (default ``args.scenarios``; see the module docstring)."""
    from conformal_control.core.jit import compile_now
    from conformal_control.experiments.bench import load_scenario, load_suite
    from conformal_control.experiments.bench.methods import expand_methods
    from conformal_control.runs.engines.batch import run_batch, supports
    from conformal_control.runs.episode import run_episode

    compile_now()  # the per-episode loop's kernels compiled too (see conformal_control.core.jit)
    warnings.simplefilter("ignore")
    suite = load_suite("crossings-v1")
    dev = suite.scenarios_for("dev")[: scenarios or args.scenarios]
    kw = expand_methods([method])[0].run_kwargs()
    assert supports(**kw) is None, supports(**kw)
    print(f"\n== {suite.name} dev split: {len(dev)} scenarios, method {method}")
    t0 = time.perf_counter()
    scenes = [load_scenario(s, args.data_root) for s in dev]
    frames = [s.max_frames for s in dev]
    print(f"(loading the scenarios: {time.perf_counter() - t0:.1f} s, not timed below)")
    run_batch(scenes[:1], max_frames=frames[:1], **kw)  # warm
    w, c = time.perf_counter(), time.process_time()
    ref = [
        run_episode(s, max_frames=f, record_animation=False, engine="loop", **kw).metrics
        for s, f in zip(scenes, frames, strict=True)
    ]
    ew, ec = time.perf_counter() - w, time.process_time() - c
    w, c = time.perf_counter(), time.process_time()
    got = run_batch(scenes, max_frames=frames, batch_size=args.batch_size, **kw)
    bw, bc = time.perf_counter() - w, time.process_time() - c
    n = len(dev)
    differing = sum(bool(same_metrics(r, g)) for r, g in zip(ref, got, strict=True))
    print(f"per-episode loop: {_fmt(ew, ec)}  ({n / ew:6.1f} episodes/s wall)")
    print(f"batch engine:     {_fmt(bw, bc)}  ({n / bw:6.1f} episodes/s wall)")
    print(f"speed-up: {ew / bw:.1f}x wall, {ec / bc:.1f}x CPU")
    print(
        f"metrics of the {n} scenarios: "
        + ("identical (every field but wall_s)" if not differing else f"{differing} differ")
    )
    return {"n": n, "wall": bw, "cpu": bc, "base_wall": ew, "base_cpu": ec, "differing": differing}


def bench_reactive(
    args: argparse.Namespace, crowd: str, scenarios: int | None, method: str = "conformal"
) -> dict[str, float]:
    """Print and return the figures of a reactive crowd (``crowd``) on the suite's dev
    split (the first ``scenarios``) with ``method``: the per-episode loop against the batch
    engine, and the metrics compared field by field."""
    from conformal_control.core.jit import compile_now
    from conformal_control.experiments.bench import load_scenario, load_suite
    from conformal_control.experiments.bench.methods import expand_methods
    from conformal_control.runs.engines.batch import run_batch, supports
    from conformal_control.runs.episode import run_episode

    compile_now()
    warnings.simplefilter("ignore")
    suite = load_suite("crossings-v1")
    dev = suite.scenarios_for("dev")[:scenarios]
    kw = {**expand_methods([method])[0].run_kwargs(), "crowd": crowd}
    assert supports(**kw) is None, supports(**kw)
    print(f"\n== {suite.name} dev split, crowd {crowd}: {len(dev)} scenarios, method {method}")
    scenes = [load_scenario(s, args.data_root) for s in dev]
    frames = [s.max_frames for s in dev]
    run_batch(scenes[:1], max_frames=frames[:1], **kw)  # warm
    run_episode(scenes[0], max_frames=frames[0], record_animation=False, engine="loop", **kw)
    w, c = time.perf_counter(), time.process_time()
    ref = [
        run_episode(s, max_frames=f, record_animation=False, engine="loop", **kw).metrics
        for s, f in zip(scenes, frames, strict=True)
    ]
    ew, ec = time.perf_counter() - w, time.process_time() - c
    w, c = time.perf_counter(), time.process_time()
    got = run_batch(scenes, max_frames=frames, batch_size=args.batch_size, **kw)
    bw, bc = time.perf_counter() - w, time.process_time() - c
    n = len(dev)
    differing = sum(
        bool(same_metrics(r.as_dict(), g.as_dict())) for r, g in zip(ref, got, strict=True)
    )
    steps = sum(m.n_steps for m in ref)
    print(f"per-episode loop: {_fmt(ew, ec)}  ({ec / steps * 1e6:6.1f} us CPU per control step)")
    print(f"batch engine:     {_fmt(bw, bc)}  ({bc / steps * 1e6:6.1f} us CPU per control step)")
    print(f"speed-up: {ew / bw:.1f}x wall, {ec / bc:.1f}x CPU (target 8x)")
    print(
        f"metrics differing: {differing} episodes of {n} (every field but wall_s, compared exactly)"
    )
    return {"n": n, "wall": bw, "cpu": bc, "base_wall": ew, "base_cpu": ec, "differing": differing}


Figure = tuple[str, float, str, "float | None", "float | None"]


def _reactive_rows(d: dict[str, float], crowd: str, method: str) -> list:
    """Figures of :func:`bench_reactive` (run_all's dict form: the 8x target as a time)."""
    name = f"batch crossings-v1 dev crowd {crowd} {method} {d['n']} scenarios"
    rows: list = []
    for kind in ("wall", "cpu"):
        base, value = d[f"base_{kind}"], d[kind]
        rows.append(
            {
                "section": "batch",
                "name": f"{name} {'wall' if kind == 'wall' else 'CPU'}",
                "value": float(value),
                "unit": "s",
                "target": float(base) / 8.0,
                "ratios": [("the per-episode loop", float(base), "faster")],
                "note": "target: 8x faster than the per-episode loop",
            }
        )
    rows.append((f"{name} metrics differing", d["differing"], "episodes", d["n"], None))
    return rows


def measure(
    seeds: int = 1000,
    quick: bool = False,
    *,
    baseline: int | None = None,
    batch_size: int = 128,
    data_root: str | Path | None = None,
    cache: str | None = None,
    suite: bool = True,
    reactive: bool = True,
) -> list[Figure]:
    """The benchmark's figures as ``(name, value, unit, baseline, ratio)`` rows.

    ``ratio`` is ``baseline / value`` for times (the speed-up of the batch engine over
    the per-episode loop timed in the same run). ``quick`` caps the crossing seeds at
    200, times the per-episode loop on 10 of them and takes the first 40 scenarios of
    the dev split (about a minute once the scene cache exists); the reactive crowds run
    on the first 40 scenarios of the dev split (every one without ``quick``). The ``*_differing``
    rows count episodes whose metrics differ from ``run_episode``'s (expected 0).
    """
    n = min(seeds, 200) if quick else seeds
    args = argparse.Namespace(
        seeds=n,
        baseline=baseline or (10 if quick else 40),
        batch_size=batch_size,
        data_root=Path(data_root) if data_root else ROOT.parent / "shared" / "data",
        cache=cache,
        workers=2,
        scenarios=40 if quick else None,
    )
    c = bench_crossing(args)
    out: list[Figure] = [
        (
            f"batch crossing {n} seeds wall",
            c["wall"],
            "s",
            c["base_wall"],
            c["base_wall"] / c["wall"],
        ),
        (f"batch crossing {n} seeds CPU", c["cpu"], "s", c["base_cpu"], c["base_cpu"] / c["cpu"]),
        (f"batch crossing {n} seeds peak memory", c["peak_mb"], "MB", None, None),
        ("batch crossing metrics differing", c["differing"], "episodes", c["n_base"], None),
    ]
    if suite:
        for method, count in (
            ("nolearn", None),
            ("acp", 10 if quick else 40),
            ("fallback:relax", 5 if quick else 20),
        ):
            d = bench_suite(args, method, count)
            name = f"batch crossings-v1 dev {method} {d['n']} scenarios"
            out += [
                (f"{name} wall", d["wall"], "s", d["base_wall"], d["base_wall"] / d["wall"]),
                (f"{name} CPU", d["cpu"], "s", d["base_cpu"], d["base_cpu"] / d["cpu"]),
                (f"{name} metrics differing", d["differing"], "episodes", d["n"], None),
            ]
    if reactive:
        for crowd in ("social_force", "orca"):
            d = bench_reactive(args, crowd, 40 if quick else None)
            out += _reactive_rows(d, crowd, "conformal")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--seeds", type=int, default=1000)
    ap.add_argument("--baseline", type=int, default=40, help="seeds timed per episode")
    ap.add_argument("--batch-size", type=int, default=128)
    ap.add_argument("--data-root", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--cache", default=None, help="crossing scene cache (default ~/.cache)")
    ap.add_argument("--workers", type=int, default=2, help="processes generating scenes")
    ap.add_argument("--no-suite", action="store_true", help="skip the suite's dev split")
    ap.add_argument("--scenarios", type=int, default=None, help="first N dev scenarios only")
    ap.add_argument("--scenarios-acp", type=int, default=40, help="dev scenarios with acp")
    ap.add_argument("--scenarios-relax", type=int, default=20, help="... with relax")
    ap.add_argument(
        "--reactive", type=int, default=40, help="dev scenarios with reactive crowds (0: none)"
    )
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child_crossing(Path(args.cache), args.seeds, args.batch_size)
        return
    bench_crossing(args)
    if not args.no_suite:
        bench_suite(args)
        bench_suite(args, "acp", args.scenarios_acp)
        bench_suite(args, "fallback:relax", args.scenarios_relax)
    if args.reactive:
        for crowd in ("social_force", "orca", "mixed"):
            bench_reactive(args, crowd, args.reactive)


if __name__ == "__main__":
    main()
