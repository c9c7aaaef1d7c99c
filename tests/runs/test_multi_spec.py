"""The robots section of a run specification: settings checked when given (one line each),
lambda's default scope, config.json read back into the same run, and the command line's
options reaching the section (``run --robots ... --config``)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from conformal_control.cli import main
from conformal_control.core.exceptions import InputError
from conformal_control.core.spec import ROBOT_FIELDS, Robots, RunSpec
from conformal_control.runs.fleet import run_multi


@pytest.mark.parametrize(
    ("setting", "words"),
    [
        ({"robots": 0}, "robots must be an integer from 1 to 20"),
        ({"robots": 21}, "robots must be an integer from 1 to 20"),
        ({"robots": 2.0}, "robots must be an integer"),
        ({"robots": True}, "robots must be an integer"),
        ({"layout": "ring"}, "layout must be one of scene, antipodal"),
        ({"sensor_history": "all"}, "sensor_history must be one of tracked, observed"),
        ({"reciprocity": "ignore"}, "reciprocity must be one of reciprocal, none"),
        ({"information": "telepathy"}, "information must be one of position, velocity, plan"),
        ({"lambda_scope": "all"}, "lambda_scope must be one of pedestrians, robots, both"),
        ({"hard_rows": "first"}, "hard_rows must be one of level, last"),
        ({"radius": -1.0}, "radius must be a finite number > 0"),
        ({"radius": float("inf")}, "radius must be a finite number > 0"),
        ({"center": [1.0]}, "center must be two finite numbers"),
        ({"center": "0,0"}, "center must be two finite numbers"),
        ({"weights": [1.0, -1.0]}, "weights must be a list of finite numbers > 0"),
        ({"weights": [1.0, float("nan")]}, "weights must be a list of finite numbers > 0"),
        ({"weights": "ab"}, "weights must be a list of finite numbers > 0"),
        ({"weights": []}, "weights must be a list of finite numbers > 0"),
        ({"ignoring": 5}, "ignoring must be a list of robot indices"),
        ({"ignoring": [True]}, "ignoring must be a list of robot indices"),
        ({"ignoring": [-1]}, "ignoring must be a list of robot indices"),
        ({"ignoring": ["a"]}, "ignoring must be a list of robot indices"),
        ({"sidestep": float("nan")}, "sidestep must be an angle in \\[0, pi/2\\]"),
        ({"sidestep": 2.0}, "sidestep must be an angle in \\[0, pi/2\\]"),
        ({"sidestep": "a"}, "sidestep must be an angle in \\[0, pi/2\\]"),
        ({"floor_margin": -0.1}, "floor_margin must be a finite distance >= 0"),
        ({"floor_margin": float("nan")}, "floor_margin must be a finite distance >= 0"),
        ({"floor_margin": float("inf")}, "floor_margin must be a finite distance >= 0"),
        ({"floor_margin": "0.1"}, "floor_margin must be a finite distance >= 0"),
        ({"floor_margin": True}, "floor_margin must be a finite distance >= 0"),
        ({"floor_core": "never"}, "floor_core must be one of always, inside, calm, ahead, none"),
        ({"floor_core": None}, "floor_core must be one of always, inside, calm, ahead, none"),
    ],
)
def test_robots_settings_are_checked_when_given_in_one_line(setting, words):
    # directly, through the keyword settings of run_multi, and read from a config file
    with pytest.raises(InputError, match=words) as err:
        Robots(**setting)
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match=words):
        RunSpec.from_settings(**setting)
    with pytest.raises(InputError, match=words):
        RunSpec.from_dict({"robots": {**Robots().as_dict(), **setting}}, "config.json")


def test_an_unknown_robots_key_in_a_file_is_one_line():
    with pytest.raises(InputError, match=r"config\.json: robots must be a mapping of robots,"):
        RunSpec.from_dict({"robots": {"robots": 2, "reciprocal": True}}, "config.json")


def test_lists_are_kept_as_tuples_so_a_section_read_back_is_equal():
    r = Robots(robots=3, weights=[1, 2.5, 1], ignoring=np.array([2]), center=[1, 2])
    assert r.weights == (1.0, 2.5, 1.0) and r.ignoring == (2,) and r.center == (1.0, 2.0)
    assert Robots(**json.loads(json.dumps(r.as_dict()))) == r
    assert set(r.as_dict()) == set(ROBOT_FIELDS)


def test_lambda_scope_defaults_to_the_pedestrians_with_reciprocity_and_both_without(crossing):
    assert Robots().lambda_scope is None
    assert Robots().scope == "pedestrians"
    assert Robots(reciprocity="none").scope == "both"
    assert Robots(reciprocity="none", lambda_scope="robots").scope == "robots"
    # without reciprocity every row is a prediction: by default lambda is the slack of all
    # of them, as in the single-robot controller (and as `run --reciprocity none` does)
    kw = dict(robots=2, max_frames=150, record_animation=False, reciprocity="none")
    default, both = run_multi(crossing, **kw), run_multi(crossing, lambda_scope="both", **kw)
    ped = run_multi(crossing, lambda_scope="pedestrians", **kw)
    np.testing.assert_array_equal(default.track["robots"], both.track["robots"])
    assert default.config["reciprocity"]["lambda_scope"] == "both"
    # ... which is not what lambda on the pedestrians alone does (the test can fail)
    assert [iv["lambda"] for iv in ped.robots[0].intervals] != [
        iv["lambda"] for iv in default.robots[0].intervals
    ]


def test_config_json_reads_back_into_the_same_multi_robot_run(tmp_path, crossing):
    res = run_multi(
        crossing,
        robots=3,
        information="velocity",
        lambda_scope="both",
        weights=[1.0, 2.0, 1.0],
        ignoring=[2],
        sidestep=0.2,
        hard_rows="level",
        floor_margin=0.05,
        floor_core="inside",
        sensor_history="observed",
        max_frames=120,
        seed=4,
        record_animation=False,
    )
    out = res.save(tmp_path / "run")
    cfg = json.loads((out / "config.json").read_text())
    spec = RunSpec.from_dict(cfg["spec"], "config.json")
    assert spec.robots == Robots(
        robots=3,
        information="velocity",
        lambda_scope="both",
        weights=(1.0, 2.0, 1.0),
        ignoring=(2,),
        sidestep=0.2,
        hard_rows="level",
        floor_margin=0.05,
        floor_core="inside",
        sensor_history="observed",
    )
    assert res.config["reciprocity"]["floor_margin"] == 0.05
    assert res.config["reciprocity"]["floor_core"] == "inside"
    assert spec.seed == 4 and spec.max_frames == 120
    again = run_multi(crossing, spec)
    np.testing.assert_array_equal(again.track["robots"], res.track["robots"])
    for a, b in zip(again.robots, res.robots, strict=True):
        assert [iv["lambda"] for iv in a.intervals] == [iv["lambda"] for iv in b.intervals]
    assert again.config["reciprocity"] == res.config["reciprocity"]
    # a changed setting on the spec is a different run (the equality above can fail)
    other = run_multi(
        crossing, dataclasses.replace(spec, robots=dataclasses.replace(spec.robots, ignoring=()))
    )
    assert not np.array_equal(other.track["robots"], res.track["robots"], equal_nan=True)


def test_the_command_line_options_reach_the_robots_section_and_replay(tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    argv = ["run", "--robots", "3", "--frames", "80", "--no-plot"]
    opts = ["--reciprocity", "none", "--information", "velocity", "--lambda-scope", "robots"]
    assert main([*argv, *opts, "--out", str(first)]) == 0
    cfg = json.loads((first / "config.json").read_text())
    robots = cfg["spec"]["robots"]
    assert (robots["robots"], robots["reciprocity"]) == (3, "none")
    assert (robots["information"], robots["lambda_scope"]) == ("velocity", "robots")
    assert cfg["reciprocity"]["lambda_scope"] == "robots"
    assert cfg["cli"]["reciprocity"] == "none" and cfg["cli"]["robots"] == 3
    # `run --config` replays the stored options; an option given beside it wins
    assert main(["run", "--config", str(first), "--out", str(second), "--no-plot"]) == 0
    a = (first / "trajectories.csv").read_text()
    assert a == (second / "trajectories.csv").read_text()
    cfg2 = json.loads((second / "config.json").read_text())
    assert cfg2["spec"] == cfg["spec"]
    third = tmp_path / "third"
    argv3 = ["run", "--config", str(first), "--lambda-scope", "both", "--out", str(third)]
    assert main([*argv3, "--no-plot"]) == 0
    cfg3 = json.loads((third / "config.json").read_text())
    assert cfg3["spec"]["robots"]["lambda_scope"] == "both"
    assert cfg3["spec"]["robots"]["reciprocity"] == "none"
    # without --lambda-scope the default follows the reciprocity
    fourth = tmp_path / "fourth"
    assert main([*argv, "--reciprocity", "none", "--out", str(fourth)]) == 0
    cfg4 = json.loads((fourth / "config.json").read_text())
    assert cfg4["spec"]["robots"]["lambda_scope"] is None
    assert cfg4["reciprocity"]["lambda_scope"] == "both"
    assert cfg4["reciprocity"]["floor_margin"] == 0.1  # the default


def test_floor_margin_on_the_command_line_reaches_the_run_and_is_checked(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["run", "--robots", "2", "--frames", "40", "--no-plot", "--floor-margin", "0.25"]
    assert main([*argv, "--floor-core", "none", "--out", str(out)]) == 0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["spec"]["robots"]["floor_margin"] == 0.25
    assert cfg["reciprocity"]["floor_margin"] == 0.25
    assert cfg["cli"]["floor_margin"] == 0.25  # what --config replays
    assert cfg["spec"]["robots"]["floor_core"] == "none"
    assert cfg["reciprocity"]["floor_core"] == "none" and cfg["cli"]["floor_core"] == "none"
    for bad, words in (
        (["--robots", "2", "--floor-margin", "-1"], "floor_margin must be a finite distance"),
        (["--robots", "2", "--floor-margin", "nan"], "floor_margin must be a finite distance"),
        (["--floor-margin", "0.1"], "--floor-margin .* needs --robots"),
        (["--floor-core", "none"], "--floor-core .* needs --robots"),
    ):
        capsys.readouterr()
        rc = main(["run", "--frames", "5", "--no-plot", "--out", str(tmp_path / "x"), *bad])
        err = capsys.readouterr().err
        assert rc != 0 and len(err.strip().splitlines()) == 1
        assert __import__("re").search(words, err), err


# ------------------------------------------------------------------ one robot refuses a fleet
@pytest.mark.parametrize(
    ("settings", "words"),
    [
        ({"robots": 3}, "cannot honour robots=3"),
        ({"robots": 3, "starts": [[0, 0]], "goals": "zzz"}, "starts=[[0, 0]], goals='zzz'"),
        ({"reciprocity": "none"}, "cannot honour reciprocity='none'"),
    ],
)
def test_the_public_run_refuses_a_robots_section(settings: dict, words: str) -> None:
    """``cc.run("crossing", robots=3)`` ran one robot, without a word."""
    import conformal_control as cc

    with pytest.raises(InputError, match="run\\(\\) drives one robot") as info:
        cc.run("crossing", max_frames=5, **settings)
    assert words in str(info.value) and "run_multi" in str(info.value)


def test_a_spec_read_from_a_multi_robot_config_is_not_run_as_one_robot(tmp_path) -> None:
    import conformal_control as cc
    from conformal_control.data import load_scene
    from conformal_control.runs.episode import run_episode

    res = run_multi(load_scene("crossing", seed=0), 2, max_frames=5)
    spec = RunSpec.from_dict(res.config["spec"])
    assert spec.robots is not None and spec.robots.robots == 2
    with pytest.raises(InputError, match=r"a robots section \(robots=2\)"):
        cc.run("crossing", spec)
    with pytest.raises(InputError, match="robots=2"):
        run_episode(load_scene("crossing", seed=0), spec)
    again = run_multi(load_scene("crossing", seed=0), spec, max_frames=5)
    assert len(again.robots) == 2
