"""In the per-fleet loop, a fleet whose robots decide through the compiled step
(priority "pedestrians": the plain steps compiled, the priority stages and the edge rule
with robots handed to the generic path step by step) equals the fleet decided by the
generic Python path in every field: metrics, every robot's trajectory, commands, lambda
and intervals, pair-frames, the filters' counters."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from conformal_control.families.cbf.controller import ConformalCBFController
from conformal_control.runs.fleet import run_multi

from .test_multi_reciprocal import _walls, free_scene


def _counted(monkeypatch: pytest.MonkeyPatch, generic: bool) -> dict[str, int]:
    """Count the decisions and those of the generic path; with ``generic`` every robot
    takes the generic path (the compiled step off: the per-fleet loop as it was)."""
    seen = {"decide": 0, "generic": 0}
    decide = ConformalCBFController.decide
    slow = ConformalCBFController._decide_generic

    def counted_decide(self, state, lam):  # type: ignore[no-untyped-def]
        seen["decide"] += 1
        return decide(self, state, lam)

    def counted_generic(self, state, lam, off):  # type: ignore[no-untyped-def]
        seen["generic"] += 1
        return slow(self, state, lam, off)

    monkeypatch.setattr(ConformalCBFController, "decide", counted_decide)
    monkeypatch.setattr(ConformalCBFController, "_decide_generic", counted_generic)
    if generic:
        monkeypatch.setattr(ConformalCBFController, "_apf_parts", lambda self: False)
    return seen


#: What a run measures of the machine (wall and CPU time), not of the robots.
TIMING = {"wall_s", "wall_s_per_robot", "cpu_s"}


def _timeless(d: dict) -> dict:
    return {k: v for k, v in d.items() if k not in TIMING}


def _same(a: object, b: object, where: str) -> None:
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), where
        for j, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{j}]")
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif isinstance(a, float) and math.isnan(a):
        assert isinstance(b, float) and math.isnan(b), where
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


def _fields(res) -> dict:  # type: ignore[no-untyped-def]
    robots = []
    for r in res.robots:
        robots.append(
            {
                "metrics": _timeless(r.metrics.as_dict()),
                "contacts": dataclasses.asdict(r.contacts),
                "trajectory": dict(r.trajectory),
                "steps": dict(r.steps),
                "intervals": [_timeless(iv) for iv in r.intervals],
            }
        )
    return {"fleet": _timeless(res.metrics.as_dict()), "robots": robots, "track": res.track}


CASES = {
    # four robots and a reactive crowd through the crossing scene
    "crossing": lambda crossing: (
        crossing,
        dict(robots=4, crowd="social_force", max_frames=100, seed=3),
    ),
    # two robots squeezed between walls of pedestrians: the priority stages decide
    "squeezed": lambda crossing: (
        _walls(1.13),
        dict(
            starts=[(0.0, 0.9), (0.0, -0.9)],
            goals=[[(3.0, 0.9)], [(3.0, -0.9)]],
            max_frames=120,
            learn=False,
        ),
    ),
    # the same with floor_core="calm": the walls inside the robots' collision distance
    # from the pedestrians let the pairs' cores give way
    "squeezed_calm": lambda crossing: (
        _walls(1.13),
        dict(
            starts=[(0.0, 0.9), (0.0, -0.9)],
            goals=[[(3.0, 0.9)], [(3.0, -0.9)]],
            max_frames=120,
            learn=False,
            floor_core="calm",
        ),
    ),
    # the same with floor_core="ahead": the pairs' cores give way while the walls'
    # pedestrians are still coming (predicted inside within the look-ahead)
    "squeezed_ahead": lambda crossing: (
        _walls(1.13),
        dict(
            starts=[(0.0, 0.9), (0.0, -0.9)],
            goals=[[(3.0, 0.9)], [(3.0, -0.9)]],
            max_frames=120,
            learn=False,
            floor_core="ahead",
        ),
    ),
    # five robots through the centre of a free scene, swapping ends
    "antipodal": lambda crossing: (
        free_scene(300),
        dict(robots=5, layout="antipodal", radius=3.0, center=(5.0, 0.0), max_frames=200),
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_compiled_fleet_step_equals_the_generic_loop(case, crossing, monkeypatch):
    scene, kw = CASES[case](crossing)
    with monkeypatch.context() as m:
        loop_seen = _counted(m, generic=True)
        loop = run_multi(scene, record_animation=False, engine="loop", **kw)
    with monkeypatch.context() as m:
        fast_seen = _counted(m, generic=False)
        fast = run_multi(scene, record_animation=False, engine="loop", **kw)
    assert loop_seen["generic"] == loop_seen["decide"] > 0
    assert fast_seen["decide"] == loop_seen["decide"]
    if case.startswith("squeezed"):  # squeezed most of the time: the priority stages decide
        assert fast_seen["generic"] > 0.5 * fast_seen["decide"]
        assert all(r.metrics.n_fallback > 0 for r in fast.robots)
    else:  # most steps compiled
        assert fast_seen["generic"] < 0.2 * fast_seen["decide"]
    _same(_fields(loop), _fields(fast), case)


@pytest.mark.data
def test_a_fleet_benchmark_equals_the_generic_loop_row_by_row(tmp_path, data_root, monkeypatch):
    """``bench run --robots`` (one worker: in this process) with the compiled step writes
    the rows the generic loop writes, every field but the times."""
    import json

    from conformal_control.experiments.bench.multi import run_multi_bench

    kw = dict(
        robots=(4,),
        split="test",
        limit=1,
        methods=("conformal",),
        reciprocity=("reciprocal",),
        data_root=str(data_root),
        workers=1,
    )
    rows = {}
    for generic in (True, False):
        with monkeypatch.context() as m:
            seen = _counted(m, generic=generic)
            # the per-fleet loop (test_fleet_lockstep.py: the lockstep engine equals it)
            m.setattr("conformal_control.runs.fleet.lockstep_reason", lambda w, s: "the loop")
            out = tmp_path / f"bench-{generic}"
            assert run_multi_bench(out, **kw).ran == 1
        assert (seen["generic"] == seen["decide"]) == generic and seen["decide"] > 0
        lines = (out / "results.jsonl").read_text().splitlines()
        rows[generic] = [
            {k: v for k, v in json.loads(line).items() if k not in ("wall_s", "cpu_s", "elapsed_s")}
            for line in lines
        ]
    assert len(rows[True]) == 1
    _same(rows[True], rows[False], "rows")
