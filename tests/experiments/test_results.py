"""The journal and tables of a sweep: torn and undecodable lines, run dirs, atomic tables."""

from __future__ import annotations

import csv
import json
import shutil
import threading
from pathlib import Path

import pytest

from conformal_control.cli import main
from conformal_control.experiments import ResultsStore

SWEEP = [
    "sweep",
    "--scene",
    "crossing",
    "--set",
    "frames=10",
    "--grid",
    "epsilon=-0.1,0,0.1",
    "--executor",
    "serial",
    "--progress",
    "off",
    "--no-summary-plot",
]


def table(out: Path) -> list[dict[str, str]]:
    with (out / "results.csv").open(newline="") as fh:
        return list(csv.DictReader(fh))


def rec(key: str, **kw) -> dict:
    return {"key": key, "status": "failed", "run_dir": None, "config": {}, **kw}


# ------------------------------------------------------------------ journal (store level)
def test_torn_tail_does_not_swallow_the_next_record(tmp_path: Path) -> None:
    store = ResultsStore(tmp_path)
    store.append(rec("a"))
    store.append(rec("b"))
    data = store.journal.read_bytes()
    store.journal.write_bytes(data[:-10])  # b's line torn, no newline at the end
    with pytest.warns(UserWarning, match=r"line 2 \(torn or not JSON\)"):
        assert [r["key"] for r in store.records()] == ["a"]
    torn = store.journal.read_bytes()
    store.append(rec("c"))
    assert store.journal.read_bytes().startswith(torn)  # the fragment is kept, not rewritten
    assert [r["key"] for r in store.records()] == ["a", "c"]
    assert store.bad_lines_ == [(2, "torn or not JSON")]


def test_undecodable_and_foreign_lines_are_counted_once(tmp_path: Path) -> None:
    store = ResultsStore(tmp_path)
    store.append(rec("a"))
    with store.journal.open("ab") as fh:
        fh.write(b'{"key": "\xff\xfe"}\n[1, 2]\n\n')
    store.append(rec("b"))
    with pytest.warns(UserWarning) as caught:
        keys = [r["key"] for r in store.records()]
        store.records()  # the same lines are not warned about twice
    assert keys == ["a", "b"]
    assert len(caught) == 1
    msg = str(caught[0].message)
    assert "skipped 2 unreadable lines" in msg
    assert "2 (not UTF-8)" in msg and "3 (not a run record: a JSON list" in msg


# ------------------------------------------------------------------ journal (CLI)
def test_cli_resume_after_a_torn_journal_line(tmp_path: Path, capsys) -> None:
    out = tmp_path / "sw"
    assert main([*SWEEP, "--out", str(out)]) == 0
    journal = out / "results.jsonl"
    data = journal.read_bytes()
    journal.write_bytes(data[:-100])  # `truncate -s -100 results.jsonl`
    torn = journal.read_bytes()
    capsys.readouterr()
    assert main([*SWEEP, "--out", str(out)]) == 0
    cap = capsys.readouterr()
    # the torn line's run had finished (its run directory is complete): journaled from it
    assert "2 already done, 1 recovered from their run directories, 0 ran" in cap.out
    assert "warning:" in cap.err and "line 3 (torn or not JSON)" in cap.err
    assert json.loads(journal.read_bytes()[len(torn) :].splitlines()[-1])["recovered"] is True
    assert len(table(out)) == 3 and {r["status"] for r in table(out)} == {"ok"}
    assert journal.read_bytes().startswith(torn)  # nothing rewritten, only appended
    # the re-run record was not glued to the fragment: nothing left to do
    assert main([*SWEEP, "--out", str(out)]) == 0
    assert "3 already done, 0 ran" in capsys.readouterr().out
    assert len(table(out)) == 3


def test_cli_resume_with_a_non_utf8_journal_line(tmp_path: Path, capsys) -> None:
    out = tmp_path / "sw"
    assert main([*SWEEP, "--out", str(out)]) == 0
    journal = out / "results.jsonl"
    lines = journal.read_bytes().splitlines(keepends=True)
    journal.write_bytes(lines[0] + b"\xff\xfe\xfd garbage\n" + b"".join(lines[1:]))
    capsys.readouterr()
    assert main([*SWEEP, "--out", str(out)]) == 0
    cap = capsys.readouterr()
    assert "3 already done, 0 ran" in cap.out
    assert "line 2 (not UTF-8)" in cap.err
    assert len(table(out)) == 3


# ------------------------------------------------------------------ run directories
def test_a_copied_sweep_folder_uses_its_own_run_dirs(tmp_path: Path, capsys) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    assert main([*SWEEP, "--out", str(a)]) == 0
    recs = [json.loads(line) for line in (a / "results.jsonl").read_text().splitlines()]
    assert all(r["run_dir"].startswith("runs/") for r in recs)  # stored relative
    assert all(r["run_dir"].startswith("runs/") for r in table(a))
    # a journal of an earlier version held absolute paths into the original folder
    old = "".join(
        json.dumps(dict(r, run_dir=str((a / r["run_dir"]).resolve()))) + "\n" for r in recs
    )
    (a / "results.jsonl").write_text(old)
    shutil.copytree(a, b)
    victim = b / recs[0]["run_dir"]
    shutil.rmtree(victim)  # the copy lost one run; the original still has it
    capsys.readouterr()
    assert main([*SWEEP, "--out", str(b)]) == 0
    assert "2 already done, 1 ran" in capsys.readouterr().out
    assert (victim / "metrics.json").exists()
    assert all(not r["run_dir"].startswith("/") for r in table(b))
    shutil.rmtree(a)  # the copy does not need the original
    assert main([*SWEEP, "--out", str(b)]) == 0
    assert "3 already done, 0 ran" in capsys.readouterr().out
    store = ResultsStore(b)
    for row in store.rows(absolute=True):
        assert Path(row["run_dir"]).is_relative_to(b.resolve())


def test_run_path_resolution(tmp_path: Path) -> None:
    store = ResultsStore(tmp_path / "sw")
    inside = store.out_dir / "runs" / "x-1"
    inside.mkdir(parents=True)
    assert store.run_path("runs/x-1") == store.out_dir / "runs" / "x-1"
    assert store.run_path(str(inside.resolve())) == inside.resolve()  # exists, inside
    elsewhere = tmp_path / "other" / "runs" / "x-1"
    elsewhere.mkdir(parents=True)
    assert store.run_path(str(elsewhere)) == store.out_dir / "runs" / "x-1"  # outside
    assert store.run_path("/gone/runs/y-2") == store.out_dir / "runs" / "y-2"
    assert store.relative_run_dir(str(elsewhere)) == "runs/x-1"
    assert store.run_path(None) is None


def test_appends_keep_the_parsed_journal_current_without_rereading(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A sweep of thousands of runs used to re-parse the whole journal after every run."""
    import numpy as np

    store = ResultsStore(tmp_path)
    store.append(rec("a"))
    assert [r["key"] for r in store.records()] == ["a"]  # read once: now cached
    reads = []
    real = Path.read_bytes
    monkeypatch.setattr(Path, "read_bytes", lambda self: reads.append(self) or real(self))
    for i in range(20):  # JSON types come back: a tuple as a list, numpy as plain numbers
        store.append(rec(f"k{i}", metrics={"x": np.float64(i / 3), "t": (i, "s")}))
    cached = store.records()
    assert reads == []  # no re-read
    monkeypatch.undo()
    fresh = ResultsStore(tmp_path).records()  # a new store reads the file
    assert cached == fresh and json.dumps(cached) == json.dumps(fresh)
    assert cached[-1]["metrics"] == {"x": 19 / 3, "t": [19, "s"]}
    assert store.rows() == ResultsStore(tmp_path).rows()


def test_an_append_by_another_writer_is_seen(tmp_path: Path) -> None:
    store = ResultsStore(tmp_path)
    store.append(rec("a"))
    assert len(store.records()) == 1
    ResultsStore(tmp_path).append(rec("b"))  # the file changed behind this store's back
    store.append(rec("c"))  # its cache no longer matches: dropped, not extended
    assert [r["key"] for r in store.records()] == ["a", "b", "c"]


def test_plain_run_dirs_are_kept_as_recorded(tmp_path: Path) -> None:
    store = ResultsStore(tmp_path / "sw")
    assert store.relative_run_dir("runs/x-1") == "runs/x-1"
    assert store.relative_run_dir("runs/../x-1") == "x-1"  # not plain: resolved
    store.append({**rec("a", status="ok"), "run_dir": "runs/a-1"})
    row = store.rows(absolute=True)[0]
    assert row["run_dir"] == str((tmp_path / "sw").resolve() / "runs" / "a-1")
    assert store.rows()[0]["run_dir"] == "runs/a-1"


# ------------------------------------------------------------------ tables
def test_concurrent_table_writes_use_unique_temp_files(tmp_path: Path) -> None:
    """Two writers rewriting the tables at once never collide on a temporary name."""
    store = ResultsStore(tmp_path)
    for i in range(5):
        store.append(rec(f"k{i}", status="ok", metrics={"l_avg": i / 10}))
    errors: list[BaseException] = []

    def writer() -> None:
        try:
            for _ in range(25):
                ResultsStore(tmp_path).write_tables()
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=writer) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert [r["key"] for r in table(tmp_path)] == [f"k{i}" for i in range(5)]
    assert not [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_stale_temp_files_are_removed(tmp_path: Path) -> None:
    store = ResultsStore(tmp_path)
    stale = [tmp_path / n for n in ("results.csv.tmp", ".results.csv.abc123.tmp")]
    keep = tmp_path / "notes.tmp"
    for p in [*stale, keep]:
        p.write_text("x")
    assert sorted(store.remove_stale_temp_files()) == sorted(stale)
    assert keep.exists()


def test_tables_have_the_permissions_of_any_new_file(tmp_path: Path) -> None:
    """Tables were created 0600 (mkstemp's mode): unreadable by the group that shares them."""
    import os

    old = os.umask(0o022)
    try:
        store = ResultsStore(tmp_path)
        store.append(rec("a", status="ok", metrics={"x": 1.0}))
        written = store.write_tables()
    finally:
        os.umask(old)
    assert written
    for path in written:
        assert path.stat().st_mode & 0o777 == 0o644, path


def test_a_failed_table_write_names_the_file_and_keeps_the_old_table(
    tmp_path: Path, monkeypatch
) -> None:
    import errno

    from conformal_control.core.exceptions import OutputNotWritableError

    store = ResultsStore(tmp_path)
    store.append(rec("a", status="ok", metrics={"x": 1.0}))
    store.write_tables(parquet=False)
    before = store.csv_path.read_bytes()
    store.append(rec("b", status="ok", metrics={"x": 2.0}))

    def full(self: Path, *args: object, **kwargs: object) -> int:
        self.open("wb").write(b"half a ta")  # what a full disk leaves
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_text", full)
    with pytest.raises(OutputNotWritableError, match=r"results\.csv: no space left"):
        store.write_tables(parquet=False)
    monkeypatch.undo()
    assert store.csv_path.read_bytes() == before  # the previous table, never a truncated one
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


WRONG_SCHEMA = [
    b'{"key": "a", "status": 5}\n',
    b'{"key": "b", "status": "ok", "metrics": "fast"}\n',
    b'{"key": "c", "status": "ok", "config": []}\n',
    b'{"key": "d", "status": "ok", "config": {"params": 3}}\n',
    b'{"key": "e", "status": "ok", "run_dir": 7}\n',
    b'{"key": "", "status": "ok"}\n',
    b'"just a string"\n',
]


def test_valid_json_of_the_wrong_schema_is_skipped_like_a_torn_line(tmp_path: Path) -> None:
    """Such a line broke resume, the tables and `bench report` (AttributeError deep inside)."""
    from conformal_control.experiments.bench.suite import read_rows

    store = ResultsStore(tmp_path)
    store.append(rec("good", status="ok", metrics={"x": 1.0}))
    with store.journal.open("ab") as fh:
        fh.writelines(WRONG_SCHEMA)
    with pytest.warns(UserWarning, match=r"skipped 7 unreadable lines: lines 2 \(not a run record"):
        assert [r["key"] for r in store.records()] == ["good"]
    assert [n for n, _ in store.bad_lines_] == list(range(2, 9))
    assert "status 5 is neither" in store.bad_lines_[0][1]
    assert "'metrics' is a str" in store.bad_lines_[1][1]
    assert "'config.params' is a int" in store.bad_lines_[3][1]
    store.write_tables(parquet=False)
    assert [r["key"] for r in table(tmp_path)] == ["good"]
    with pytest.warns(UserWarning, match="skipped 7 unreadable lines"):
        assert [r["key"] for r in read_rows(tmp_path)] == ["good"]  # what `bench report` reads


def test_cli_resume_with_a_wrong_schema_journal_line(tmp_path: Path, capsys) -> None:
    out = tmp_path / "sw"
    assert main([*SWEEP, "--out", str(out)]) == 0
    with (out / "results.jsonl").open("ab") as fh:
        fh.write(b'{"key": "zz", "status": "ok", "config": "not a mapping"}\n')
    capsys.readouterr()
    assert main([*SWEEP, "--out", str(out)]) == 0
    cap = capsys.readouterr()
    assert "3 already done, 0 ran" in cap.out
    assert "line 4 (not a run record: 'config' is a str)" in cap.err


def test_absolute_run_dirs_resolve_links_like_pathlib(tmp_path: Path) -> None:
    """Plain run dirs are resolved by resolving ``runs`` once: a run folder that is a
    symbolic link must still come out resolved, as ``Path.resolve`` gives it."""
    store = ResultsStore(tmp_path / "sw")
    (store.out_dir / "runs").mkdir()
    (tmp_path / "real").mkdir()
    (store.out_dir / "runs" / "l-1").symlink_to(tmp_path / "real")
    (store.out_dir / "runs" / "p-1").mkdir()
    for key in ("l-1", "p-1", "gone-1"):
        store.append({**rec(key, status="ok"), "run_dir": f"runs/{key}"})
    got = [r["run_dir"] for r in store.rows(absolute=True)]
    want = [str((store.out_dir / "runs" / k).resolve()) for k in ("l-1", "p-1", "gone-1")]
    assert got == want and got[0] == str((tmp_path / "real").resolve())
