"""The one writer of every exporter: never an input, never through a link, never a device."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from conformal_control.core.exceptions import OutputNotWritableError
from conformal_control.io.export.destination import (
    check_destination,
    safe_output,
    safe_output_path,
)


@pytest.fixture
def run(tmp_path: Path) -> Path:
    d = tmp_path / "run"
    d.mkdir()
    (d / "trajectory.csv").write_text("frame,t\n")
    (d / "config.json").write_text("{}")
    (d / "run.mcap").write_bytes(b"old export")
    return d


def _write(out: Path, **kw) -> None:
    with safe_output(out, **kw) as fh:
        fh.write(b"new")


@pytest.mark.parametrize("name", ["trajectory.csv", "config.json"])
def test_a_file_of_an_input_folder_is_never_overwritten(run: Path, name: str) -> None:
    before = (run / name).read_bytes()
    with pytest.raises(OutputNotWritableError, match="a file of the input folder"):
        _write(run / name, inputs=[run], suffix=".mcap")
    assert (run / name).read_bytes() == before
    assert not [p for p in run.iterdir() if p.name.endswith(".partial")]


def test_an_earlier_output_and_a_new_name_may_be_written(run: Path) -> None:
    _write(run / "run.mcap", inputs=[run], suffix=".mcap")
    assert (run / "run.mcap").read_bytes() == b"new"
    _write(run / "other.csv", inputs=[run], suffix=".mcap")  # new: not an input
    assert (run / "other.csv").read_bytes() == b"new"


def test_an_input_reached_another_way_is_refused(run: Path, tmp_path: Path) -> None:
    (tmp_path / "alias").symlink_to(run)  # the run folder through a linked folder
    with pytest.raises(OutputNotWritableError, match="a file of the input folder"):
        _write(tmp_path / "alias" / "config.json", inputs=[run], suffix=".mcap")
    os.link(run / "trajectory.csv", tmp_path / "hard.csv")  # the same file, hard-linked
    with pytest.raises(OutputNotWritableError, match="one of the inputs"):
        _write(tmp_path / "hard.csv", inputs=[run / "trajectory.csv"])
    with pytest.raises(OutputNotWritableError, match="one of the inputs"):
        _write(run / "trajectory.csv", inputs=[run / "trajectory.csv"])


def test_a_link_is_never_followed(run: Path, tmp_path: Path) -> None:
    victim = tmp_path / "victim"
    victim.write_text("secret")
    (tmp_path / "out.mcap").symlink_to(victim)
    with pytest.raises(OutputNotWritableError, match="symbolic link"):
        _write(tmp_path / "out.mcap", inputs=[run], suffix=".mcap")
    assert victim.read_text() == "secret"
    # a planted temporary name is never used: the temporary file has a random name
    (tmp_path / "x.mcap.partial").symlink_to(victim)
    (tmp_path / ".x.mcap.partial").symlink_to(victim)
    _write(tmp_path / "x.mcap", inputs=[run], suffix=".mcap")
    assert victim.read_text() == "secret" and (tmp_path / "x.mcap").read_bytes() == b"new"


def test_a_fifo_or_a_folder_is_refused(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "fifo")
    with pytest.raises(OutputNotWritableError, match="a FIFO"):
        _write(tmp_path / "fifo")
    (tmp_path / "folder").mkdir()
    with pytest.raises(OutputNotWritableError, match=r"a folder \(give a file name"):
        _write(tmp_path / "folder", suffix=".mcap")
    assert not list(tmp_path.glob("*.partial")) and not list(tmp_path.glob(".*.partial"))


def test_an_error_while_writing_leaves_nothing(tmp_path: Path) -> None:
    out = tmp_path / "x.mcap"
    out.write_bytes(b"before")
    with pytest.raises(RuntimeError), safe_output(out) as fh:
        fh.write(b"half")
        raise RuntimeError("exporter failed")
    assert out.read_bytes() == b"before"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.mcap"]


def test_a_path_for_a_library_is_private_and_copied(tmp_path: Path) -> None:
    out = tmp_path / "x.rrd"
    with safe_output_path(out) as staged:
        assert staged.parent != tmp_path
        assert staged.parent.stat().st_mode & 0o777 == 0o700
        staged.write_bytes(b"recording")
    assert out.read_bytes() == b"recording" and not staged.exists()
    assert check_destination(out) == out
