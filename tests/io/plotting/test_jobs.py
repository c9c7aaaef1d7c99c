"""Figures drawn on two cores: same files as drawn one after the other, errors surface."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from conformal_control.io.plotting import jobs
from conformal_control.io.plotting.jobs import can_fork, draw_all

PARENT = os.getpid()


def _figure(path: Path, seed: int) -> None:
    from conformal_control.io.plotting.run import pyplot

    plt = pyplot()
    rng = np.random.default_rng(seed)
    fig, ax = plt.subplots(figsize=(3, 2))
    ax.plot(rng.normal(size=50).cumsum())
    ax.set_title(f"seed {seed}, pid-independent")
    fig.savefig(path, dpi=60)
    plt.close(fig)
    (path.parent / f"{path.stem}.pid").write_text(str(os.getpid()))


def _raise(path: Path) -> None:
    raise ValueError(f"cannot draw {path.name}")


def _die_in_child(path: Path) -> None:
    if os.getpid() != PARENT:
        os._exit(3)  # the figure process dies without a word
    _figure(path, 7)


@pytest.fixture
def forkable(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fork even if an earlier test left a thread running (the test suite's process is
    not the command's, which checks for a single thread)."""
    monkeypatch.setattr(jobs, "can_fork", lambda: True)


def _jobs(folder: Path, n: int = 4) -> list[jobs.FigureJob]:
    folder.mkdir()
    return [(_figure, (folder / f"f{i}.png", i), {}) for i in range(n)]


def test_forked_drawing_writes_the_same_files_as_serial(tmp_path: Path, forkable: None) -> None:
    assert draw_all(_jobs(tmp_path / "serial"), workers=1) == "serial"
    assert draw_all(_jobs(tmp_path / "forked")) == "forked"
    for i in range(4):
        a = (tmp_path / "serial" / f"f{i}.png").read_bytes()
        b = (tmp_path / "forked" / f"f{i}.png").read_bytes()
        assert a == b
    pids = {int((tmp_path / "forked" / f"f{i}.pid").read_text()) for i in range(4)}
    assert len(pids) == 2 and os.getpid() in pids  # half here, half in the child
    assert jobs._JOBS == ()  # nothing held after the call


def test_an_error_in_the_child_is_raised_here(tmp_path: Path, forkable: None) -> None:
    todo = _jobs(tmp_path / "f", 1)
    todo.append((_raise, (tmp_path / "bad.png",), {}))  # odd position: the child's
    with pytest.raises(ValueError, match=r"cannot draw bad\.png"):
        draw_all(todo)
    assert (tmp_path / "f" / "f0.png").is_file()  # this process's share was drawn


def test_a_dead_child_is_reported_and_its_figures_drawn_here(
    tmp_path: Path, forkable: None
) -> None:
    todo = _jobs(tmp_path / "f", 1)
    todo.append((_die_in_child, (tmp_path / "f" / "late.png",), {}))
    with pytest.warns(RuntimeWarning, match="figure process died.*drawing its 1 figures here"):
        assert draw_all(todo) == "forked"
    assert int((tmp_path / "f" / "late.pid").read_text()) == os.getpid()


def test_serial_when_a_second_thread_runs(tmp_path: Path) -> None:
    import threading

    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        assert not can_fork()
        assert draw_all(_jobs(tmp_path / "f", 2)) == "serial"
    finally:
        stop.set()
        t.join()
    pids = {int((tmp_path / "f" / f"f{i}.pid").read_text()) for i in range(2)}
    assert pids == {os.getpid()}


@pytest.mark.parametrize("workers", [0, -1, True])
def test_bad_workers(workers: object) -> None:
    with pytest.raises(ValueError, match="workers must be a positive integer"):
        draw_all([], workers=workers)  # type: ignore[arg-type]


STOPPED_CHILD = """
import os, signal, sys, warnings
from pathlib import Path
from conformal_control.io.plotting.jobs import can_fork, draw_all

parent = os.getpid()

def job(path):
    if os.getpid() != parent:  # the forked figure process stops itself (kill -STOP)
        os.kill(os.getpid(), signal.SIGSTOP)
    Path(path).write_text("drawn")

assert can_fork(), "this test needs Linux and two CPUs"
out = Path(sys.argv[1])
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    how = draw_all([(job, (out / "a",), {}), (job, (out / "b",), {})])
print(how, sorted(p.name for p in out.iterdir()), [str(w.message) for w in caught])
"""


def test_a_stopped_figure_process_does_not_hang_the_run(tmp_path: Path) -> None:
    """A stopped child used to be waited for forever."""
    import subprocess
    import sys

    res = subprocess.run(
        [sys.executable, "-c", STOPPED_CHILD, str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("forked ['a', 'b']"), res.stdout
    assert "was stopped" in res.stdout and "drawing its 1 figures here" in res.stdout


# ------------------------------------------------------------- the prepared figure process
def _unpicklable_jobs(folder: Path) -> list[jobs.FigureJob]:
    folder.mkdir()
    return [(lambda p: _figure(p, 0), (folder / "f0.png",), {})]


def test_prepared_process_draws_the_same_files(tmp_path: Path, forkable: None) -> None:
    assert draw_all(_jobs(tmp_path / "serial", 2), workers=1) == "serial"
    assert jobs.prepare()
    child = jobs._PREPARED.pid  # type: ignore[union-attr]
    assert draw_all(_jobs(tmp_path / "prepared", 2)) == "forked"
    for i in range(2):
        a = (tmp_path / "serial" / f"f{i}.png").read_bytes()
        assert (tmp_path / "prepared" / f"f{i}.png").read_bytes() == a
    pids = {int((tmp_path / "prepared" / f"f{i}.pid").read_text()) for i in range(2)}
    assert os.getpid() not in pids and child in pids  # drawn by the prepared process
    assert jobs._PREPARED is None  # used once
    with pytest.raises(ChildProcessError):
        os.waitpid(child, os.WNOHANG)  # and reaped


def test_prepared_process_raises_a_drawing_error_here(tmp_path: Path, forkable: None) -> None:
    assert jobs.prepare()
    with pytest.raises(ValueError, match=r"cannot draw bad\.png"):
        draw_all([(_raise, (tmp_path / "bad.png",), {})])


def test_prepared_process_unpicklable_jobs_are_drawn_here(tmp_path: Path, forkable: None) -> None:
    assert jobs.prepare()
    child = jobs._PREPARED.pid  # type: ignore[union-attr]
    draw_all(_unpicklable_jobs(tmp_path / "f"), workers=1)
    assert int((tmp_path / "f" / "f0.pid").read_text()) == os.getpid()
    with pytest.raises(ChildProcessError):
        os.waitpid(child, os.WNOHANG)  # released and reaped


def test_a_dead_prepared_process_is_reported_and_its_figures_drawn_here(
    tmp_path: Path, forkable: None
) -> None:
    import signal

    assert jobs.prepare()
    os.kill(jobs._PREPARED.pid, signal.SIGKILL)  # type: ignore[union-attr]
    with pytest.warns(RuntimeWarning, match="figure process died"):
        draw_all(_jobs(tmp_path / "f", 2))
    pids = {int((tmp_path / "f" / f"f{i}.pid").read_text()) for i in range(2)}
    assert os.getpid() in pids


def test_an_unused_prepared_process_is_released(forkable: None) -> None:
    assert jobs.prepare()
    child = jobs._PREPARED.pid  # type: ignore[union-attr]
    jobs.release()  # what happens at exit when nothing was drawn
    assert jobs._PREPARED is None
    with pytest.raises(ChildProcessError):
        os.waitpid(child, os.WNOHANG)


def test_no_prepared_process_where_forking_is_unsafe(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(jobs, "can_fork", lambda: False)
    assert not jobs.prepare()
    assert jobs._PREPARED is None


def test_a_prepared_process_in_another_folder_is_not_used(
    tmp_path: Path, forkable: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Jobs name files relative to this process's folder: a figure process forked in
    another folder would write them elsewhere."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    monkeypatch.chdir(tmp_path / "a")
    assert jobs.prepare()
    child = jobs._PREPARED.pid  # type: ignore[union-attr]
    monkeypatch.chdir(tmp_path / "b")
    draw_all([(_figure, (Path("rel.png"), 1), {})])
    assert (tmp_path / "b" / "rel.png").is_file() and not (tmp_path / "a" / "rel.png").exists()
    with pytest.raises(ChildProcessError):
        os.waitpid(child, os.WNOHANG)
