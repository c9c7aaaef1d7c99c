"""A suite on a Dask cluster (``bench run --scheduler ADDRESS``): the same records as here."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import distributed  # the sweep extra, installed by the README: a missing one fails

from conformal_control.cli import main
from conformal_control.experiments.batch import run_chunked
from conformal_control.experiments.bench.suite import read_rows
from conformal_control.experiments.executors.serial import SerialExecutor

#: one method without learning, one learning method, one whose fallback decides in Python
#: (relax; these three batched), one the engine does not batch (cc_mpc: the sampling MPC)
METHODS = "nolearn,conformal,fallback:relax,cc_mpc"


def _bench(out: Path, data: Path, *extra: str) -> None:
    # --tuned none: every method's own settings (conformal's three epsilons), not the
    # values shipped for the suite
    argv = ["bench", "run", "--split", "dev", "--limit", "3", "--methods", METHODS]
    argv += ["--tuned", "none"]
    argv += ["--data-root", str(data)]
    with contextlib.redirect_stdout(io.StringIO()):
        assert main([*argv, "--out", str(out), "--progress", "off", *extra]) == 0


def _metrics(out: Path) -> dict[str, dict]:
    rows = read_rows(out)
    assert rows and all(r["status"] == "ok" for r in rows), rows
    return {r["key"]: {k: v for k, v in r.items() if k.startswith("metric.")} for r in rows}


def test_a_suite_on_a_two_worker_cluster_equals_the_serial_run(
    tmp_path: Path, data_root: Path
) -> None:
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
        host="127.0.0.1", protocol="tcp://",
    ) as cluster:  # fmt: skip
        _bench(tmp_path / "cluster", data_root, "--scheduler", cluster.scheduler_address)
        with distributed.Client(cluster) as client:
            workers = {w["id"] for w in client.scheduler_info()["workers"].values()}
    _bench(tmp_path / "serial", data_root, "--executor", "serial")
    on_cluster, serial = _metrics(tmp_path / "cluster"), _metrics(tmp_path / "serial")
    # 3 scenarios x (1 + 3 + 1 + 1)
    assert on_cluster.keys() == serial.keys() and len(serial) == 3 * 6
    for key, metrics in serial.items():
        wall = {k for k in metrics if "wall" in k}
        assert {k: v for k, v in on_cluster[key].items() if k not in wall} == {
            k: v for k, v in metrics.items() if k not in wall
        }, key
    assert len(workers) == 2
    # the records say where they ran: batched chunks and single runs on the workers
    journal = [json.loads(line) for line in (tmp_path / "cluster" / "results.jsonl").open()]
    where = {r["worker"] for r in journal}
    assert any(w.endswith("(batch)") for w in where)
    assert any(not w.endswith("(batch)") for w in where)


def test_scheduler_and_another_executor_conflict(tmp_path: Path, capsys) -> None:
    argv = ["bench", "run", "--scheduler", "tcp://127.0.0.1:1", "--executor", "process"]
    assert main([*argv, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "--scheduler runs on a Dask cluster: drop --executor process" in err


class _Cluster(SerialExecutor):
    """A serial executor that calls itself distributed and loses one job."""

    distributed = True
    n_workers = 2

    def __init__(self, lose: int | None = None) -> None:
        self.jobs: list[int] = []
        self.lose = lose

    def run(self, fn, tasks):  # type: ignore[no-untyped-def]
        for i, args in enumerate(tasks):
            self.jobs.append(len(args))
            if i == self.lose:
                yield i, ConnectionError("worker lost")
            else:
                yield i, fn(*args)


def test_chunks_cover_every_run_once_and_a_lost_chunk_fails_its_runs(tmp_path: Path) -> None:
    from conformal_control.experiments import SweepRun

    cfg = {"max_frames": 30, "record_animation": False}
    runs = [SweepRun.from_settings("crossing", seed=s, **cfg) for s in range(20)]
    tasks = [(run, f"k{s}", str(tmp_path), "metrics") for s, run in enumerate(runs)]
    other = SweepRun.from_settings("crossing", barrier="distance_squared", **cfg)  # not batched
    tasks.append((other, "other", str(tmp_path), "metrics"))
    ex = _Cluster()
    got = dict(run_chunked(ex, tasks, chunk=8))
    assert sorted(got) == list(range(21))
    assert ex.jobs == [1, 1, 1, 4]  # three chunks (8 + 8 + 4 runs), the other run alone
    assert all(r["status"] == "ok" for r in got.values())
    lost = dict(run_chunked(_Cluster(lose=1), tasks, chunk=8))
    failed = sorted(i for i, r in lost.items() if isinstance(r, BaseException))
    assert failed == list(range(8, 16))
