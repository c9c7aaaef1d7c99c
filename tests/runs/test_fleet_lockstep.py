"""A fleet stepped by the lockstep engine (each control instant's robots in compiled calls,
``conformal_control.runs.engines.batch.fleet``) equals the per-fleet loop in every field:
fleet metrics, every robot's metrics, contacts, trajectory, commands, lambda and intervals,
the track (pair-frames, deadlocks) -- on constructed fleets and on real
``multi-crossings-v1`` entries, and row by row through ``bench run --robots``."""

from __future__ import annotations

import json

import numpy as np
import pytest

import conformal_control.runs.fleet as fleet_mod
from conformal_control.runs.engines.batch.fleet import FleetRun, lockstep_reason
from conformal_control.runs.fleet import run_multi

from .test_fleet_compiled import _fields, _same
from .test_multi_reciprocal import _walls, free_scene


def _spied(monkeypatch: pytest.MonkeyPatch) -> list[FleetRun]:
    """The lockstep engine's counts of every fleet it runs."""
    runs: list[FleetRun] = []
    real = fleet_mod.drive_lockstep

    def spy(*a, **kw):  # type: ignore[no-untyped-def]
        out = real(*a, **kw)
        runs.append(out)
        return out

    monkeypatch.setattr(fleet_mod, "drive_lockstep", spy)
    return runs


SQUEEZED = dict(
    starts=[(0.0, 0.9), (0.0, -0.9)],
    goals=[[(3.0, 0.9)], [(3.0, -0.9)]],
    max_frames=120,
    learn=False,
)
ANTIPODAL = dict(robots=5, layout="antipodal", radius=3.0, center=(5.0, 0.0), max_frames=200)

CASES = {
    # two robots squeezed between walls of pedestrians: most steps go to the priority
    # stages (handed back to the robots' own decide)
    "squeezed": lambda: (_walls(1.13), SQUEEZED),
    "squeezed_calm": lambda: (_walls(1.13), {**SQUEEZED, "floor_core": "calm"}),
    # five robots through the centre of a free scene: most steps compiled; parked robots
    "antipodal": lambda: (free_scene(300), ANTIPODAL),
    "antipodal_velocity": lambda: (free_scene(300), {**ANTIPODAL, "information": "velocity"}),
    "antipodal_position": lambda: (free_scene(300), {**ANTIPODAL, "information": "position"}),
    # robots first: the kernel's other codes (lambda search) handed back too
    "antipodal_robots_first": lambda: (free_scene(300), {**ANTIPODAL, "priority": "robots"}),
    # unequal shares, a robot that ignores the others (its steps are its own decide's)
    "antipodal_weights_ignoring": lambda: (
        free_scene(300),
        {**ANTIPODAL, "weights": [1.0, 2.0, 1.0, 3.0, 1.0], "ignoring": [2]},
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_lockstep_fleet_equals_the_per_fleet_loop(case, monkeypatch):
    scene, kw = CASES[case]()
    loop = run_multi(scene, record_animation=False, engine="loop", **kw)
    runs = _spied(monkeypatch)
    fast = run_multi(scene, record_animation=False, **kw)
    (run,) = runs
    assert run.compiled_steps > 0
    if case.startswith("squeezed"):  # the priority stages: the robots' own decide
        assert run.python_steps > 0.3 * run.compiled_steps
    _same(_fields(loop), _fields(fast), case)
    for a, b in zip(loop.robots, fast.robots, strict=True):  # the loops' own logs
        assert [(iv.k, iv.lam, iv.loss, iv.n_steps) for iv in a.loop.intervals] == [
            (iv.k, iv.lam, iv.loss, iv.n_steps) for iv in b.loop.intervals
        ]
        assert a.loop.lambda_final == b.loop.lambda_final
    assert sum(len(r.steps["t"]) for r in fast.robots) >= run.compiled_steps


def test_lockstep_reason_names_what_it_does_not_run(crossing):
    seen: list[str | None] = []
    real = fleet_mod.lockstep_reason

    def spy(world, steppers):  # type: ignore[no-untyped-def]
        why = real(world, steppers)
        seen.append(why)
        return why

    with pytest.MonkeyPatch.context() as m:
        m.setattr(fleet_mod, "lockstep_reason", spy)
        run_multi(crossing, robots=2, crowd="social_force", max_frames=5, record_animation=False)
        run_multi(
            crossing,
            robots=2,
            max_frames=5,
            record_animation=False,
            coordination="yield",
            information="plan",
        )
        run_multi(crossing, robots=2, max_frames=5, record_animation=False)
    assert seen[0] is not None and "crowd" in seen[0]
    assert seen[1] is not None and "coordination='yield'" in seen[1]
    assert seen[2] is None
    assert lockstep_reason is real
    with pytest.raises(ValueError, match="engine must be"):
        run_multi(crossing, robots=2, max_frames=5, engine="fast")


def _entry(data_root, index: int, robots: int):  # type: ignore[no-untyped-def]
    from conformal_control.experiments.bench.multi import (
        entry_scene,
        entry_tasks,
        load_multi_suite,
    )

    suite = load_multi_suite()
    entries = [e for e in suite.entries if e.split == "test"]
    base, starts, goals = entry_tasks(suite, entries[index], robots)
    return entry_scene(base, suite.time_factor, str(data_root)), starts, goals


@pytest.mark.data
@pytest.mark.parametrize(
    "index, learn, floor_core",
    [
        (0, True, "always"),
        (0, False, "inside"),
        (1, True, "calm"),
        (1, True, "ahead"),
        (1, False, "none"),
    ],
)
def test_real_fleets_equal_the_per_fleet_loop(data_root, monkeypatch, index, learn, floor_core):
    """Five robots on a ``multi-crossings-v1`` test entry (reciprocal, plans broadcast),
    flagship and ``nolearn``, each ``floor_core``."""
    scene, starts, goals = _entry(data_root, index, 5)
    kw = dict(
        starts=starts,
        goals=goals,
        max_frames=min(scene.meta["max_frames"], 150),
        seed=7,
        learn=learn,
        floor_core=floor_core,
        record_animation=False,
    )
    loop = run_multi(scene, engine="loop", **kw)
    runs = _spied(monkeypatch)
    fast = run_multi(scene, **kw)
    assert runs and runs[0].compiled_steps > runs[0].python_steps
    _same(_fields(loop), _fields(fast), f"entry {index}")
    assert json.dumps(loop.config, sort_keys=True) == json.dumps(fast.config, sort_keys=True)


@pytest.mark.data
def test_a_fleet_benchmark_through_the_lockstep_engine_equals_the_loop_row_by_row(
    tmp_path, data_root, monkeypatch
):
    """``bench run --robots`` (one worker: in this process) through the lockstep engine
    writes the per-fleet loop's rows, every field but the times."""
    from conformal_control.experiments.bench.multi import run_multi_bench

    kw = dict(
        robots=(3,),
        split="test",
        limit=2,
        methods=("conformal", "nolearn"),
        reciprocity=("reciprocal",),
        data_root=str(data_root),
        workers=1,
    )
    rows = {}
    for loop in (True, False):
        with monkeypatch.context() as m:
            runs = _spied(m)
            if loop:
                m.setattr(fleet_mod, "lockstep_reason", lambda world, steppers: "the loop")
            out = tmp_path / f"bench-{loop}"
            assert run_multi_bench(out, **kw).ran == 4
        assert bool(runs) != loop and all(r.compiled_steps > 0 for r in runs)
        lines = (out / "results.jsonl").read_text().splitlines()
        rows[loop] = sorted(
            (
                {
                    k: v
                    for k, v in json.loads(line).items()
                    if k not in ("wall_s", "cpu_s", "elapsed_s")
                }
                for line in lines
            ),
            key=lambda r: r["key"],
        )
    assert len(rows[True]) == 4
    _same(rows[True], rows[False], "rows")


def test_the_steps_log_of_a_lockstep_fleet_is_the_worlds(monkeypatch):
    """Per robot, the per-instant record holds one row per decision (its commands are
    the decisions) and its goal time is the last row's time."""
    res = run_multi(free_scene(300), record_animation=False, **ANTIPODAL)
    for r in res.robots:
        t = r.steps["t"]
        assert np.all(np.diff(t) > 0)
        assert r.steps["cmd"].shape == (t.size, 2) == (r.steps["x"].shape[0], 2)
        if r.metrics.goal_reached:
            assert r.metrics.t_goal == pytest.approx(t[-1])
