"""A sweep's own bookkeeping is linear in its size, and its journal's fsync is a group commit.

Nothing here times anything: the work is counted (Python lines executed, journal records
read back, table rows written, fsync calls), and the runner's clock is replaced where the
policy under test is a time policy.
"""

from __future__ import annotations

import gc
import sys
import time
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import conformal_control.experiments.runner as runner_mod
from conformal_control.experiments import ResultsStore, SweepRun, run_sweep
from conformal_control.experiments.executors import Executor


class StubExecutor(Executor):
    """Every run 'finishes' at once with a fixed record; ``tick(i)`` is called before each."""

    name = "stub"

    def __init__(self, tick: Any = None, stop_after: int | None = None) -> None:
        self.tick = tick
        self.stop_after = stop_after

    def run(self, fn: Any, tasks: Any) -> Iterator[tuple[int, Any]]:
        for i, (_cfg, key, _out, _plot) in enumerate(tasks):
            if self.stop_after is not None and i == self.stop_after:
                raise KeyboardInterrupt
            if self.tick is not None:
                self.tick(i)
            yield i, {"key": key, "status": "ok", "run_dir": None, "metrics": {"t_goal": 1.0}}


def configs(n: int) -> list[SweepRun]:
    return [
        SweepRun.from_settings("crossing", {"epsilon": -i * 1e-6}, max_frames=5) for i in range(n)
    ]


class FakeClock:
    """The runner's ``time`` module with a clock the test moves."""

    def __init__(self) -> None:
        self.now = 1000.0

    def perf_counter(self) -> float:
        return self.now

    def time(self) -> float:
        return time.time()


def _counted_sweep(tmp_path: Path, n: int, monkeypatch: pytest.MonkeyPatch) -> dict[str, int]:
    """Run an ``n``-run stub sweep and count its work."""
    work = {"lines": 0, "records_read": 0, "rows_built": 0, "fsync": 0}
    real_records = ResultsStore.records
    real_rows = ResultsStore.rows

    def records(self: ResultsStore) -> list[dict[str, Any]]:
        out = real_records(self)
        work["records_read"] += len(out)
        return out

    def rows(self: ResultsStore, *a: Any, **k: Any) -> list[dict[str, Any]]:
        out = real_rows(self, *a, **k)
        work["rows_built"] += len(out)
        return out

    def fsync(fd: int) -> None:
        work["fsync"] += 1

    monkeypatch.setattr(ResultsStore, "records", records)
    monkeypatch.setattr(ResultsStore, "rows", rows)
    monkeypatch.setattr(runner_mod.os, "fsync", fsync)  # the same os module as results.py

    def line(frame: types.FrameType, event: str, arg: Any) -> Any:
        if event == "line":  # a new line, or the same line again through a loop's back jump
            work["lines"] += 1
        return line

    def call(frame: types.FrameType, event: str, arg: Any) -> Any:
        return line

    todo = configs(n)
    sys.settrace(call)
    try:
        report = run_sweep(
            todo, tmp_path / f"s{n}", StubExecutor(), summary_plot=False, progress=False
        )
    finally:
        sys.settrace(None)
    assert len(report.ran) == n and not report.failed
    monkeypatch.undo()
    return work


def test_the_bookkeeping_of_a_run_does_not_grow_with_the_sweep(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ten times the runs, ten times the work (not a hundred): validating, keys, journal,
    result records and tables counted in Python lines executed (loops and comprehensions
    included) and in records read back or rows built (work done in C)."""
    # imports and first-use caches, once, outside the count
    run_sweep(configs(10), tmp_path / "warm", StubExecutor(), summary_plot=False, progress=False)
    small = _counted_sweep(tmp_path, 150, monkeypatch)
    large = _counted_sweep(tmp_path, 1500, monkeypatch)
    for what in ("lines", "records_read", "rows_built"):
        assert small[what] > 0, what
        # linear: 10x (fixed costs make it a little less); one O(n) step per run: ~100x
        assert large[what] <= 11 * small[what], (what, small[what], large[what])
    # the journal is read back at most a few times over the whole sweep, not once per run
    assert large["records_read"] <= 3 * 1500
    # fsync: a group commit (about one a second of stub runs), not one per run
    assert large["fsync"] < 1500 // 10


def test_a_sweep_keeps_no_collected_object_per_run(tmp_path: Path) -> None:
    """Objects the garbage collector tracks, kept per finished run, make its full
    collections (whose cost grows with every tracked object alive) ever longer and more
    frequent as a sweep goes on: the journal's records are kept as bytes until asked for."""
    alive: dict[int, int] = {}

    def tick(i: int) -> None:
        if i in (100, 1100):
            gc.collect()
            alive[i] = len(gc.get_objects())

    run_sweep(configs(1101), tmp_path, StubExecutor(tick), summary_plot=False, progress=False)
    # 1,000 runs in between; parsed records kept in memory: about 5 per run
    assert alive[1100] - alive[100] < 200, alive
    assert len(ResultsStore(tmp_path).records()) == 1101


def _table_rows_per_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, n: int) -> float:
    """Table rows written per run by an ``n``-run sweep on a clock where a run takes 0.2 s
    and a table rewrite 2 ms per row."""
    clock = FakeClock()
    written: list[int] = []

    def write_tables(self: ResultsStore, *, parquet: bool = True) -> list[Path]:
        rows = len(self.latest())
        written.append(rows)
        clock.now += 0.002 * rows
        return []

    def tick(i: int) -> None:
        clock.now += 0.2

    monkeypatch.setattr(runner_mod, "time", clock)
    monkeypatch.setattr(ResultsStore, "write_tables", write_tables)
    monkeypatch.setattr(runner_mod.os, "fsync", lambda fd: None)
    try:
        run_sweep(
            configs(n),
            tmp_path / f"t{n}",
            StubExecutor(tick),
            summary_plot=False,
            progress=False,
            validate=False,
        )
    finally:
        monkeypatch.undo()
    assert written[-1] == n  # the tables at the end hold every run
    assert len(written) >= 3  # rewritten during the sweep too (the policy is exercised)
    # the rewrites take at most about a twentieth of the sweep's time, plus the last one
    assert 0.002 * sum(written[:-1]) <= 0.2 * n / runner_mod.TABLE_COST_RATIO + 0.002 * n
    return sum(written) / n


def test_table_rewrites_stay_a_bounded_multiple_of_the_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The periodic table rewrite waits in proportion to its cost, which grows with the
    table: the rows written per run stay bounded as the sweep grows tenfold (a fixed period
    would write ten times more rows per run)."""
    per_run = {n: _table_rows_per_run(tmp_path, monkeypatch, n) for n in (1_000, 10_000)}
    # each rewrite waits 20x its cost: 20 x 2 ms x rows = 0.2 x rows seconds = 0.2 x rows
    # more runs, so the table grows 1.2x between rewrites and all of them sum to about 6x
    # the final table, plus the final one; a fixed 30 s period: 4 at 1,000 runs, 34 at 10,000
    assert per_run[1_000] <= 8 and per_run[10_000] <= 8, per_run


def _journal_events(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    n: int,
    run_s: float,
    events: list[tuple[str, bool]],
    **kw: Any,
) -> None:
    """Record in ``events`` the appends (with their ``sync`` flag) and fsyncs, in order, of
    an ``n``-run sweep whose runs take ``run_s`` seconds on the runner's clock."""
    clock = FakeClock()
    real_append = ResultsStore.append

    def append(self: ResultsStore, record: dict[str, Any], *, sync: bool = True) -> None:
        events.append(("append", sync))
        real_append(self, record, sync=sync)

    def fsync(fd: int) -> None:
        events.append(("fsync", True))

    def tick(i: int) -> None:
        clock.now += run_s

    monkeypatch.setattr(runner_mod, "time", clock)
    monkeypatch.setattr(ResultsStore, "append", append)
    monkeypatch.setattr(runner_mod.os, "fsync", fsync)
    try:
        run_sweep(
            configs(n), tmp_path, StubExecutor(tick, **kw), summary_plot=False, progress=False
        )
    finally:
        monkeypatch.undo()


def test_journal_fsync_is_a_group_commit(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # fast runs (10 ms each): one fsync per second of results, and one at the end
    events: list[tuple[str, bool]] = []
    _journal_events(tmp_path / "fast", monkeypatch, 500, 0.01, events)
    appends = [e for e in events if e[0] == "append"]
    assert len(appends) == 500
    synced = sum(1 for _, sync in appends if sync)
    assert 4 <= synced <= 6  # 5 s of runs, the first line synced at once
    assert events[-1] == ("fsync", True)  # nothing is left unsynced at the end
    assert len(ResultsStore(tmp_path / "fast").records()) == 500
    # slow runs (2 s each): every line is synced as it is written, as before
    events.clear()
    _journal_events(tmp_path / "slow", monkeypatch, 20, 2.0, events)
    appends = [e for e in events if e[0] == "append"]
    assert len(appends) == 20 and all(sync for _, sync in appends)


def test_a_stopped_sweep_syncs_the_lines_it_wrote(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    events: list[tuple[str, bool]] = []
    with pytest.raises(KeyboardInterrupt):
        _journal_events(tmp_path, monkeypatch, 300, 0.001, events, stop_after=200)
    appends = [k for k, (what, _) in enumerate(events) if what == "append"]
    assert len(appends) == 200  # every finished run is in the journal ...
    assert not all(sync for what, sync in events if what == "append")  # (grouped) ...
    assert ("fsync", True) in events[appends[-1] + 1 :]  # ... and synced on the way out
    assert len(ResultsStore(tmp_path).records()) == 200
