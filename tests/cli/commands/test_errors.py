"""Expected failures deep inside a run still end as one line (exit status 2)."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from conformal_control.cli import EXIT_BUG, EXIT_ERROR, describe_error, main


def test_predictor_database_error_is_one_line(monkeypatch, tmp_path: Path, capsys) -> None:
    # a predictor whose storage fails mid-run (an unreadable cache the plugin could not
    # set aside) ends the run with one line naming the predictor, the scene and the cause
    from conformal_control.predictors.constant_velocity import ConstantVelocityPredictor

    def broken(self, *a: object, **k: object) -> None:
        raise sqlite3.DatabaseError("file is not a database")

    monkeypatch.setattr(ConstantVelocityPredictor, "predict", broken)
    # the patched class is no longer the one the engine compiles: its predict() is called
    caps = ConstantVelocityPredictor.capabilities.replace(compiled=None)
    monkeypatch.setattr(ConstantVelocityPredictor, "capabilities", caps)
    argv = ["run", "--frames", "20", "--out", str(tmp_path / "r"), "--quiet"]
    assert main(argv) == EXIT_ERROR
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("error: predictor ConstantVelocityPredictor failed on scene crossing")
    assert "a cache database cannot be read (file is not a database)" in err


def test_os_errors_name_the_file() -> None:
    assert describe_error(IsADirectoryError(21, "Is a directory", "/x/y")) == (
        "/x/y: is a folder, expected a file"
    )
    assert describe_error(PermissionError(13, "Permission denied", "/x")) == (
        "/x: permission denied"
    )
    assert "cache database" in describe_error(sqlite3.DatabaseError("file is not a database"))


def test_a_bug_is_reported_as_a_bug(monkeypatch, tmp_path: Path, capsys) -> None:
    import conformal_control.runs.engines.batch as engines  # the engine choice run() calls

    def broken(*a: object, **k: object) -> None:
        raise TypeError("unsupported operand")

    monkeypatch.setattr(engines, "run_single", broken)
    assert main(["run", "--out", str(tmp_path / "r"), "-q"]) == EXIT_BUG
    err = capsys.readouterr().err
    assert err.startswith("error: internal error (TypeError: unsupported operand)")
    assert "Traceback" not in err
    assert main(["-vv", "run", "--out", str(tmp_path / "r"), "-q"]) == EXIT_BUG
    assert "Traceback" in capsys.readouterr().err  # -vv shows it
