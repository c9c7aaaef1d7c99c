"""Attacks through ``export``: its destination and the run folder it reads.

``export RUN --out RUN/trajectory.csv`` overwrote the run's own file with MCAP bytes; a
planted ``RUN/run.mcap.partial`` link made export write through it; a device given as
``--out`` was replaced by a regular file; damaged run folders ended in internal errors (and
left ``run.mcap.partial`` behind); a multi-robot run without ``robots/robot_01`` exported
robot_02's data as ``/robot_1``. Each case now ends in one line (or a correct file)."""

from __future__ import annotations

import csv
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from conformal_control.cli import EXIT_ERROR, main


@pytest.fixture(scope="module")
def single(tmp_path_factory) -> Path:
    import conformal_control as cc

    res = cc.run("crossing", seed=0, max_frames=30)
    return Path(res.save(tmp_path_factory.mktemp("single") / "run", plot=False))


@pytest.fixture(scope="module")
def multi(tmp_path_factory) -> Path:
    from conformal_control.data import load_scene
    from conformal_control.runs.fleet import run_multi, write_multi_run_dir

    res = run_multi(load_scene("crossing", seed=0), 3, max_frames=30)
    return write_multi_run_dir(res, tmp_path_factory.mktemp("multi") / "run")


def _copy(src: Path, dest: Path) -> Path:
    shutil.copytree(src, dest)
    return dest


def _leftovers(folder: Path) -> list[str]:
    return [p.name for p in folder.rglob("*") if "partial" in p.name]


# ------------------------------------------------------------------------------ destinations
@pytest.mark.parametrize("name", ["trajectory.csv", "config.json", "intervals.csv"])
def test_export_never_overwrites_the_run_it_reads(
    name: str, single: Path, tmp_path: Path, error_line
) -> None:
    run = _copy(single, tmp_path / "run")
    before = (run / name).read_bytes()
    assert main(["export", str(run), "--out", str(run / name)]) == EXIT_ERROR
    line = error_line()
    assert f"cannot write {run / name}" in line and "never overwrites" in line
    assert (run / name).read_bytes() == before and not _leftovers(run)


@pytest.mark.parametrize(("fmt", "suffix"), [("mcap", ".mcap"), ("rerun", ".rrd")])
def test_a_planted_partial_link_is_never_written_through(
    fmt: str, suffix: str, single: Path, tmp_path: Path, capsys
) -> None:
    run = _copy(single, tmp_path / "run")
    victim = tmp_path / "victim"
    victim.write_text("secret")
    (run / f"run{suffix}.partial").symlink_to(victim)
    assert main(["export", str(run), "--format", fmt]) == 0
    assert victim.read_text() == "secret"
    assert (run / f"run{suffix}").stat().st_size > 1000
    assert "->" in capsys.readouterr().out


def _device_or_fifo(path: Path) -> str:
    """A character device like /dev/full where allowed (root), else a FIFO: either is a
    node that must never be replaced by a regular file."""
    import stat

    try:
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 7))
        return "a character device"
    except PermissionError:
        os.mkfifo(path)
        return "a FIFO"


@pytest.mark.parametrize("kind", ["device", "link", "folder"])
def test_a_destination_that_is_no_regular_file_is_refused(
    kind: str, single: Path, tmp_path: Path, error_line
) -> None:
    import stat

    out = tmp_path / "out"
    if kind == "device":
        words = _device_or_fifo(out)
    elif kind == "link":
        (tmp_path / "target").write_text("keep")
        out.symlink_to(tmp_path / "target")
        words = "symbolic link"
    else:
        out.mkdir()
        words = "a folder"
    mode = os.lstat(out).st_mode
    assert main(["export", str(single), "--out", str(out)]) == EXIT_ERROR
    assert words in error_line()
    assert stat.S_IFMT(os.lstat(out).st_mode) == stat.S_IFMT(mode)  # still what it was
    assert not [p for p in tmp_path.iterdir() if "partial" in p.name]
    if kind == "link":
        assert (tmp_path / "target").read_text() == "keep"


# ------------------------------------------------------------------------------ damaged folders
def _edit_cell(run: Path, column: str, value: str, file: str = "trajectory.csv") -> None:
    path = run / file
    rows = list(csv.reader(path.open(newline="")))
    rows[3][rows[0].index(column)] = value
    with path.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)


def _header_only(run: Path) -> None:
    path = run / "trajectory.csv"
    path.write_text(path.read_text().splitlines()[0] + "\n")


def _missing_column(run: Path) -> None:
    path = run / "trajectory.csv"
    rows = [r[:3] for r in csv.reader(path.open(newline=""))]
    with path.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)


def _bad_npz(run: Path) -> None:
    with np.load(run / "animation.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays["pred_cols"] = arrays["pred_cols"][:, :1]
    np.savez(run / "animation.npz", **arrays)


DAMAGED: list[tuple[str, Callable[[Path], None], list[str]]] = [
    ("header only", _header_only, ["trajectory.csv", "no frame"]),
    ("missing column", _missing_column, ["trajectory.csv", "no column y"]),
    (
        "a list as config.json",
        lambda r: (r / "config.json").write_text("[1, 2]"),
        ["config.json", "a JSON list"],
    ),
    ("negative time", lambda r: _edit_cell(r, "t", "-5"), ["time -5.0 s", "not in [0"]),
    ("time 1e300", lambda r: _edit_cell(r, "t", "1e300"), ["time 1e+300 s"]),
    ("nan time", lambda r: _edit_cell(r, "t", "nan"), ["time nan s"]),
    ("frame 2**63", lambda r: _edit_cell(r, "frame", str(2**63)), ["out of the range"]),
    (
        "interval time 1e300",
        lambda r: _edit_cell(r, "t", "1e300", "intervals.csv"),
        ["intervals.csv", "time 1e+300 s"],
    ),
    ("text for a number", lambda r: _edit_cell(r, "x", "root:x:0:0"), ["line 4, column x"]),
    (
        "corrupt animation.npz",
        lambda r: (r / "animation.npz").write_bytes(b"PK\x03\x04 not a zip"),
        ["animation.npz", "not a readable .npz"],
    ),
    ("animation arrays disagree", _bad_npz, ["animation.npz", "pred_cols has shape"]),
]


@pytest.mark.parametrize(("damage", "words"), [c[1:] for c in DAMAGED], ids=[c[0] for c in DAMAGED])
@pytest.mark.parametrize("fmt", ["mcap", "rerun"])
def test_a_damaged_run_folder_is_one_line(
    fmt: str,
    damage: Callable[[Path], None],
    words: list[str],
    single: Path,
    tmp_path: Path,
    error_line,
) -> None:
    run = _copy(single, tmp_path / "run")
    damage(run)
    assert main(["export", str(run), "--format", fmt]) == EXIT_ERROR
    line = error_line()
    for w in words:
        assert w in line, f"{w!r} not in {line!r}"
    assert "root:x" not in line  # a cell of a file that is not a run's is never echoed
    assert not _leftovers(run)


def test_a_fifo_in_the_run_folder_is_refused_not_read(
    single: Path, tmp_path: Path, error_line
) -> None:
    run = _copy(single, tmp_path / "run")
    (run / "trajectory.csv").unlink()
    os.mkfifo(run / "trajectory.csv")  # reading it would wait forever
    assert main(["export", str(run)]) == EXIT_ERROR
    assert "trajectory.csv is not a regular file" in error_line()


def test_a_multi_robot_run_missing_a_robot_is_refused(
    multi: Path, tmp_path: Path, error_line
) -> None:
    run = _copy(multi, tmp_path / "run")
    shutil.rmtree(run / "robots" / "robot_01")
    assert main(["export", str(run)]) == EXIT_ERROR
    assert "has no robot_01 of the run's 3 robots" in error_line()
    run2 = _copy(multi, tmp_path / "run2")
    shutil.copytree(run2 / "robots" / "robot_02", run2 / "robots" / "robot_03")
    assert main(["export", str(run2)]) == EXIT_ERROR
    assert "holds robot_03, but config.json says the run had 3 robots" in error_line()


def test_a_multi_robot_export_keeps_each_robot_s_own_data(multi: Path, tmp_path: Path) -> None:
    from conformal_control.io.export import read_run

    rec = read_run(multi)
    assert [r.name for r in rec.robots] == ["robot_0", "robot_1", "robot_2"]
    assert rec.robots_xy is not None
    for i, r in enumerate(rec.robots):
        own = list(csv.DictReader((multi / "robots" / f"robot_{i:02d}" / "trajectory.csv").open()))
        assert r.trajectory["x"][0] == float(own[0]["x"])
        assert json.loads((multi / "config.json").read_text())["robots"][i]["robot"] == i
