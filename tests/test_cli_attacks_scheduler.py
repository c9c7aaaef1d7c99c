"""Scheduler loss: an infrastructure failure is never a method failure.

A Dask scheduler killed 12 s into a ``bench run`` turned into "540 ran (68 failed)", a
multi-line traceback despite ``-q``, and a ``bench report`` that ranked ``acp`` on n = 4 at
100 % success without a word. The lost episodes are now left unfinished (not journaled,
run by the next ``bench run``), the summary says so in one line, and a report over the
folder says so on its first line. The executor here loses its jobs the way a cluster
does (the exception ``distributed`` raises for a lost scheduler), deterministically."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from conformal_control.cli import main
from conformal_control.experiments.executors.serial import SerialExecutor


class LostScheduler(SerialExecutor):
    """A 'cluster' that runs its first ``keep`` jobs and then loses the scheduler: every
    later job comes back as the connection error, as from ``distributed``."""

    distributed = True
    n_workers = 2

    def __init__(self, keep: int) -> None:
        self.keep = keep

    def run(self, fn, tasks):  # type: ignore[no-untyped-def]
        for i, args in enumerate(tasks):
            if i < self.keep:
                yield i, fn(*args)
            else:
                yield i, ConnectionError("Client lost the connection to the scheduler")


@pytest.fixture(autouse=True)
def _data(data_root: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The commands find the real data where the tests do (CI sets no variable: the data
    is ``../shared/data`` beside the project, which a command run elsewhere does not see)."""
    monkeypatch.setenv("CONFORMAL_CONTROL_DATA", str(data_root))


@pytest.fixture
def lost_after(monkeypatch):
    """``bench run --scheduler ...`` on a cluster that loses its scheduler after N jobs."""
    import conformal_control.experiments.runner as runner

    def install(keep: int) -> None:
        monkeypatch.setattr(runner, "make_executor", lambda *a, **k: LostScheduler(keep))

    return install


ARGV = ["bench", "run", "--split", "test", "--limit", "6", "--methods", "nolearn,acp"]


def test_a_lost_scheduler_leaves_episodes_unfinished_not_failed(
    tmp_path: Path, lost_after, capsys
) -> None:
    out = tmp_path / "b"
    lost_after(1)  # the first job (a chunk of batched runs) comes back, the rest is lost
    code = main(["-q", *ARGV, "--scheduler", "tcp://cluster:8786", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 1
    assert captured.err == ""  # -q: no traceback, no log line
    summary = captured.out.strip().splitlines()[-1]
    assert "(0 failed)" in summary and "left unfinished, not failed" in summary
    assert "ConnectionError: Client lost the connection to the scheduler" in summary
    journal = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
    assert journal and all(r["status"] == "ok" for r in journal)  # nothing lost is journaled
    planned = len(json.loads((out / "sweep.json").read_text())["runs"])
    assert len(journal) < planned

    # a report before resuming says so on its first line, in every page
    assert main(["bench", "report", str(out)]) == 0
    printed = capsys.readouterr().out
    first = printed.splitlines()[0]
    assert first.startswith(f"**INCOMPLETE: {planned - len(journal)} of the {planned} episodes")
    for page in ("leaderboard.md", "targets.md"):
        assert (out / "report" / page).read_text().startswith("**INCOMPLETE")

    # the next bench run finishes them; the report is then whole
    lost_after(10**6)
    assert main([*ARGV, "--scheduler", "tcp://cluster:8786", "--out", str(out)]) == 0
    assert f"{len(journal)} already done" in capsys.readouterr().out
    assert main(["bench", "report", str(out)]) == 0
    assert capsys.readouterr().out.startswith("# Benchmark")


def test_a_tune_with_unfinished_episodes_writes_no_tuned_file(
    tmp_path: Path, lost_after, error_line
) -> None:
    lost_after(0)
    argv = ["bench", "tune", "--limit", "2", "--methods", "acp", "--executor", "dask"]
    assert main([*argv, "--out", str(tmp_path / "t")]) == 2
    assert "tuning episodes were left unfinished" in error_line()
    assert not (tmp_path / "t" / "tuned.json").exists()


def test_a_refused_scheduler_port_is_one_line_at_once(tmp_path: Path, error_line) -> None:
    """distributed retried for 91 s while its message said 30 s."""
    argv = [*ARGV, "--scheduler", "tcp://127.0.0.1:9", "--out", str(tmp_path / "b")]
    assert main(argv) == 2
    line = error_line()
    assert "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in line
    assert "refused" in line.lower()


@pytest.mark.parametrize("command", ["bench", "sweep"])
def test_an_empty_scheduler_is_refused_not_a_local_cluster(
    command: str, tmp_path: Path, error_line
) -> None:
    if command == "bench":
        argv = [*ARGV, "--scheduler", "", "--out", str(tmp_path / "b")]
    else:
        argv = ["sweep", "--executor", "dask", "--scheduler", "", "--scene", "crossing"]
        argv += ["--grid", "seed=0", "--out", str(tmp_path / "s")]
    assert main(argv) != 0
    assert "--scheduler is empty" in error_line()


def test_quiet_mutes_the_cluster_s_logs() -> None:
    from conformal_control.core import progress
    from conformal_control.experiments.executors.dask import _distributed

    try:
        progress.set_quiet(True)
        _distributed()
        for name in ("distributed", "distributed.client"):
            assert logging.getLogger(name).getEffectiveLevel() > logging.CRITICAL
    finally:
        progress.set_quiet(None)
        for name in ("distributed", "distributed.client"):
            logging.getLogger(name).setLevel(logging.WARNING)
