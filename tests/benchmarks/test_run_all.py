"""``benchmarks/run_all.py``: the figures' text, the docs section it writes, the batch hook.

Nothing here times anything: the script's timings are measured when it runs, never
asserted.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def run_all():
    spec = importlib.util.spec_from_file_location("_run_all", ROOT / "benchmarks" / "run_all.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_ratios_read_the_right_way_round(run_all):
    f = run_all.figure(
        "s", "step", 5e-6, "us", target=10e-6,
        ratios=[("piqp", 50e-6, "faster"), ("python -c pass", 1e-6, "times")],
    )  # fmt: skip
    assert run_all.fmt_ratio(f["value"], "piqp", 50e-6, "faster", "us").startswith(
        "10.0x faster than piqp (50.0 us)"
    )
    assert run_all.fmt_ratio(f["value"], "p", 1e-6, "times", "us").startswith("5.0x p")
    assert run_all.fmt_target(f) == "<= 10.0 us (met)"
    assert run_all.fmt_target({**f, "value": 11e-6}) == "<= 10.0 us (not met)"
    assert run_all.fmt_time(12.5, "us") == "12.5 s"  # 12.5e6 us: shown in a larger unit


def _results(run_all):
    figs = [run_all.figure("c", "control step", 5e-6, "us", target=10e-6, note="median")]
    return [("Controller", figs, ""), ("Batch", [], "batch engine: not available")]


def test_docs_section_replaces_only_its_own_block(run_all, tmp_path):
    info = {"date": "D", "cpu": "C", "python": "P", "commit": "abc", "load": "1", "load_end": "2"}
    page = tmp_path / "benchmarks.md"
    page.write_text("# Benchmarks\n\nIntro.\n\n## Hand-written section\n\nKeep me.\n")
    run_all.write_docs(page, run_all.markdown(_results(run_all), info, quick=False))
    first = page.read_text()
    assert first.index("Intro.") < first.index(run_all.BEGIN) < first.index("Keep me.")
    assert "| control step | 5.0 us | <= 10.0 us (met) |" in first
    assert "Batch engine: not available." in first
    assert "Measured D on C" in first
    # a second run replaces the block and leaves the rest as it was
    info["date"] = "E"
    run_all.write_docs(page, run_all.markdown(_results(run_all), info, quick=True))
    second = page.read_text()
    assert (
        second.count(run_all.BEGIN) == 1 and "Measured E" in second and "Measured D" not in second
    )
    assert second.split(run_all.END)[1] == first.split(run_all.END)[1]
    assert second.split(run_all.BEGIN)[0] == first.split(run_all.BEGIN)[0]


def test_batch_section_uses_bench_batch_measure_when_it_exists(run_all, monkeypatch):
    args = argparse.Namespace(quick=True, data_root=Path("/data"))
    monkeypatch.setitem(sys.modules, "bench_batch", None)  # import fails
    assert run_all.sec_batch(args) == "batch engine: not available on this branch"
    monkeypatch.setitem(sys.modules, "bench_batch", types.ModuleType("bench_batch"))
    assert "no measure()" in run_all.sec_batch(args)
    fake = types.ModuleType("bench_batch")
    seen = {}

    def measure(quick, data_root):
        seen.update(quick=quick, data_root=data_root)
        return [run_all.figure("batch", "1,000 crossing seeds", 12.0, "s", target=15.0)]

    fake.measure = measure
    monkeypatch.setitem(sys.modules, "bench_batch", fake)
    (fig,) = run_all.sec_batch(args)
    assert fig["name"] == "1,000 crossing seeds" and seen == {
        "quick": True,
        "data_root": args.data_root,
    }


def test_a_failing_section_is_reported_and_the_others_still_run(
    run_all, monkeypatch, capsys, data_root
):
    def boom(args):
        raise ValueError("broken")

    def ok(args):
        return [run_all.figure("x", "fine figure", 1e-3, "ms")]

    monkeypatch.setattr(run_all, "SECTIONS", {"a": ("A", boom), "b": ("B", ok)})
    monkeypatch.setattr(
        run_all, "machine", lambda: {"cpu": "c", "python": "p", "commit": "x", "load": "0"}
    )
    assert run_all.main(["--data-root", str(data_root), "--quick"]) == 0
    out = capsys.readouterr().out
    assert "failed: ValueError: broken" in out
    assert "fine figure" in out


def test_round4_is_a_section_and_names_its_parts(run_all):
    import bench_round4  # run_all put benchmarks/ on sys.path

    assert "round4" in run_all.SECTIONS
    assert list(bench_round4.MEASURES) == ["shift", "learned", "mpc", "fleet"]
    with pytest.raises(ValueError, match=r"unknown section\(s\) \['fleets'\]"):
        bench_round4.measure("/nowhere", only=("fleets",))


def test_round4_python_baselines_empty_and_restore_the_engine_tables(run_all):
    """The per-episode baselines empty the batch engine's compiled-shift and compiled-predictor
    tables while they run and restore them after (the package's ``supports`` is also a
    function's name: reading the tables through it was an AttributeError)."""
    import importlib

    import bench_round4  # run_all put benchmarks/ on sys.path

    tables = importlib.import_module("conformal_control.runs.engines.batch.supports")
    shifts, predictors = dict(tables.SHIFTS), dict(tables.PREDICTORS)
    assert shifts and "recorded" in predictors
    with bench_round4.python_shifts():
        assert tables.SHIFTS == {}
    assert tables.SHIFTS == shifts
    with bench_round4.python_recorded():
        assert "recorded" not in tables.PREDICTORS
    assert tables.PREDICTORS == predictors


def test_round4_fleet_baseline_takes_the_generic_path_and_restores_it(run_all):
    """``generic_fleet`` turns the compiled step off for the fleet baseline and restores it;
    ``counting_steps`` counts decisions and hand-overs and restores the methods."""
    import bench_round4  # run_all put benchmarks/ on sys.path

    from conformal_control.families.cbf import (
        APFBarrier,
        AttractiveField,
        ConformalConstraint,
        Exact2DSafetyFilter,
    )
    from conformal_control.families.cbf.controller import ConformalCBFController as C
    from conformal_control.predictors import ConstantVelocityPredictor

    c = C(
        ConstantVelocityPredictor(),
        ConformalConstraint(APFBarrier(K_rep=0.5, rho0=5.0, d_c=0.7), a=2.0),
        Exact2DSafetyFilter(v_max=1.5),
        AttractiveField(K_att=1.0, v_max=1.5),
    )
    c.reset()
    assert c._fused
    parts, decide, generic = C._apf_parts, C.decide, C._decide_generic
    with bench_round4.generic_fleet():
        c.reset()
        assert not c._fused
    assert C._apf_parts is parts
    from conformal_control.runs import fleet

    reason, lockstep = fleet.lockstep_reason, fleet.drive_lockstep
    seen: dict[str, int] = {}
    with bench_round4.counting_steps(seen):
        assert C.decide is not decide and C._decide_generic is not generic
        assert fleet.drive_lockstep is not lockstep
    assert C.decide is decide and C._decide_generic is generic
    assert fleet.drive_lockstep is lockstep
    with bench_round4.per_fleet_loop():  # every fleet through the per-fleet loop
        assert fleet.lockstep_reason(None, []) == "the per-fleet loop"
    assert fleet.lockstep_reason is reason
