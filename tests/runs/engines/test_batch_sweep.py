"""The ``batch`` executor of sweeps and benchmarks records what the per-episode runs record."""

from __future__ import annotations

import dataclasses
import json

import pytest

from conformal_control.experiments import run_sweep
from conformal_control.experiments.batch import batch_reason
from conformal_control.experiments.bench.suite import read_rows, run_bench
from conformal_control.experiments.plan import SweepRun

#: Columns that measure the machine or the process, not the episode.
MACHINE = {"wall_s", "elapsed_s", "worker", "finished_at", "run_dir"}


def _by_key(rows):
    return {r["key"]: {k: v for k, v in r.items() if k not in MACHINE} for r in rows}


def _same_rows(a, b):
    assert a.keys() == b.keys()
    for key in a:
        ra, rb = a[key], b[key]
        assert ra.keys() == rb.keys()
        for col in ra:
            same = ra[col] == rb[col] or (ra[col] != ra[col] and rb[col] != rb[col])  # NaN
            assert same, (key, col, ra[col], rb[col])


def test_bench_run_batched_equals_serial(tmp_path, data_root):
    kw = {
        "suite": "crossings-v1",
        "split": "dev",
        "methods": [
            "conformal",
            "conformal_pid",
            "conformal_dtaci",
            "conformal_aci",
            "fallback:relax",
            "acp",
        ],
        "grids": {"conformal": [-0.1]},
        "data_root": str(data_root),
        "limit": 2,
        "progress": False,
    }
    batched = run_bench(tmp_path / "batch", executor="batch", workers=1, **kw)
    serial = run_bench(tmp_path / "serial", executor="serial", **kw)
    assert batched.failed == serial.failed == 0 and batched.ran == serial.ran == 12
    rows_b, rows_s = read_rows(tmp_path / "batch"), read_rows(tmp_path / "serial")
    _same_rows(_by_key(rows_b), _by_key(rows_s))
    # every method (any rule, the collision loss, the relax fallback, acp) ran batched
    batched_runs = {r["label"] for r in rows_b if r["worker"].endswith("(batch)")}
    assert batched_runs == {r["label"] for r in rows_b}
    assert len(batched_runs) == 12
    # config.json is the per-episode run's, plus the engine
    for r in rows_b:
        cb = json.loads((tmp_path / "batch" / r["run_dir"] / "config.json").read_text())
        cs = json.loads((tmp_path / "serial" / r["run_dir"] / "config.json").read_text())
        if r["worker"].endswith("(batch)"):
            assert cb.pop("engine") == "batch"
        cs.pop("engine")  # the serial run's run_episode engine ("auto" picks either)
        cb.pop("engine", None)
        assert cb == cs


def _crossing_runs(n=3):
    return [
        SweepRun.from_settings("crossing", seed=s, max_frames=60, record_animation=False)
        for s in range(n)
    ]


def test_sweep_batch_falls_back_run_by_run_when_a_batch_fails(tmp_path, monkeypatch):
    import conformal_control.runs.engines.batch as engine

    real = engine.iter_batch

    def failing(*args, **kwargs):  # the batch dies after its first episode
        it = real(*args, **kwargs)
        yield next(it)
        raise RuntimeError("boom")

    monkeypatch.setattr(engine, "iter_batch", failing)
    rep = run_sweep(_crossing_runs(), tmp_path / "a", "batch", workers=1, summary_plot=False)
    assert not rep.failed and len(rep.ran) == 3
    ref = run_sweep(_crossing_runs(), tmp_path / "b", "serial", summary_plot=False)
    _same_rows(_by_key(rep.rows), _by_key(ref.rows))
    assert sum(r["worker"].endswith("(batch)") for r in rep.rows) == 1


@pytest.mark.parametrize(
    ("cfg", "plot", "words"),
    [
        ({}, False, "animation"),
        ({}, True, "plot"),
        ({"barrier": "distance_squared"}, "metrics", "barrier"),
        ({"family": "mpc"}, "none", "family 'mpc'"),
    ],
)
def test_batch_reason(cfg, plot, words):
    assert words in batch_reason(SweepRun.from_settings("crossing", **cfg), plot)


def test_batch_reason_batches_compiled_and_fast_predictors_only():
    from conformal_control.core import registry
    from conformal_control.predictors.constant_velocity import ConstantVelocityPredictor

    class Slow(ConstantVelocityPredictor, batchable=False):
        pass

    class Fast(ConstantVelocityPredictor, batchable=True):
        pass

    registry.register("predictor", "slow_sweep_test", Slow)
    registry.register("predictor", "fast_sweep_test", Fast)
    try:
        reasons = {
            name: batch_reason(SweepRun.from_settings("crossing", predictor=name), "none")
            for name in ("oracle", "constant_velocity", "fast_sweep_test", "slow_sweep_test")
        }
    finally:
        registry.unregister("predictor", "slow_sweep_test")
        registry.unregister("predictor", "fast_sweep_test")
    assert reasons.pop("slow_sweep_test") == (
        "predictor 'slow_sweep_test' is not declared batchable: its runs predict in parallel "
        "on the pool"
    )
    assert reasons == dict.fromkeys(reasons)
    assert (
        "unknown"
        in batch_reason(SweepRun.from_settings("crossing", predictor="nope"), "none").lower()
    )


def test_batch_reason_accepts_metrics_only_runs():
    assert batch_reason(SweepRun("crossing"), "metrics") is None
    quiet = SweepRun.from_settings("crossing", record_animation=False)
    assert batch_reason(quiet, False) is None


def test_pool_runs_while_the_batch_runs(monkeypatch, tmp_path):
    # the pool's runs must not wait for the batched groups: here the batch itself waits
    # (up to 20 s) until the pool has delivered a result; run one after the other, the
    # batch would time out and the order below would differ
    import threading

    import conformal_control.experiments.batch as sweep_batch
    import conformal_control.runs.engines.batch as sim_batch

    pool_delivered = threading.Event()

    class FakePool:
        def run(self, fn, tasks):
            for k, _ in enumerate(tasks):
                yield k, {"key": f"pool{k}", "status": "ok"}
                pool_delivered.set()

    waited: list[bool] = []

    def fake_iter_batch(scenes, *a, **k):
        for j, _ in enumerate(scenes):
            waited.append(pool_delivered.wait(20))
            yield j, object()

    monkeypatch.setattr(sim_batch, "iter_batch", fake_iter_batch)
    monkeypatch.setattr(
        sweep_batch, "_record", lambda cfg, key, out, plot, result, t0: {"key": key}
    )
    monkeypatch.setattr("conformal_control.experiments.worker.load_run_scene", lambda cfg: _Scene())
    batched = SweepRun.from_settings("crossing", seed=0, record_animation=False)
    pooled = SweepRun.from_settings("crossing", seed=1, barrier="distance_squared")
    tasks = [(batched, "b0", str(tmp_path), "none"), (pooled, "p0", str(tmp_path), "none")]
    assert batch_reason(batched, "none") is None and batch_reason(pooled, "none") is not None
    records = dict(sweep_batch.run_batched(FakePool(), tasks))
    assert waited == [True], "the pool did not run while the batch ran"
    assert records == {0: {"key": "b0"}, 1: {"key": "pool0", "status": "ok"}}


@dataclasses.dataclass
class _Scene:
    meta: dict = dataclasses.field(default_factory=dict)
    defaults: dict = dataclasses.field(default_factory=dict)

    def replace(self, **changes: object) -> _Scene:  # as Scene.replace
        return dataclasses.replace(self, **changes)
