"""Round 4 of the speed work (issue 37): what an episode costs under a predictor shift, in
a fleet and with a sampling-MPC family, each against the plain single-robot CBF episode
timed in the same run.

Usage::

    python benchmarks/bench_round4.py [--data-root ../shared/data] [--only shift learned]

Every figure is the time per episode of ``bench run`` on the first test scenarios, run in
this process with one worker (``workers=1``: the process pool and the in-process batch
engine use one core alike), after a warm-up run that loads the compiled kernels; wall time
(``time.perf_counter``) and this process's CPU time with its children's.

* ``shift``: ``delay-0.5s`` against ``nominal`` (40 scenarios x ``nolearn``, ``conformal``),
  and the same shift with its wrapper called in Python per episode and interval (the
  engine before it compiled the shifts) -- target 1.3x nominal;
* ``learned``: the ``learned`` shift (Trajectron++'s published forecasts replayed by the
  ``recorded`` predictor, compiled in the engine) against ``nominal`` on the same scenarios
  (the first test scenarios of ``crossings-v2`` are biwi_eth's, which it covers), and the
  same shift with the predictor called in Python per episode and interval (the engine before
  it compiled the recorded forecasts);
* ``mpc``: the ``mpc`` family against ``conformal`` (20 scenarios; the MPC families run in
  this process one episode after another, ``runs.engines.mpc_batch``, not in the compiled
  lockstep engine) -- target 5x; wall time, and the CPU time of this process (every episode
  of both runs in it);
* ``fleet``: a robot of a 5-robot fleet (``bench run --robots 5``, reciprocal; fleets run
  one per task, each with its control instants' robots stepped together in compiled calls,
  ``runs.engines.batch.fleet``: the plain steps compiled, the priority stages handed to the
  robots' own decide) against a single-robot episode -- target 3x; the same fleets through
  the per-fleet loop (one robot's decision at a time, its plain steps compiled) and with
  every step on the generic path (the loop as before either), with the share of steps
  handed over.

:func:`measure` returns the figures as dicts (``benchmarks/run_all.py``'s form).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import resource
import sys
import tempfile
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def _cpu() -> float:
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _best_of(repeats: int, run: Any, what: str) -> tuple[float, float, int]:
    """(wall, CPU, episodes) of the fastest of ``repeats`` calls of ``run(folder)`` into
    fresh folders; ``run`` returns ``(episodes, failed)``."""
    best: tuple[float, float, int] | None = None
    for _ in range(repeats):
        with tempfile.TemporaryDirectory(prefix="cc-round4-") as tmp, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            c0, t0 = _cpu(), time.perf_counter()
            episodes, failed = run(Path(tmp) / "b")
            wall, cpu = time.perf_counter() - t0, _cpu() - c0
        if failed:
            raise RuntimeError(f"{failed} episodes failed ({what})")
        if best is None or wall < best[0]:
            best = (wall, cpu, episodes)
    assert best is not None
    return best


def time_bench(data_root: str, limit: int, repeats: int = 1, **kw: Any) -> tuple[float, float, int]:
    """(wall, CPU, episodes) of the better of ``repeats`` ``run_bench`` calls into fresh
    folders (one worker)."""
    from conformal_control.experiments.bench.suite import run_bench

    def run(folder: Path) -> tuple[int, int]:
        r = run_bench(folder, data_root=data_root, limit=limit, workers=1, progress=False, **kw)
        return r.ran, r.failed

    return _best_of(repeats, run, str(kw))


def _supports_module() -> Any:
    """The batch engine's ``supports`` module (by its dotted name: the package re-exports the
    function :func:`supports` under the same name, so ``from ...batch import supports`` gives
    the function, not the module whose tables these benchmarks empty)."""
    return importlib.import_module("conformal_control.runs.engines.batch.supports")


@contextlib.contextmanager
def python_recorded() -> Iterator[None]:
    """The batch engine with the ``recorded`` predictor called per episode (as before it
    replayed the forecasts compiled): the predictor is then the episode's own object."""
    batch = _supports_module()
    code = batch.PREDICTORS.pop("recorded")
    try:
        yield
    finally:
        batch.PREDICTORS["recorded"] = code


def _load() -> str:
    return "load average " + " ".join(f"{x:.1f}" for x in os.getloadavg())


@contextlib.contextmanager
def python_shifts() -> Iterator[None]:
    """The batch engine with the shifts' wrappers called per episode (as before they ran
    compiled): the predictor is then the episode's own object."""
    batch = _supports_module()
    saved = dict(batch.SHIFTS)
    batch.SHIFTS.clear()
    try:
        yield
    finally:
        batch.SHIFTS.update(saved)


def _fig(section: str, name: str, value: float, unit: str, **kw: Any) -> dict[str, Any]:
    return {
        "section": section,
        "name": name,
        "value": value,
        "unit": unit,
        "target": kw.get("target"),
        "ratios": kw.get("ratios", []),
        "note": kw.get("note", ""),
    }


def measure_shift(data_root: str, quick: bool = False) -> list[dict[str, Any]]:
    limit, repeats = (10, 1) if quick else (40, 3)
    kw = {"methods": ("nolearn", "conformal")}
    time_bench(data_root, 2, shifts=("delay-0.5s",), **kw)  # warm-up: kernels loaded
    nom = time_bench(data_root, limit, repeats, shifts=("nominal",), **kw)
    delay = time_bench(data_root, limit, repeats, shifts=("delay-0.5s",), **kw)
    with python_shifts():
        before = time_bench(data_root, limit, repeats, shifts=("delay-0.5s",), **kw)
    per = [w / n for w, _, n in (nom, delay, before)]
    cpu = [c / n for _, c, n in (nom, delay, before)]
    note = (
        f"{delay[2]} episodes ({limit} test scenarios x nolearn, conformal), one worker, best "
        f"of {repeats}; CPU per episode {cpu[1] * 1e3:.1f} ms against {cpu[0] * 1e3:.1f} ms "
        f"nominal ({cpu[1] / cpu[0]:.2f}x), {cpu[2] * 1e3:.1f} ms with the wrapper in Python "
        "per episode"
    )
    return [
        _fig(
            "shift",
            "delay-0.5s episode (shift compiled)",
            per[1],
            "ms",
            target=1.3 * per[0],
            note=note,
            ratios=[
                ("a nominal episode", per[0], "times"),
                ("the wrapper called in Python (as before)", per[2], "faster"),
            ],
        ),
    ]


def measure_learned(data_root: str, quick: bool = False) -> list[dict[str, Any]]:
    limit, repeats = (10, 1) if quick else (40, 3)
    kw = {"methods": ("nolearn", "conformal")}
    time_bench(data_root, 2, shifts=("learned",), **kw)  # warm-up: kernels, files loaded
    loads = [_load()]
    nom = time_bench(data_root, limit, repeats, shifts=("nominal",), **kw)
    learned = time_bench(data_root, limit, repeats, shifts=("learned",), **kw)
    with python_recorded():
        before = time_bench(data_root, limit, repeats, shifts=("learned",), **kw)
    loads.append(_load())
    if not nom[2] == learned[2] == before[2]:
        raise RuntimeError(f"episodes differ: nominal {nom[2]}, learned {learned[2]}/{before[2]}")
    per = [w / n for w, _, n in (nom, learned, before)]
    cpu = [c / n for _, c, n in (nom, learned, before)]
    note = (
        f"{learned[2]} episodes ({limit} test scenarios of biwi_eth x nolearn, conformal), one "
        f"worker, best of {repeats}; CPU per episode {cpu[1] * 1e3:.1f} ms against "
        f"{cpu[0] * 1e3:.1f} ms nominal ({cpu[1] / cpu[0]:.2f}x), {cpu[2] * 1e3:.1f} ms with "
        f"the predictor in Python per episode ({cpu[2] / cpu[0]:.2f}x); {loads[0]} before, "
        f"{loads[1]} after"
    )
    return [
        _fig(
            "shift",
            "learned episode (recorded forecasts compiled)",
            per[1],
            "ms",
            note=note,
            ratios=[
                ("a nominal episode", per[0], "times"),
                ("the predictor called in Python (as before)", per[2], "faster"),
            ],
        ),
    ]


def measure_mpc(data_root: str, quick: bool = False) -> list[dict[str, Any]]:
    """An ``mpc`` episode against a ``conformal`` (CBF) episode on the same scenarios."""
    limit, repeats = (5, 1) if quick else (20, 2)
    time_bench(data_root, 1, methods=("mpc", "conformal"))  # warm-up: kernels loaded
    loads = [_load()]
    cbf = time_bench(data_root, limit, repeats, methods=("conformal",))
    mpc = time_bench(data_root, limit, repeats, methods=("mpc",))
    loads.append(_load())
    per = [w / n for w, _, n in (cbf, mpc)]
    cpu = [c / n for _, c, n in (cbf, mpc)]
    note = (
        f"{mpc[2]} mpc and {cbf[2]} conformal episodes (the first {limit} test scenarios; "
        "mpc, a reference family, runs its whole margin grid), one worker (the MPC family "
        "in this process one episode after another, the CBF in the lockstep engine), best "
        f"of {repeats}; CPU per episode {cpu[1] * 1e3:.1f} ms against {cpu[0] * 1e3:.1f} ms "
        f"({cpu[1] / cpu[0]:.2f}x); {loads[0]} before, {loads[1]} after"
    )
    return [
        _fig(
            "mpc",
            "mpc episode (sampling MPC, fixed margin)",
            per[1],
            "ms",
            target=5.0 * per[0],
            note=note,
            ratios=[("a conformal CBF episode", per[0], "times")],
        )
    ]


def time_fleet(data_root: str, limit: int, robots: int, repeats: int) -> tuple[float, float, int]:
    """(wall, CPU, robot episodes) of the better of ``repeats`` reciprocal ``conformal``
    fleet runs of ``robots`` robots on the first ``limit`` multi-robot test entries."""
    from conformal_control.experiments.bench.multi import run_multi_bench

    def run(folder: Path) -> tuple[int, int]:
        r = run_multi_bench(
            folder,
            robots=(robots,),
            methods=("conformal",),
            reciprocity=("reciprocal",),
            data_root=data_root,
            workers=1,
            limit=limit,
        )
        return r.ran * robots, r.failed

    return _best_of(repeats, run, f"{robots}-robot fleets")


@contextlib.contextmanager
def generic_fleet() -> Iterator[None]:
    """Every robot of a fleet decided by the generic Python path (the compiled step off:
    the per-fleet loop as before the robot rows first were compiled)."""
    from conformal_control.families.cbf.controller import ConformalCBFController

    parts = ConformalCBFController._apf_parts
    ConformalCBFController._apf_parts = lambda self: False  # type: ignore[method-assign]
    try:
        yield
    finally:
        ConformalCBFController._apf_parts = parts  # type: ignore[method-assign]


@contextlib.contextmanager
def per_fleet_loop() -> Iterator[None]:
    """Every fleet through the per-fleet loop (``runs.fleet.drive``: one robot's decision
    at a time), not the lockstep engine."""
    from conformal_control.runs import fleet

    reason = fleet.lockstep_reason
    fleet.lockstep_reason = lambda world, steppers: "the per-fleet loop"  # type: ignore[assignment]
    try:
        yield
    finally:
        fleet.lockstep_reason = reason  # type: ignore[assignment]


@contextlib.contextmanager
def counting_steps(seen: dict[str, int]) -> Iterator[None]:
    """Count the robots' decisions: those of the lockstep engine's compiled call
    (``compiled``) and those handed to the robots' own ``decide`` (``decide``), of which
    the generic path's (``generic``)."""
    from conformal_control.families.cbf.controller import ConformalCBFController
    from conformal_control.runs import fleet

    decide, generic = ConformalCBFController.decide, ConformalCBFController._decide_generic
    lockstep = fleet.drive_lockstep

    def counted(self: Any, *a: Any) -> Any:
        seen["decide"] = seen.get("decide", 0) + 1
        return decide(self, *a)

    def handed(self: Any, *a: Any) -> Any:
        seen["generic"] = seen.get("generic", 0) + 1
        return generic(self, *a)

    def stepped(*a: Any, **kw: Any) -> Any:
        out = lockstep(*a, **kw)
        seen["compiled"] = seen.get("compiled", 0) + out.compiled_steps
        return out

    ConformalCBFController.decide = counted  # type: ignore[method-assign]
    ConformalCBFController._decide_generic = handed  # type: ignore[method-assign]
    fleet.drive_lockstep = stepped  # type: ignore[assignment]
    try:
        yield
    finally:
        ConformalCBFController.decide = decide  # type: ignore[method-assign]
        ConformalCBFController._decide_generic = generic  # type: ignore[method-assign]
        fleet.drive_lockstep = lockstep  # type: ignore[assignment]


def measure_fleet(data_root: str, quick: bool = False) -> list[dict[str, Any]]:
    """A robot of a 5-robot reciprocal fleet against a single-robot ``conformal`` episode."""
    limit, repeats = (2, 1) if quick else (4, 1)
    time_fleet(data_root, 1, 5, 1)  # warm-up: kernels loaded (those of 5-robot fleets too)
    loads = [_load()]
    single = time_bench(data_root, 20, 2, methods=("conformal",))
    fleet = time_fleet(data_root, limit, 5, repeats)
    with per_fleet_loop():
        loop = time_fleet(data_root, limit, 5, repeats)
        with generic_fleet():
            before = time_fleet(data_root, limit, 5, repeats)
    loads.append(_load())
    seen: dict[str, int] = {}
    with counting_steps(seen):  # not timed
        time_fleet(data_root, limit, 5, 1)
    per = [w / n for w, _, n in (single, fleet, loop, before)]
    cpu = [c / n for _, c, n in (single, fleet, loop, before)]
    steps = seen.get("compiled", 0) + seen.get("decide", 0)
    note = (
        f"{fleet[2]} robot episodes (the first {limit} multi-crossings-v1 test entries, "
        f"5 robots, reciprocal, conformal), one worker (fleets run one per task, each in the "
        f"lockstep engine of fleets), against {single[2]} single-robot episodes (20 "
        f"crossings-v2 test scenarios, lockstep engine); CPU per robot "
        f"{cpu[1] * 1e3:.1f} ms against {cpu[0] * 1e3:.1f} ms ({cpu[1] / cpu[0]:.1f}x), "
        f"{cpu[2] * 1e3:.1f} ms through the per-fleet loop, {cpu[3] * 1e3:.1f} ms with every "
        f"step on the generic path; of {steps} steps {seen.get('compiled', 0)} decided by "
        f"the compiled call, {seen.get('decide', 0)} handed to the robots' own decide "
        f"({seen.get('generic', 0)} of them to the generic path); {loads[0]} before, "
        f"{loads[1]} after"
    )
    return [
        _fig(
            "fleet",
            "a robot of a 5-robot fleet (reciprocal)",
            per[1],
            "ms",
            target=3.0 * per[0],
            note=note,
            ratios=[
                ("a single-robot episode", per[0], "times"),
                ("the per-fleet loop (one robot's decision at a time)", per[2], "faster"),
                ("every step on the generic path (the loop as before)", per[3], "faster"),
            ],
        )
    ]


#: section -> function, in the order :func:`measure` runs them
MEASURES = {
    "shift": measure_shift,
    "learned": measure_learned,
    "mpc": measure_mpc,
    "fleet": measure_fleet,
}


def measure(
    data_root: str, quick: bool = False, only: tuple[str, ...] = ()
) -> list[dict[str, Any]]:
    unknown = sorted(set(only) - set(MEASURES))
    if unknown:
        raise ValueError(f"unknown section(s) {unknown}; choose from {sorted(MEASURES)}")
    out: list[dict[str, Any]] = []
    for name, fn in MEASURES.items():
        if not only or name in only:
            out += fn(data_root, quick)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    default = os.environ.get("CONFORMAL_CONTROL_DATA", str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--data-root", default=default)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", nargs="+", default=[])
    args = ap.parse_args()
    print(f"load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    for f in measure(args.data_root, args.quick, tuple(args.only)):
        ratios = "; ".join(
            f"{f['value'] / b if k == 'times' else b / f['value']:.2f}x "
            f"{'of' if k == 'times' else 'faster than'} {n} ({b * 1e3:.1f} ms)"
            for n, b, k in f["ratios"]
        )
        print(f"{f['name']}: {f['value'] * 1e3:.1f} ms per episode; {ratios}\n  {f['note']}")
    print(f"load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    sys.exit(main())
