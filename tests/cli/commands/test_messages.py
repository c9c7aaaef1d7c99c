"""What a new user's typos and unit slips get: the right noun, the unit probably meant,
advice that fits the cause, and progress that a log file can hold."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import warnings
from pathlib import Path

import pytest

import conformal_control as cc
import conformal_control.core.progress as progress_mod
from conformal_control.cli import EXIT_ERROR, build_parser, main
from conformal_control.core.exceptions import (
    GoalNotReachedWarning,
    InputError,
    SuspiciousValueWarning,
)
from conformal_control.core.spec import PLAUSIBLE_SI, Parameters
from conformal_control.data.scenes import PAPER_SCENES
from conformal_control.runs.params import resolve_params

ROOT = Path(__file__).resolve().parents[3]


def error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err
    return err[0]


# ------------------------------------------------------------------------------ choices
@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (
            ["run", "--crowd", "socialforce"],
            "error: unknown crowd 'socialforce'; did you mean 'social_force'? (one of replay, "
            "orca, social_force, mixed; see `conformal-control run --help`)",
        ),
        (
            ["bench", "run", "--split", "val"],
            "error: unknown split 'val'; did you mean 'all'? (one of dev, test, all; see "
            "`conformal-control bench run --help`)",
        ),
        (
            ["export", "runs/x", "--format", "rrd"],
            "error: unknown format 'rrd'; choose from mcap, rerun, ros2-bag (see "
            "`conformal-control export --help`)",
        ),
        (
            ["reproduce", "tabel1"],
            "error: unknown target 'tabel1'; did you mean 'table1'? (one of table1, table2, "
            "forms, all; see `conformal-control reproduce --help`)",
        ),
        (
            ["rnu"],
            "error: unknown command 'rnu'; did you mean 'run'? (see `conformal-control --help`)",
        ),
    ],
    ids=["crowd", "split", "export format", "positional", "command"],
)
def test_a_wrong_choice_is_named_by_what_it_is(
    argv: list[str], expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(argv) == EXIT_ERROR
    assert error_line(capsys) == expected


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (
            ["run", "--epsilo", "-0.1"],
            "error: unknown option '--epsilo'; did you mean '--epsilon'? (see "
            "`conformal-control run --help`)",
        ),
        (
            ["run", "--strat=0.1,0.5"],
            "error: unknown option '--strat'; did you mean '--start'? (see "
            "`conformal-control run --help`)",
        ),
        (
            ["bench", "run", "--shfit", "nominal", "--out", "x"],
            "error: unknown option '--shfit'; did you mean '--shift'? (see "
            "`conformal-control bench run --help`)",
        ),
    ],
    ids=["abbreviation", "with =", "nested command"],
)
def test_an_unknown_flag_is_never_abbreviated_and_gets_a_suggestion(
    argv: list[str], expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """The issue: `--epsilo -0.1` was silently read as `--epsilon` (argparse's
    abbreviations), and typo'd flags got no suggestion while typo'd names did."""
    assert main(argv) == EXIT_ERROR
    assert error_line(capsys) == expected


def test_no_parser_of_the_cli_or_its_scripts_abbreviates() -> None:
    import argparse

    parser = build_parser()
    stack: list[argparse.ArgumentParser] = [parser]
    n = 0
    while stack:
        p = stack.pop()
        assert p.allow_abbrev is False, p.prog
        n += 1
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                stack += list(action.choices.values())
    assert n >= 20
    scripts = [
        p
        for d in ("conformal_control", "examples", "benchmarks", "plugins")
        for p in (ROOT / d).rglob("*.py")
        if "argparse.ArgumentParser(" in p.read_text()
    ]
    assert scripts
    for path in scripts:
        for call in re.findall(r"argparse\.ArgumentParser\((.*?)\)\n", path.read_text(), re.S):
            assert "allow_abbrev=False" in call, path


def test_no_choice_error_calls_an_option_value_a_command(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Every option with choices, in every command, names its own noun."""
    import argparse

    parser = build_parser()
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    n = 0
    stack = list(subs.choices.items())
    while stack:
        name, sub = stack.pop()
        for action in sub._actions:
            if isinstance(action, argparse._SubParsersAction):
                stack += [(f"{name} {k}", p) for k, p in action.choices.items()]
            elif action.choices is not None and action.option_strings:
                with pytest.raises(argparse.ArgumentError) as err:
                    sub._check_value(action, "zzzz")
                noun = max(action.option_strings, key=len).lstrip("-").replace("-", " ")
                assert f"unknown {noun} 'zzzz'" in str(err.value), (name, action.dest)
                n += 1
    assert n >= 10


# ------------------------------------------------------------------------------ --no-learning
def test_no_learning_is_the_spelling_and_no_learn_an_alias_in_help(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", "--help"]) == 0
    help_text = " ".join(capsys.readouterr().out.split())
    assert "--no-learning, --no-learn" in help_text and "--no-learn is an alias" in help_text
    assert main(["run", "--no-learn", "--frames", "5", "-q", "--out", str(tmp_path / "r")]) == 0
    cfg = json.loads((tmp_path / "r" / "config.json").read_text())
    assert cfg["learning"] is False and cfg["cli"]["no_learning"] is True
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        found = re.findall(r"--no-learn(?!ing)\b", page.read_text())
        assert not found, f"{page.name} writes --no-learn; the spelling is --no-learning"


# ------------------------------------------------------------------------------ units
def test_every_scene_default_is_plausible(crossing) -> None:
    """The plausibility ranges hold every default the toolkit ships (else a user confirming
    a default would be warned)."""
    from conformal_control.data.scenes import REFERENCE_M_PER_PX
    from conformal_control.data.units import UnitSystem

    sdd = UnitSystem(REFERENCE_M_PER_PX, 1 / 30, "px", "frame")
    cases = [(crossing.defaults, crossing.units)]
    cases += [(spec.defaults, sdd) for spec in PAPER_SCENES.values()]
    checked = 0
    for defaults, units in cases:
        for name, (lo, hi, _) in PLAUSIBLE_SI.items():
            if name in defaults and not (name == "eta" and defaults[name] == 100.0):
                si = defaults[name] * units.factor(name)
                assert lo <= si <= hi, (name, defaults[name], si)
                checked += 1
    assert checked > 40
    # the ranges live in the one parameter table
    infos = {f.name: f.metadata["info"].plausible for f in dataclasses.fields(Parameters)}
    assert {k for k, v in infos.items() if v} == set(PLAUSIBLE_SI) >= {"eta", "tau", "a"}


@pytest.mark.parametrize(
    ("scene", "given", "words"),
    [
        (
            "nexus4",
            {"eta": 30},
            "eta=30 is read in the scene's unit: 30 1/frame = 900 1/s on nexus_4, more than "
            "100 1/s; write eta=30/frame to confirm it, or eta=30/s if you meant 1/s",
        ),
        (
            "crossing",
            {"tau": 4},
            "tau=4 is read in the scene's unit: 4 s on crossing, more than 2 s; write tau=4s "
            "to confirm it, or tau=4frames if you meant frames (0.4 s)",
        ),
        ("nexus4", {"K_acc": 60}, "or K_acc=60/s if you meant 1/s"),
        ("nexus4", {"a": 300}, "or a=300/s if you meant 1/s"),
    ],
)
def test_a_value_typed_in_the_other_unit_system_is_warned(
    scene: str, given: dict, words: str, request: pytest.FixtureRequest
) -> None:
    sc = request.getfixturevalue(scene)
    with pytest.warns(SuspiciousValueWarning) as rec:
        resolve_params(sc, given)
    assert len(rec) == 1 and words in str(rec[0].message)


def test_plausible_or_explicit_values_are_quiet(nexus4, crossing, sdd_dir: Path) -> None:
    from conformal_control.data import load_scene

    gates = load_scene("gates_1", sdd_dir)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SuspiciousValueWarning)
        resolve_params(nexus4, {"eta": 1, "tau": 8, "a": 1, "K_acc": 2})
        resolve_params(nexus4, {"eta": "30/s", "tau": "0.4s"})
        resolve_params(nexus4, {"eta": "30/frame"})  # implausible, but confirmed
        resolve_params(crossing, {"eta": 30, "tau": 0.4, "a": 2})
        resolve_params(gates, {"eta": 100})  # Table I's: 3000/s, but the scene's default
    with pytest.warns(SuspiciousValueWarning, match="eta=100 is read"):
        resolve_params(nexus4, {"eta": 100})


def test_eta_and_tau_flags_take_a_unit(tmp_path: Path, sdd_dir: Path) -> None:
    argv = ["run", "--scene", "nexus_4", "--data-root", str(sdd_dir), "--frames", "5", "-q"]
    out = tmp_path / "r"
    with warnings.catch_warnings():
        warnings.simplefilter("error", SuspiciousValueWarning)
        assert main([*argv, "--eta", "30/s", "--tau", "0.4s", "--out", str(out)]) == 0
    si = json.loads((out / "config.json").read_text())["params"]["si"]
    assert si["eta"] == pytest.approx(30.0) and si["tau"] == pytest.approx(0.4)


def test_tau_in_frames_that_is_not_whole_suggests_seconds(nexus4, crossing) -> None:
    with pytest.raises(InputError) as err:
        resolve_params(nexus4, {"tau": 0.4})
    assert str(err.value).endswith("not 0.4; write tau=0.4s if you meant seconds (12 frames)")
    with pytest.raises(InputError, match=r"the nearest are tau=0.4s \(4 frames\) or tau=0.5s"):
        resolve_params(crossing, {"tau": 0.45})


# ------------------------------------------------------------------------------ plugin units
def test_plugin_parameters_take_si_suffixes(tmp_path: Path) -> None:
    out = tmp_path / "r"
    argv = ["run", "--frames", "5", "-q", "--no-plot", "--out", str(out)]
    argv += ["--predictor", "noisy", "--predictor-param", "sigma_m=20cm"]
    argv += ["--crowd", "mixed", "--crowd-param", "radius=300cm"]
    argv += ["--crowd-param", "min_max_speed=3.6km/h", "--crowd-param", "tau=500ms"]
    assert main(argv) == 0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["predictor"]["params"]["sigma_m"] == pytest.approx(0.2)
    crowd = cfg["crowd"]
    assert crowd["mixed_radius"] == pytest.approx(3.0)
    assert crowd["min_max_speed"] == pytest.approx(1.0)
    assert crowd["model_params"]["tau"] == pytest.approx(0.5)


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (
            ["--crowd", "social_force", "--crowd-param", "min_max_speed=2m"],
            "min_max_speed is a speed in m/s, but m is a length",
        ),
        (
            ["--crowd", "social_force", "--crowd-param", "gamma=2m"],
            "gamma has no documented unit",
        ),
        (["--predictor", "delayed", "--predictor-param", "delay_s=3frames"], "not converted"),
        (["--predictor", "noisy", "--predictor-param", "sigma_m=2furlongs"], "unknown unit"),
        (  # not an argument at all: named as such, not as a unit problem
            ["--predictor-param", "max_speed=2m/s"],
            "predictor 'constant_velocity' has no parameter 'max_speed'; its parameters: window",
        ),
        (["--predictor-param", "windw=2"], "no parameter 'windw'; did you mean 'window'?"),
    ],
)
def test_a_plugin_unit_that_does_not_fit_fails_before_the_data_is_read(
    argv: list[str], words: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the data root does not exist: the unit is checked before the scene is loaded
    base = ["run", "--scene", "nexus_4", "--data-root", str(tmp_path / "none"), "-q"]
    assert main([*base, *argv, "--out", str(tmp_path / "r")]) == EXIT_ERROR
    line = error_line(capsys)
    assert words in line and "not found" not in line


# ------------------------------------------------------------------------------ cc.run
@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"rho": 3}, "unexpected keyword argument 'rho'; did you mean params={'rho0': 3}?"),
        ({"epsilom": -0.1}, "did you mean epsilon=-0.1?"),
        ({"barier": "apf"}, "did you mean barrier='apf'?"),
        ({"rho0": 3}, "takes the controller parameter 'rho0' in params"),
    ],
)
def test_run_keywords_get_a_did_you_mean(kwargs: dict, words: str) -> None:
    with pytest.raises(TypeError) as err:
        cc.run("crossing", **kwargs)
    assert words in str(err.value)


# ------------------------------------------------------------------------------ advice
@pytest.mark.filterwarnings("ignore::conformal_control.core.exceptions.FeasibilityWarning")
def test_below_the_floor_the_missed_goal_is_blamed_on_the_fallback(crossing) -> None:
    with pytest.warns(GoalNotReachedWarning) as rec:  # the default lambda floor opened
        res = cc.run(crossing, epsilon=-0.45, params={"lambda_min": -math.inf})
    text = str(next(w.message for w in rec if w.category is GoalNotReachedWarning))
    share = res.metrics["fallback_share"]
    assert not res.metrics["goal_reached"] and share > 0.25
    assert "epsilon=-0.45 is below the feasibility floor" in text
    assert f"the fallback decided at {share:.0%} of the control instants" in text
    assert "start frame" not in text and "closer goal" not in text
    assert res.metrics["lambda_final"] < res.metrics["lambda_floor"]  # "lambda sank below it"
    # the advice works: epsilon above the floor reaches the goal
    assert cc.run(crossing, epsilon=-0.2).metrics["goal_reached"]


def test_the_floor_advice_knows_the_lambda_min_given(nexus4) -> None:
    """The issue: `--param a=1 --param lambda_min=-5` failed and the warning advised
    clipping lambda with lambda_min, already given. A lambda_min at or below the floor is
    named as the reason, with the bound that works; one above it is not advised again."""
    from conformal_control.core.exceptions import FeasibilityWarning

    def warned(**params: float) -> tuple[list[str], cc.EpisodeResult]:
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            res = cc.run(nexus4, params={"a": 1, **params}, units="scene")
        texts = [str(w.message) for w in rec if issubclass(w.category, FeasibilityWarning)]
        texts += [str(w.message) for w in rec if w.category is GoalNotReachedWarning]
        return texts, res

    texts, res = warned(lambda_min=-5)
    assert not res.metrics["goal_reached"] and len(texts) == 2, texts
    for text in texts:
        assert "lambda_min=-5 1/frame is at or below the floor (-0.5 1/frame)" in text
        assert text.endswith("set lambda_min above -0.5 1/frame, or raise epsilon or a")
    texts, res = warned(lambda_min=-0.45)  # the advice works
    assert res.metrics["goal_reached"] and res.metrics["fallback_share"] == 0
    assert len(texts) == 1 and texts[0].endswith(
        "lambda_min=-0.45 1/frame keeps lambda above that floor, so l_avg cannot come down "
        "to epsilon"
    )
    assert res.metrics["l_avg"] > res.metrics["epsilon"]


# ------------------------------------------------------------------------------ progress
def test_animate_writes_lines_not_carriage_returns_into_a_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(progress_mod, "DELAY", 0.0)
    monkeypatch.setattr(progress_mod, "EVERY", 0.0)
    monkeypatch.delenv("CONFORMAL_CONTROL_PROGRESS", raising=False)
    assert main(["run", "--frames", "20", "-q", "--no-plot", "--out", str(tmp_path / "r")]) == 0
    capsys.readouterr()
    gif = tmp_path / "r.gif"
    assert main(["animate", str(tmp_path / "r"), "--out", str(gif), "--dpi", "30"]) == 0
    err = capsys.readouterr().err  # captured: not a terminal, like a log file
    assert gif.is_file()
    assert "\r" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("rendering r.gif")]
    assert len(lines) >= 2 and lines[-1].startswith("rendering r.gif: done,")


# ------------------------------------------------------------------------------ data root
def test_every_data_root_option_names_the_three_places_in_order() -> None:
    """Every command reading data takes ``--data-root`` and says where it looks without it:
    the option, ``$CONFORMAL_CONTROL_DATA``, the per-user folder ``fetch-data`` fills."""
    import argparse

    from conformal_control.cli import build_parser

    def parsers(p: argparse.ArgumentParser, name: str):
        yield name, p
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for sub, sp in a.choices.items():
                    yield from parsers(sp, f"{name} {sub}")

    found = []
    for name, p in parsers(build_parser(), "conformal-control"):
        for a in p._actions:
            if "--data-root" in a.option_strings:
                found.append(name)
                text = " ".join((a.help or "").split())
                assert "$CONFORMAL_CONTROL_DATA, else the per-user data folder" in text, name
                assert "fetch-data" in text, name
    for name in ("run", "params", "sweep", "reproduce", "eval-predictor", "bench run"):
        assert f"conformal-control {name}" in found, (name, found)


# ------------------------------------------------------------------------------ start-up
def _commands_of(parser) -> list[str]:
    import argparse

    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sorted(sub.choices)


def test_a_command_line_builds_the_parser_of_its_command_only() -> None:
    every = _commands_of(build_parser())
    assert {"run", "bench", "fetch-data", "scenes"} <= set(every)
    assert _commands_of(build_parser(["run", "--scene", "nexus_4"])) == ["run"]
    assert _commands_of(build_parser(["-q", "-vv", "bench", "run"])) == ["bench"]
    # no module named like the command (fetch-data lives in commands/data.py), no command,
    # help, version, a typo: every command
    for argv in (["fetch-data"], [], ["--help"], ["--version"], ["runn"], ["-x", "run"]):
        assert _commands_of(build_parser(argv)) == every, argv


@pytest.mark.parametrize(
    "argv",
    [["run", "--no-such-option"], ["run", "--crowd", "nobody"], ["run", "--epsilon", "x"]],
)
def test_usage_errors_read_the_same_with_the_command_parser_alone(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit):
        build_parser(argv).parse_args(argv)
    alone = capsys.readouterr().err
    with pytest.raises(SystemExit):
        build_parser().parse_args(argv)
    assert capsys.readouterr().err == alone and alone.startswith("error: ")
