"""The run specification: the parameter table and RunSpec (types, deep parameters, JSON)."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest

from conformal_control.core.exceptions import InputError
from conformal_control.core.spec import (
    PARAM_DIMENSIONS,
    PARAMETERS,
    PLAUSIBLE_SI,
    Parameters,
    RunSpec,
    parameter_info,
)


def test_one_table_gives_every_derived_table() -> None:
    names = Parameters.names()
    assert tuple(PARAMETERS) == names
    assert set(PARAM_DIMENSIONS) <= set(names) and set(PLAUSIBLE_SI) <= set(PARAM_DIMENSIONS)
    assert PARAM_DIMENSIONS["eta"] == (0, -1) and PARAM_DIMENSIONS["K_rep"] == (2, 0)
    assert "v_max" not in PARAM_DIMENSIONS  # always SI
    info = parameter_info("epsilon")
    assert (info.low, info.high, info.closed) == (-0.5, 0.5, (False, False))
    assert parameter_info("substeps").kind == "int"
    assert PARAMETERS["lambda_max"][0] == math.inf
    assert dataclasses.fields(Parameters)[0].metadata["info"].doc == PARAMETERS["a"][1]


def test_round_trip_through_json() -> None:
    spec = RunSpec(
        params={"epsilon": -0.1, "rho0": "18m"},
        predictor=("constant_velocity", {"window": 3}),
        barrier="apf",
        rule=("pid", {"K_I": 0.1}),
        crowd=("social_force", {"radius": 3.0}),
        units="si",
        learn=False,
        seed=7,
        max_frames=120,
        lambda_safe=0.5,
        engine="loop",
    )
    text = json.dumps(spec.as_dict())
    assert RunSpec.from_dict(json.loads(text)) == spec


def test_deep_parameters() -> None:
    spec = RunSpec(predictor="constant_velocity")
    changed = spec.set_params(predictor__window=4, epsilon=-0.2, seed=3)
    assert changed.role("predictor") == ("constant_velocity", {"window": 4})
    assert changed.params == {"epsilon": -0.2} and changed.seed == 3
    flat = changed.get_params()
    assert flat["predictor__window"] == 4 and flat["epsilon"] == -0.2
    assert spec.role("predictor") == ("constant_velocity", {})  # frozen: spec unchanged
    with pytest.raises(InputError, match="give the barrier by name"):
        spec.set_params(barrier__K_rep=1.0)
    with pytest.raises(InputError, match="unknown run setting 'epsilonn'"):
        spec.set_params(epsilonn=0.1)


@pytest.mark.parametrize(
    ("data", "words"),
    [
        ({"learn": "false"}, "learn must be bool, got 'false'"),
        ({"max_frames": "abc"}, "max_frames must be int or None, got 'abc'"),
        ({"seed": True}, "seed must be int, got True"),
        ({"params": {"epsilonn": 0.1}}, "did you mean 'epsilon'"),
        ({"units": "px"}, "units must be 'scene' or 'si'"),
        ({"out": "/tmp/x"}, "unknown key 'out'"),
        ({"predictor": {"name": 3}}, "role predictor as a mapping"),
        ({"barrier": {"instance": "APFBarrier", "params": {}}}, "give it by registered name"),
    ],
)
def test_from_dict_is_type_checked(data: dict, words: str) -> None:
    with pytest.raises(InputError, match=words.replace("(", r"\(").replace(")", r"\)")):
        RunSpec.from_dict(data)


def test_every_benchmark_method_is_a_run_specification() -> None:
    from conformal_control.experiments.bench.methods import METHOD_FAMILIES, expand_methods

    for m in expand_methods(METHOD_FAMILIES):
        spec = m.run_spec("oracle")
        assert spec.units == "si" and spec.learn == m.learn
        assert spec.role_name("predictor") == (m.predictor or "oracle")
        data = json.loads(json.dumps(spec.as_dict()))  # tuples come back as lists
        assert RunSpec.from_dict(data).as_dict() == data


def test_config_json_is_the_specification_of_the_run() -> None:
    """config.json holds the run's specification; read back, it runs the same episode."""
    from conformal_control.data import load_scene
    from conformal_control.runs.episode import run_episode

    spec = RunSpec(
        params={"epsilon": 0.1, "a": 2.0, "lambda_min": -math.inf},
        rule=("aci", {"alpha": 0.2}),
        units="si",
        seed=3,
        max_frames=80,
    )
    first = run_episode(load_scene("crossing", seed=3), spec, engine="loop")
    data = json.loads(json.dumps(first.config["spec"]))
    assert data["engine"] == "loop" and data["params"]["lambda_min"] == "-inf"
    again = RunSpec.from_dict(data)
    assert again == dataclasses.replace(spec, engine="loop")
    second = run_episode(load_scene("crossing", seed=3), again, engine="loop")
    a, b = first.metrics.as_dict(), second.metrics.as_dict()
    a.pop("wall_s"), b.pop("wall_s")
    assert a == b and a["n_updates"] > 0


def test_the_fallback_is_set_one_way() -> None:
    """The run's fallback role; the parameter and the filter parameter of 0.2 move there."""
    assert "fallback" not in PARAMETERS
    with pytest.warns(DeprecationWarning, match="fallback=NAME"):
        spec = RunSpec(params={"fallback": "brake", "epsilon": 0.1})
    assert spec.fallback == "brake" and spec.params == {"epsilon": 0.1}
    with pytest.warns(DeprecationWarning):
        spec = RunSpec(safety_filter=("exact2d", {"fallback": "hold", "speed_sides": 8}))
    assert spec.fallback == "hold" and spec.role("safety_filter") == ("exact2d", {"speed_sides": 8})
    with pytest.raises(InputError, match="given twice"):
        RunSpec(params={"fallback": "brake"}, fallback="hold")


def test_the_fallback_parameter_of_the_command_line_is_the_role(tmp_path) -> None:
    from conformal_control.cli import main

    for name, argv in (("a", ["--fallback", "brake"]), ("b", ["--param", "fallback=brake"])):
        out = tmp_path / name
        assert main(["run", "--frames", "40", "--out", str(out), "-q", "--no-plot", *argv]) == 0
    cfgs = [json.loads((tmp_path / n / "config.json").read_text()) for n in "ab"]
    assert cfgs[0]["fallback"] == cfgs[1]["fallback"] == "brake"
    metrics = [json.loads((tmp_path / n / "metrics.json").read_text()) for n in "ab"]
    for m in metrics:
        m.pop("wall_s")
    assert metrics[0] == metrics[1]


# ------------------------------------------------------------------ values read from a file
@pytest.mark.parametrize(
    ("data", "words"),
    [
        ({"predictor": 5}, "predictor must be a registered name"),
        ({"rule": True}, "rule must be a registered name"),
        ({"params": {"epsilon": float("nan")}}, "parameter epsilon must be finite, got nan"),
        ({"params": {"eta": float("inf")}}, "parameter eta must be finite"),
        ({"params": {"lambda_max": float("-inf")}}, "parameter lambda_max must be finite"),
        ({"params": {"tau": [1]}}, "parameter tau must be a number"),
        ({"params": {"tau": True}}, "parameter tau must be a number"),
        ({"seed": -3}, "seed must be an integer in [0, 2**63), got -3"),
        ({"lambda_safe": float("nan")}, "lambda_safe must be finite"),
        ({"lambda_safe": "safe"}, "lambda_safe must be a number or 'auto'"),
    ],
)
def test_from_dict_refuses_what_fails_later_with_one_input_error(data: dict, words: str) -> None:
    """These passed ``from_dict`` and failed later as TypeError or ValueError."""
    from conformal_control.core.exceptions import InputError

    with pytest.raises(InputError) as info:
        RunSpec.from_dict(data, where="config.json")
    assert words in str(info.value) and str(info.value).startswith("config.json")


def test_from_dict_keeps_what_config_json_writes() -> None:
    spec = RunSpec(params={"lambda_min": -math.inf, "tau": "0.4s", "eta": 2.0}, seed=7)
    back = RunSpec.from_dict(json.loads(json.dumps(spec.as_dict())))
    assert back.params["lambda_min"] == -math.inf and back.params["tau"] == "0.4s"
    assert back.seed == 7


def test_lambda_safe_auto_says_where_it_comes_from() -> None:
    spec = RunSpec(lambda_safe="auto")
    assert spec.lambda_safe_source is not None
    assert spec.lambda_safe_source.startswith("derived: CBF gap bound")
    own = RunSpec(lambda_safe="auto", lambda_safe_source="mine")
    assert own.lambda_safe_source == "mine"
    back = RunSpec.from_dict(json.loads(json.dumps(spec.as_dict())))
    assert back.lambda_safe == "auto"
