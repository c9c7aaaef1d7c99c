"""Sweeps: spec expansion and keys, resume, failure isolation, executors (incl. real Dask)."""

from __future__ import annotations

import csv
import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from conformal_control.cli import main
from conformal_control.experiments import (
    ResultsStore,
    SerialExecutor,
    SweepRun,
    SweepSpec,
    execute_run,
    load_spec,
    parse_grid_option,
    run_sweep,
)
from conformal_control.experiments.executors import Executor
from conformal_control.experiments.worker import cached_scene


def need(module: str):
    """Import an optional dependency of the `sweep` extra; fail (never skip) without it."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        pytest.fail(f"{module} missing: pip install -e '.[dev,sweep]'", pytrace=False)


def rows(path: Path) -> list[dict[str, str]]:
    with (path / "results.csv").open() as fh:
        return list(csv.DictReader(fh))


# ---------------------------------------------------------------------------- spec
def test_grid_expansion_and_keys() -> None:
    spec = SweepSpec(
        base={"scene": "crossing", "frames": 30},
        grid={"epsilon": [-0.1, 0.1], "seed": [0, 1], "predictor_params.window": [3]},
        runs=[{"label": "learn"}, {"label": "nolearn", "learn": False}],
    )
    runs = spec.expand()
    assert len(runs) == 2 * 2 * 2
    assert len({r.key for r in runs}) == 8
    r = runs[0]
    assert r.spec.params == {"epsilon": -0.1}
    assert r.spec.role("predictor") == ("constant_velocity", {"window": 3})
    assert r.spec.max_frames == 30 and r.spec.learn is True and r.label == "learn"
    # the key ignores label and data root, and 4 == 4.0
    a = SweepRun.from_flat({"scene": "nexus_4", "tau": 4, "label": "x", "data_root": "/a"})
    b = SweepRun.from_flat({"scene": "nexus_4", "tau": 4.0, "label": "y"})
    c = SweepRun.from_flat({"scene": "nexus_4", "tau": 8})
    assert a.key == b.key != c.key
    # duplicates collapse
    dup = SweepSpec(base={"scene": "crossing"}, runs=[{"label": "a"}, {"label": "b"}])
    assert len(dup.expand()) == 1


def test_spec_errors() -> None:
    with pytest.raises(ValueError, match="unknown sweep key"):
        SweepRun.from_flat({"scene": "crossing", "epsilonn": 0.1})
    with pytest.raises(ValueError, match="needs a 'scene'"):
        SweepRun.from_flat({"epsilon": 0.1})
    with pytest.raises(ValueError, match="unknown section"):
        SweepSpec.from_mapping({"grids": {}})
    with pytest.raises(ValueError, match="KEY=V1"):
        parse_grid_option(["epsilon"])
    assert parse_grid_option(["epsilon=-0.25,0", "fallback=brake"]) == {
        "epsilon": [-0.25, 0],
        "fallback": ["brake"],
    }


@pytest.mark.parametrize("suffix", ["yaml", "json", "toml"])
def test_load_spec_formats(tmp_path: Path, suffix: str) -> None:
    text = {
        "yaml": "base:\n  scene: crossing\ngrid:\n  epsilon: [-0.1, 0.1]\n",
        "json": '{"base": {"scene": "crossing"}, "grid": {"epsilon": [-0.1, 0.1]}}',
        "toml": '[base]\nscene = "crossing"\n[grid]\nepsilon = [-0.1, 0.1]\n',
    }[suffix]
    path = tmp_path / f"spec.{suffix}"
    path.write_text(text)
    runs = load_spec(path).expand()
    assert [r.spec.params["epsilon"] for r in runs] == [-0.1, 0.1]


# ---------------------------------------------------------------------------- running
class InterruptAfter(SerialExecutor):
    """Serial executor interrupted (like Ctrl-C) after ``n`` completed runs."""

    def __init__(self, n: int) -> None:
        self.n = n

    def run(self, fn, tasks) -> Iterator:
        for i, out in super().run(fn, tasks):
            if i >= self.n:
                raise KeyboardInterrupt
            yield i, out


def test_resume_skips_finished_runs(tmp_path: Path) -> None:
    spec = SweepSpec(base={"scene": "crossing", "frames": 30}, grid={"epsilon": [-0.2, 0, 0.2]})
    out = tmp_path / "sw"
    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, out, InterruptAfter(2), plot=False, progress=False)
    store = ResultsStore(out)
    # both runs journaled before the interrupt are kept, and the third, which finished
    # (its run directory is complete) but was interrupted before its journal line, is
    # journaled from its run directory
    assert len(store.finished()) == 3
    assert [bool(r.get("recovered")) for r in store.records()] == [False, False, True]
    assert len(rows(out)) == 3
    report = run_sweep(spec, out, "serial", plot=False, progress=False)
    assert len(report.skipped) == 3 and report.ran == [] and not report.failed
    (out / "results.jsonl").write_bytes(  # as before: the third run's line is lost
        b"".join((out / "results.jsonl").read_bytes().splitlines(keepends=True)[:2])
    )
    report = run_sweep(spec, out, "serial", plot=False, progress=False)
    assert len(report.skipped) == 2 and len(report.recovered) == 1 and report.ran == []
    # nothing left to do
    report = run_sweep(spec, out, "serial", plot=False, progress=False)
    assert len(report.skipped) == 3 and report.ran == []
    # a run whose directory was deleted is redone; a widened grid only adds new runs
    victim = Path(report.rows[0]["run_dir"])
    for f in victim.iterdir():
        f.unlink()
    wider = SweepSpec(base=spec.base, grid={"epsilon": [-0.2, 0, 0.2, 0.3]})
    report = run_sweep(wider, out, "serial", plot=False, progress=False)
    assert sorted(report.ran) == sorted([report.keys[0], report.keys[3]])
    table = rows(out)
    assert len(table) == 4 and {r["status"] for r in table} == {"ok"}
    assert len(store.records()) == 5  # the journal keeps every attempt
    # every run directory holds the run's full config incl. its sweep key
    cfg = json.loads((Path(report.rows[3]["run_dir"]) / "config.json").read_text())
    assert cfg["sweep"]["key"] == report.keys[3]
    assert cfg["params"]["given"]["epsilon"] == 0.3


def test_failure_is_recorded_and_others_finish(tmp_path: Path) -> None:
    out = tmp_path / "sw"
    # a window of 0 or -1 passes validation (a known parameter name) and fails inside the
    # run, when the predictor first predicts: a genuine run-time failure
    spec = SweepSpec(
        base={"scene": "crossing", "frames": 30},
        runs=[
            {"epsilon": 0.1},
            {"predictor_params.window": 0},
            {"predictor_params.window": -1},
            {"epsilon": -0.1},
        ],
    )
    report = run_sweep(spec, out, "process", workers=2, progress=False, summary_plot=False)
    assert len(report.failed) == 2 and len(report.ran) == 4
    by_key = {r["key"]: r for r in rows(out)}
    assert [by_key[k]["status"] for k in report.keys] == ["ok", "failed", "failed", "ok"]
    rec = ResultsStore(out).latest()[report.keys[1]]
    assert "window must be a positive integer, got 0" in rec["error"]
    assert "Traceback" in rec["traceback"] and "predict" in rec["traceback"]
    assert "got -1" in ResultsStore(out).latest()[report.keys[2]]["error"]
    # a resumed sweep retries failed runs (they fail again) unless told not to
    again = run_sweep(spec, out, "serial", progress=False, summary_plot=False)
    assert sorted(again.ran) == sorted(report.failed)
    kept = run_sweep(spec, out, "serial", progress=False, retry_failed=False)
    assert kept.ran == []


def test_unvalidated_bad_parameters_fail_as_runs(tmp_path: Path) -> None:
    """``validate=False`` lets invalid runs start; they are recorded, the others finish."""
    spec = SweepSpec(
        base={"scene": "crossing", "frames": 30},
        runs=[{"epsilon": 0.7}, {"tau": -1.0}, {"epsilon": -0.1}],
    )
    report = run_sweep(spec, tmp_path, "serial", validate=False, progress=False)
    assert [r["status"] for r in report.rows] == ["failed", "failed", "ok"]
    rec = ResultsStore(tmp_path).latest()[report.keys[0]]
    assert "epsilon must lie in" in rec["error"] and "resolve_params" in rec["traceback"]
    assert "tau" in report.rows[1]["error"]


def test_runs_sharing_a_scene_do_not_leak_into_each_other(tmp_path: Path) -> None:
    """Building an episode sets radii/v_max on its scene: runs must not see each other's."""
    base = {"scene": "crossing", "frames": 40}
    big = SweepRun.from_flat({**base, "robot_radius": 2.0, "v_max": 1.0})
    plain = SweepRun.from_flat(base)
    alone = execute_run(plain, "alone", str(tmp_path / "a"), False)
    cached_scene.cache_clear()
    first = execute_run(big, "big", str(tmp_path / "b"), False)
    after = execute_run(plain, "after", str(tmp_path / "b"), False)
    assert first["status"] == after["status"] == alone["status"] == "ok"
    from conformal_control.data import load_scene

    cached, fresh = cached_scene("crossing", None, 0), load_scene("crossing")
    assert (cached.robot_radius, cached.v_max) == (fresh.robot_radius, fresh.v_max)
    assert fresh.robot_radius != 2.0 and fresh.v_max != 1.0
    for k in ("t_goal", "n_collide", "d_min", "l_avg"):
        assert after["metrics"][k] == alone["metrics"][k]
    assert first["metrics"]["d_min"] != alone["metrics"]["d_min"]


def test_cli_sweep_grid_and_dry_run(tmp_path: Path, capsys) -> None:
    out = tmp_path / "cli"
    argv = ["sweep", "--scene", "crossing", "--set", "frames=30", "--grid", "epsilon=-0.1,0.1"]
    assert main([*argv, "--out", str(out), "--dry-run"]) == 0
    assert "2 runs" in capsys.readouterr().out
    assert main([*argv, "--out", str(out), "--executor", "serial"]) == 0
    assert "2 ran (0 failed)" in capsys.readouterr().out
    assert {r["param.epsilon"] for r in rows(out)} == {"-0.1", "0.1"}
    # a failing run makes the exit status 1, the others are still written
    bad = [*argv[:-1], "epsilon=-0.1", "--grid", "predictor_params.window=0"]
    assert main([*bad, "--out", str(out), "--executor", "serial"]) == 1
    assert len(rows(out)) == 3


def test_parquet_table(tmp_path: Path) -> None:
    pq = need("pyarrow.parquet")
    spec = SweepSpec(
        base={"scene": "crossing", "frames": 30},
        runs=[{"epsilon": 0.1}, {"predictor_params.window": 0}],
    )
    run_sweep(spec, tmp_path, "serial", progress=False)
    table = pq.read_table(tmp_path / "results.parquet").to_pylist()
    assert [r["status"] for r in table] == ["ok", "failed"]
    assert table[0]["goal_reached"] in (True, False) and table[1]["error"]


def test_parquet_off_writes_the_csv_only_and_removes_a_stale_table(tmp_path: Path) -> None:
    need("pyarrow.parquet")
    spec = SweepSpec(base={"scene": "crossing", "frames": 30}, runs=[{"epsilon": 0.1}])
    run_sweep(spec, tmp_path, "serial", progress=False)
    assert (tmp_path / "results.parquet").is_file()
    more = SweepSpec(base={"scene": "crossing", "frames": 30}, grid={"epsilon": [0.1, 0.2]})
    run_sweep(more, tmp_path, "serial", progress=False, parquet=False)
    # the old table had one run; it would no longer match the journal, so it is gone
    assert not (tmp_path / "results.parquet").exists()
    assert {r["param.epsilon"] for r in rows(tmp_path)} == {"0.1", "0.2"}


def test_progress_off_starts_no_thread(tmp_path: Path) -> None:
    """A sweep without a progress bar leaves the process single-threaded (tqdm's first
    bar, even disabled, starts a monitor thread), so the report's figures may fork."""
    import subprocess
    import sys

    code = (
        "import threading\n"
        "from conformal_control.experiments import SweepSpec, run_sweep\n"
        "spec = SweepSpec(base={'scene': 'crossing', 'frames': 20}, runs=[{}])\n"
        f"run_sweep(spec, {str(tmp_path)!r}, 'serial', progress=False, summary_plot=False)\n"
        "print(sorted(t.name for t in threading.enumerate()))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip().splitlines()[-1] == "['MainThread']"


# ---------------------------------------------------------------------------- Dask
def test_dask_local_cluster_same_results_as_serial(tmp_path: Path, sdd_dir: Path) -> None:
    distributed = need("distributed")
    from conformal_control.experiments.executors.dask import DaskExecutor

    spec = SweepSpec(
        base={"scene": "nexus_4", "data_root": str(sdd_dir), "frames": 90, "a": 10},
        grid={"tau": [4, 8], "eta": [0.1, 1]},
        runs=[{}, {"predictor_params.window": 0}],  # four failing runs ride along
    )
    serial = run_sweep(spec, tmp_path / "serial", "serial", plot=False, progress=False)
    with (
        distributed.LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=False,
            protocol="tcp://",  # real TCP on loopback, not the in-process transport
            host="127.0.0.1",
            dashboard_address=None,
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        ex = DaskExecutor(client=client)
        assert ex.n_workers == 2
        report = run_sweep(spec, tmp_path / "dask", ex, plot=False, progress=False)
        assert client.status == "running"  # a client handed in is not closed
    assert len(report.ran) == 8 and len(report.failed) == 4
    assert report.keys == serial.keys
    for a, b in zip(serial.rows, report.rows, strict=True):
        assert a["status"] == b["status"]
        if a["status"] != "ok":
            assert a["error"] == b["error"]
            continue
        for k in ("t_goal", "n_collide", "d_min", "l_avg", "lambda_final", "identity_residual"):
            assert a[k] == b[k]
    # resume on the Dask path too
    ex = DaskExecutor(workers=1, processes=False)  # the executor's own LocalCluster
    again = run_sweep(spec, tmp_path / "dask", ex, progress=False, retry_failed=False)
    ex.close()
    assert again.ran == [] and len(again.skipped) == 8


def test_process_pool_workers_run_single_threaded_blas(monkeypatch) -> None:
    import os

    from conformal_control.experiments import ProcessExecutor

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    with ProcessExecutor(workers=2) as ex:
        seen = dict(ex.run(os.getenv, [("OMP_NUM_THREADS",)]))
    assert seen[0] == "1"
    assert "OMP_NUM_THREADS" not in os.environ  # the driver's environment is restored


def test_process_pool_survives_a_dying_worker() -> None:
    """A worker killed mid-run fails its own task; the pool restarts and the rest run."""
    from concurrent.futures.process import BrokenProcessPool

    from conformal_control.experiments import ProcessExecutor

    tasks = [("1 + 1",), ("__import__('os')._exit(3)",), ("2 + 2",), ("3 + 3",)]
    with ProcessExecutor(workers=1) as ex:
        out = dict(ex.run(eval, tasks))
    assert len(out) == 4 and isinstance(out[1], BrokenProcessPool)
    assert out[0] == 2 and out[3] == 6  # before the crash, and on the restarted pool
    assert out[2] == 4 or isinstance(out[2], BrokenProcessPool)  # in flight when it died


class InstantExecutor(Executor):
    """Every run 'finishes' at once with a fixed record: the sweep's own overhead only."""

    name = "instant"

    def run(self, fn, tasks) -> Iterator:
        for i, (_cfg, key, _out, _plot) in enumerate(tasks):
            yield i, {"key": key, "status": "ok", "run_dir": None, "metrics": {"t_goal": 1.0}}


def test_tables_are_not_rewritten_after_every_run(tmp_path: Path, monkeypatch) -> None:
    """Rewriting the tables after each run made a sweep quadratic in its size."""
    calls = []
    real = ResultsStore.write_tables

    def counted(self, *a, **k):
        calls.append(len(self.latest()))
        return real(self, *a, **k)

    monkeypatch.setattr(ResultsStore, "write_tables", counted)
    grid = {"epsilon": [round(-0.45 + 0.9 * i / 400, 6) for i in range(400)]}
    spec = SweepSpec(base={"scene": "crossing", "frames": 10}, grid=grid)
    report = run_sweep(
        spec, tmp_path, InstantExecutor(), validate=False, summary_plot=False, progress=False
    )
    assert len(report.ran) == 400
    assert len(calls) <= 3 and calls[-1] == 400  # at the end (and at most every 30 s)
    assert len(rows(tmp_path)) == 400
    # an explicit count still works: every 100 runs, plus the end
    calls.clear()
    run_sweep(
        spec,
        tmp_path / "b",
        InstantExecutor(),
        validate=False,
        summary_plot=False,
        progress=False,
        table_every=100,
    )
    assert calls == [100, 200, 300, 400, 400]


def test_a_huge_grid_is_refused_before_it_is_expanded(monkeypatch) -> None:
    import conformal_control.experiments.plan as spec_mod

    huge = SweepSpec(grid={"epsilon": list(range(10**4)), "eta": list(range(10**4))})
    assert huge.size() == 10**8
    with pytest.raises(ValueError, match=r"100,000,000 runs \(10000 epsilon x 10000 eta\)"):
        huge.expand()  # at once: nothing is built (it used to take 5.6 GB, then MemoryError)
    monkeypatch.setattr(spec_mod, "MAX_RUNS", 50)
    small = SweepSpec(base={"scene": "crossing"}, runs=[{}, {"seed": 1}], grid={"eta": [0, 1] * 13})
    with pytest.raises(ValueError, match=r"52 runs \(2 runs x 26 eta\), more than the 50"):
        small.expand()


def test_cli_refuses_a_huge_grid_in_one_line(tmp_path: Path, capsys) -> None:
    values = ",".join(str(i) for i in range(1001))
    argv = ["sweep", "--scene", "crossing", "--out", str(tmp_path / "s"), "--dry-run"]
    code = main([*argv, "--grid", f"seed={values}", "--grid", f"frames={values}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "1,002,001 runs" in err[0], err


def test_progress_is_reported_in_lines_when_the_output_is_redirected(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The issue: `bench tune` with its output redirected printed nothing for a minute (the
    bar was for terminals only). Redirected (here: captured), a sweep prints a line per
    period with the runs done and the time left, and a last line; no carriage return."""
    import conformal_control.core.progress as progress_mod

    monkeypatch.setattr(progress_mod, "DELAY", 0.0)
    monkeypatch.setattr(progress_mod, "EVERY", 0.0)
    monkeypatch.delenv("CONFORMAL_CONTROL_PROGRESS", raising=False)
    spec = SweepSpec(base={"scene": "crossing", "frames": 10}, grid={"epsilon": [-0.2, 0, 0.2]})
    run_sweep(spec, tmp_path / "s", "serial", plot=False, summary_plot=False)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("sweep:")]
    assert "\r" not in err
    assert lines[0].startswith("sweep: 1/3 runs (33%), ") and lines[0].endswith(" s left")
    assert lines[-1].startswith("sweep: done, 3 runs in ")
    run_sweep(spec, tmp_path / "t", "serial", plot=False, summary_plot=False, progress=False)
    assert "sweep:" not in capsys.readouterr().err


def test_runs_of_one_configuration_are_one_run_said_and_counted(tmp_path: Path) -> None:
    # two labels, one configuration (labels and meta are not hashed): the journal keeps one
    # row per key, so the second was collapsed into the first without a word
    from conformal_control.core.exceptions import ConformalControlWarning

    a = SweepRun.from_settings("crossing", {"epsilon": 0.1}, label="oracle_mpc", max_frames=30)
    b = SweepRun.from_settings("crossing", {"epsilon": 0.1}, label="mpc", max_frames=30)
    c = SweepRun.from_settings("crossing", {"epsilon": 0.2}, label="other", max_frames=30)
    assert a.key == b.key != c.key
    with pytest.warns(
        ConformalControlWarning, match=r"1 run\(s\) left out: .*\(mpc = oracle_mpc\)"
    ):
        report = run_sweep([a, b, c], tmp_path / "sw", "serial", plot=False, progress=False)
    assert report.keys == [a.key, c.key] and len(report.ran) == 2
    assert any("mpc = oracle_mpc" in n for n in report.notes)
    assert [r["label"] for r in rows(tmp_path / "sw")] == ["oracle_mpc", "other"]
