"""Every configuration of a sweep is checked before any run starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from conformal_control.cli import main
from conformal_control.experiments import SweepSpec, SweepValidationError, run_sweep, validate_runs

BASE = ["sweep", "--scene", "crossing", "--set", "frames=10", "--progress", "off"]


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        (["--grid", "eta=abc"], ["eta", "'abc'", "2 of 2 runs"]),
        (["--grid", "eta=0.5,abc"], ["eta", "'abc'", "2 of 4 runs"]),
        (["--set", "eta=abc"], ["eta", "'abc'"]),
        (["--grid", "epsilon=0.1,0.9,-0.7"], ["got 0.9", "got -0.7", "4 of 6 runs"]),
        (["--grid", "tau=0.25"], ["tau must be a positive whole number of frames"]),
        (["--grid", "etaa=1,2"], ["unknown sweep key(s) etaa"]),
        (["--set", "learn=maybe"], ["'learn' must be true or false"]),
        (["--predictor", "constant_velocty"], ["constant_velocity"]),
        (["--grid", "predictor_params.windw=1,2"], ["windw"]),
    ],
)
def test_cli_rejects_a_bad_value_before_any_run(
    tmp_path: Path, capsys, options: list[str], expected: list[str]
) -> None:
    out = tmp_path / "sw"
    assert main([*BASE, "--grid", "seed=0,1", *options, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err  # one sentence, one line
    for text in expected:
        assert text in err
    assert not (out / "runs").exists() and not (out / "results.jsonl").exists()
    assert main([*BASE, "--grid", "seed=0,1", *options, "--out", str(out), "--dry-run"]) == 2
    assert capsys.readouterr().err.strip() == err  # a dry run makes the same check


def test_validation_lists_each_problem_once_with_its_runs() -> None:
    spec = SweepSpec(
        base={"scene": "crossing", "frames": 10},
        grid={"eta": [0.5, "abc"], "epsilon": [0.0, 0.9], "seed": [0, 1]},
    )
    with pytest.raises(SweepValidationError) as info:
        validate_runs(spec.expand())
    problems = info.value.problems
    assert len(problems) == 2  # eta "abc" (4 runs), epsilon 0.9 with eta 0.5 (2 runs)
    assert sorted(len(keys) for keys in problems.values()) == [2, 4]
    assert str(info.value).startswith("6 of 8 runs of the sweep are invalid")


def test_no_learn_runs_are_validated_like_they_run(tmp_path: Path) -> None:
    """learn=false sets eta to 0 unless given, as the run does; a bad eta still fails."""
    ok = SweepSpec(base={"scene": "crossing", "frames": 10, "learn": False})
    validate_runs(ok.expand())
    bad = SweepSpec(base={"scene": "crossing", "frames": 10, "learn": False, "eta": -1})
    with pytest.raises(ValueError, match="eta"):
        run_sweep(bad, tmp_path, "serial", progress=False)
    assert not (tmp_path / "runs").exists()


def test_missing_data_is_reported_before_any_run(tmp_path: Path) -> None:
    spec = SweepSpec(
        base={"scene": "nexus_4", "data_root": str(tmp_path / "nowhere"), "frames": 10},
        grid={"seed": [0, 1]},
    )
    with pytest.raises(SweepValidationError, match="2 of 2 runs"):
        run_sweep(spec, tmp_path / "sw", "serial", progress=False)
    assert not (tmp_path / "sw" / "runs").exists()
