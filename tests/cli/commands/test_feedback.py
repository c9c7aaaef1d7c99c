"""What the CLI tells the user: progress, warnings, units, replay, help."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import conformal_control.core.progress as progress_mod
from conformal_control.cli import main
from conformal_control.core.exceptions import (
    ConformalControlWarning,
    FeasibilityWarning,
    GoalNotReachedWarning,
    NoUpdatesWarning,
    SuspiciousValueWarning,
)
from conformal_control.runs.episode import run_episode
from conformal_control.runs.params import resolve_params


def warning_lines(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if ln.startswith("warning: ")]


@pytest.fixture
def instant_progress(monkeypatch: pytest.MonkeyPatch) -> None:
    """Progress reports show at once and on every update, as plain lines."""
    monkeypatch.setattr(progress_mod, "DELAY", 0.0)
    monkeypatch.setattr(progress_mod, "EVERY", 0.0)
    monkeypatch.setenv("CONFORMAL_CONTROL_PROGRESS", "lines")


# ------------------------------------------------------------------------------ progress
def test_run_reports_progress_in_frames(instant_progress, tmp_path: Path, capsys) -> None:
    assert main(["run", "--out", str(tmp_path / "r"), "--no-plot"]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("run crossing [constant_velocity]")]
    assert len(lines) >= 10, err
    assert "/599 frames" in lines[0] and "l_avg" in lines[1]
    assert lines[-1].startswith("run crossing [constant_velocity]: done, 14")  # 149 frames


def test_quiet_silences_progress_not_warnings(
    instant_progress, tmp_path: Path, capsys, sdd_dir: Path
) -> None:
    argv = ["run", "--scene", "nexus_4", "--data-root", str(sdd_dir), "--param", "rho0=18"]
    assert main(["--quiet", *argv, "--frames", "40", "--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err
    assert "frames" not in err.replace("40 frames", "")  # no progress line
    assert len(warning_lines(err)) == 2  # suspicious rho0, no update
    assert main([*argv, "-q", "--frames", "40", "--out", str(tmp_path / "r2")]) == 0
    assert "nexus_4 [constant_velocity]" not in capsys.readouterr().err  # after the command too


def test_training_and_evaluation_report_progress(
    instant_progress, tmp_path: Path, capsys, ethucy_dir: Path, monkeypatch
) -> None:
    monkeypatch.setenv("CONFORMAL_CONTROL_CACHE", str(tmp_path / "cache"))
    argv = ["train-predictor", "lstm", "--dataset", "ethucy:zara1", "--data-root", str(ethucy_dir)]
    tiny = ["--param", "epochs=2", "--param", "hidden=4", "--param", "batch_size=8192"]
    assert main([*argv, *tiny, "--out", str(tmp_path / "w")]) == 0
    err = capsys.readouterr().err
    assert "training lstm on" in err and "windows of ethucy:zara1/train" in err
    assert "/2 epochs" in err and "loss" in err
    argv = ["eval-predictor", "--predictor", "constant_velocity", "--dataset", "ethucy:zara1"]
    assert main([*argv, "--data-root", str(ethucy_dir), "--max-windows", "600"]) == 0
    err = capsys.readouterr().err
    assert "eval constant_velocity on ethucy:zara1: 256/600 windows" in err


def test_chunked_evaluation_equals_one_call(ethucy_dir: Path) -> None:
    from conformal_control.core import registry
    from conformal_control.predictors.evaluation import dataset_windows, evaluate_predictor
    from conformal_control.predictors.training import (
        evaluate_with_progress as _evaluate_with_progress,
    )

    win = dataset_windows("ethucy:zara1", ethucy_dir.parent)
    cv = registry.create("predictor", "constant_velocity", window=1)
    whole = evaluate_predictor(cv, win)
    chunked = _evaluate_with_progress(cv, win, "eval", chunk=100)
    assert chunked["n"] == whole["n"] > 100
    assert chunked["ade"] == pytest.approx(whole["ade"], rel=1e-12)
    assert chunked["fde"] == pytest.approx(whole["fde"], rel=1e-12)


def test_progress_lines_and_quiet(monkeypatch, capsys) -> None:
    monkeypatch.setenv("CONFORMAL_CONTROL_PROGRESS", "lines")
    with progress_mod.progress(4, "work", "steps", delay=0.0, every=0.0) as bar:
        for _ in range(4):
            bar.update()
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("work: 1/4 steps (25%)") and err[-1].startswith("work: done, 4")
    progress_mod.set_quiet(True)
    try:
        with progress_mod.progress(4, "work", "steps", delay=0.0, every=0.0) as bar:
            bar.update(4)
        progress_mod.note("a note")
    finally:
        progress_mod.set_quiet(None)
    assert capsys.readouterr().err == ""


# ------------------------------------------------------------------------------ warnings
def test_warnings_are_one_line_each(tmp_path: Path, capsys, sdd_dir: Path) -> None:
    argv = ["run", "--scene", "nexus_4", "--data-root", str(sdd_dir), "--param", "rho0=18"]
    assert main([*argv, "--frames", "60", "--out", str(tmp_path / "r"), "-q"]) == 0
    err = capsys.readouterr().err
    lines = warning_lines(err)
    assert len(lines) == 2 and len(err.splitlines()) == 2, err
    assert "rho0=18 is read in the scene's unit: 18 px = 0.826 m" in lines[0]
    assert "rho0=18m" in lines[0]  # the suffix is suggested
    assert "lambda was never updated" in lines[1]
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert m["n_updates"] == 0  # what the warning says


def test_unattainable_epsilon_is_warned_before_the_run(nexus4) -> None:
    seen: list[int] = []
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")

        def first(log) -> None:
            if not seen:
                seen.append(sum(issubclass(w.category, FeasibilityWarning) for w in rec))

        res = run_episode(nexus4, params={"a": 1}, max_frames=30, on_interval=first)
    assert seen == [1]  # already warned when the first interval ended
    assert res.metrics["epsilon_attainable"] is False
    text = str(next(w.message for w in rec if w.category is FeasibilityWarning))
    assert "epsilon=-0.25 is not attainable" in text and "lambda_floor=-0.5 1/frame" in text


def test_goal_not_reached_says_why(sdd_dir: Path) -> None:
    from conformal_control.data import load_scene

    late = load_scene("nexus_4", sdd_dir, start_frame=950)
    last = late.first_frame + late.n_frames - 1
    with pytest.warns(GoalNotReachedWarning, match=f"data ended at frame {last}") as rec:
        res = run_episode(late, max_frames=None)
    assert rec[0].message.reason == "data_ended" and not res.metrics["goal_reached"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", GoalNotReachedWarning)  # a frame limit is not warned
        run_episode(late, max_frames=30)
        # nor a limit that ends where the data ends (a benchmark scenario's time limit)
        res = run_episode(late, max_frames=last - late.start_frame)
    assert not res.metrics["goal_reached"]


@pytest.mark.parametrize(
    ("argv", "warned", "given"),
    [
        (["--eta", "1", "--param", "eta=2"], "--eta 1 and --param eta=2 disagree", {"eta": 1}),
        (["--param", "eta=1", "--param", "eta=2"], "using the last, eta=2", {"eta": 2}),
        (["--no-learning", "--eta", "3"], "--eta", {"eta": 3}),
        (["--lambda-safe", "-1", "--rule", "pid"], "rule pid has no Theorem-2 bound", {}),
        (["--data-root", "/nowhere"], "--data-root is ignored", {}),
    ],
    ids=["flag vs param", "param twice", "no-learning eta", "lambda-safe pid", "data-root"],
)
def test_conflicting_and_ignored_options_are_warned(
    argv: list[str], warned: str, given: dict, tmp_path: Path, capsys
) -> None:
    assert main(["run", *argv, "--frames", "20", "--out", str(tmp_path / "r"), "-q"]) == 0
    lines = warning_lines(capsys.readouterr().err)
    assert len(lines) == 1 and warned in lines[0], lines
    cfg = json.loads((tmp_path / "r" / "config.json").read_text())
    for k, v in given.items():
        assert cfg["params"]["given"][k] == v


def test_project_warnings_share_one_base_class() -> None:
    for cls in (FeasibilityWarning, NoUpdatesWarning, SuspiciousValueWarning):
        assert issubclass(cls, ConformalControlWarning) and issubclass(cls, UserWarning)


# ------------------------------------------------------------------------------ units
@pytest.mark.parametrize(
    ("name", "value", "si"),
    [
        ("rho0", "18m", 18.0),
        ("rho0", "400px", 400 * 0.045883871),
        ("rho0", "1800cm", 18.0),
        ("tau", "0.4s", 0.4),
        ("tau", "12frames", 0.4),
        ("eta", "30/s", 30.0),
        ("eta", "1/frame", 30.0),
        ("eta", "30Hz", 30.0),
        ("K_rep", "0.1m^2", 0.1),
    ],
)
def test_unit_suffixes_on_sdd(nexus4, name: str, value: str, si: float) -> None:
    r = resolve_params(nexus4, {name: value})
    assert r.si[name] == pytest.approx(si, rel=1e-6)
    assert r.given[name] == value  # recorded as typed
    if name == "tau":
        assert r.scene_units["tau"] == 12 and r.tau_frames == 12


def test_unit_suffixes_on_the_builtin_scene(crossing) -> None:
    r = resolve_params(crossing, {"eta": "1/frame", "tau": "4frames", "rho0": "500cm"})
    assert r.si["eta"] == pytest.approx(10.0)  # 10 fps
    assert r.si["tau"] == pytest.approx(0.4) and r.si["rho0"] == pytest.approx(5.0)


def test_suspicious_bare_values_suggest_the_suffix(nexus4, crossing) -> None:
    with pytest.warns(SuspiciousValueWarning, match=r"rho0=18m if you meant m"):
        resolve_params(nexus4, {"rho0": 18})
    with pytest.warns(SuspiciousValueWarning, match=r"more than 100 m"):
        resolve_params(nexus4, {"sensing_radius": 4000})
    with pytest.warns(SuspiciousValueWarning, match=r"tau=12 is read in the scene's unit: 12 s"):
        resolve_params(crossing, {"tau": 12})
    with warnings.catch_warnings():
        warnings.simplefilter("error", SuspiciousValueWarning)
        resolve_params(nexus4, {"rho0": "18px", "tau": 12})  # explicit or plausible: quiet


def test_params_shows_the_scenes_units_and_defaults(capsys, sdd_dir: Path) -> None:
    assert main(["params", "--scene", "nexus_4", "--data-root", str(sdd_dir)]) == 0
    out = capsys.readouterr().out
    assert "scene nexus_4: parameters are typed in px and frames" in out
    rho0 = next(ln for ln in out.splitlines() if ln.startswith("rho0 "))
    assert rho0.split()[:5] == ["rho0", "400", "px", "18.3535", "m"]
    eta = next(ln for ln in out.splitlines() if ln.startswith("eta "))
    assert eta.split()[:5] == ["eta", "1", "1/frame", "30", "1/s"]
    assert main(["params", "--scene", "crossing"]) == 0
    out = capsys.readouterr().out
    assert "m and s (SI)" in out
    assert next(ln for ln in out.splitlines() if ln.startswith("rho0 ")).split()[:3] == [
        "rho0",
        "5",
        "m",
    ]


# ------------------------------------------------------------------------------ replay, help
def _metrics(run: Path) -> dict:
    m = json.loads((run / "metrics.json").read_text())
    m.pop("wall_s")
    return m


def test_config_replays_a_run_exactly(tmp_path: Path, sdd_dir: Path) -> None:
    first = tmp_path / "first"
    argv = ["run", "--scene", "nexus_4", "--data-root", str(sdd_dir), "--eta", "0.5"]
    extra = ["--param", "rho0=15m", "--frames", "150", "--no-plot", "-q"]
    assert main([*argv, *extra, "--out", str(first)]) == 0
    again = tmp_path / "again"
    assert main(["run", "--config", str(first / "config.json"), "--out", str(again), "-q"]) == 0
    assert _metrics(again) == _metrics(first)
    cfg = json.loads((again / "config.json").read_text())
    assert cfg["params"]["given"]["rho0"] == "15m" and cfg["params"]["given"]["eta"] == 0.5
    other = tmp_path / "other"
    assert main(["run", "--config", str(first), "--eta", "2", "--out", str(other), "-q"]) == 0
    assert _metrics(other)["eta"] == 2.0 and _metrics(other)["frames"] == 150


def test_config_replays_the_builtin_scene_and_its_seed(tmp_path: Path) -> None:
    assert main(["run", "--seed", "3", "--frames", "80", "--out", str(tmp_path / "a"), "-q"]) == 0
    assert main(["run", "--config", str(tmp_path / "a"), "--out", str(tmp_path / "b"), "-q"]) == 0
    assert _metrics(tmp_path / "b") == _metrics(tmp_path / "a")
    cfg = json.loads((tmp_path / "b" / "config.json").read_text())
    assert cfg["seed"] == 3 and cfg["command"][:2] == ["conformal-control", "run"]


def test_help_shows_defaults(capsys) -> None:
    assert main(["run", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "[default: crossing]" in out and "[default: fixed_eta]" in out
    assert "[default: constant_velocity]" in out and "[default: 0]" in out


def test_verbose_shows_diagnostics(tmp_path: Path, capsys) -> None:
    assert main(["-v", "run", "--frames", "20", "--out", str(tmp_path / "r"), "-q"]) == 0
    err = capsys.readouterr().err
    assert "INFO conformal_control.run: scene crossing" in err
    assert main(["run", "--frames", "20", "--out", str(tmp_path / "r2"), "-q"]) == 0
    assert "INFO" not in capsys.readouterr().err


# ------------------------------------------------------------------------------ learned
def test_lstm_on_the_builtin_scene_needs_no_downloaded_data(
    tmp_path: Path, capsys, monkeypatch
) -> None:
    monkeypatch.setenv("CONFORMAL_CONTROL_DATA", str(tmp_path / "no-data-here"))
    monkeypatch.setenv("CONFORMAL_CONTROL_CACHE", str(tmp_path / "cache"))
    argv = ["run", "--predictor", "lstm", "--predictor-param", "epochs=1"]
    argv += ["--predictor-param", "hidden=8", "--frames", "60", "--no-plot"]
    assert main([*argv, "--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err
    assert "training lstm on" in err
    assert "crossing's own pedestrian tracks in the 12 s before the start frame" in err
    # the line Getting started shows, up to the cache path (which is the user's)
    page = (Path(__file__).resolve().parents[3] / "docs/getting-started.md").read_text()
    shown = page.split("$ conformal-control run --predictor lstm\n", 1)[1].split(" -> ")[0]
    line = next(ln for ln in err.splitlines() if ln.startswith("training lstm"))
    assert line.startswith(shown), (line, shown)
    weights = json.loads((tmp_path / "r" / "config.json").read_text())["predictor"]["params"]
    info = json.loads((Path(weights["weights"]) / "training.json").read_text())
    assert info["dataset"] == "scene:crossing" and info["n_windows"] >= 64
    assert main([*argv, "--out", str(tmp_path / "r2")]) == 0  # cached: no retraining
    assert "training" not in capsys.readouterr().err


def test_scene_windows_use_nothing_after_the_start(crossing) -> None:
    import dataclasses

    from conformal_control.predictors.training import scene_windows

    win = scene_windows(crossing)
    pos = crossing.positions.copy()
    pos[crossing.start_index + 1 :] = np.nan  # the future hidden
    hidden = scene_windows(dataclasses.replace(crossing, positions=pos))
    assert len(win) == len(hidden) > 64
    np.testing.assert_array_equal(win.history, hidden.history)
    assert math.isclose(win.dt, 0.4)
