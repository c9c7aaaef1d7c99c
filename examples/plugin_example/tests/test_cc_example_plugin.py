"""The example plugins pass the conformal-control contract kit and drive the flagship."""

from __future__ import annotations

import json

import numpy as np

try:
    from cc_example_plugin import DampedConstantVelocity, DistanceSquaredBarrier
except ImportError as exc:  # fail loudly (never skip), saying what to do
    raise ImportError(
        "the example plugin is not installed: pip install -e examples/plugin_example"
    ) from exc


from conformal_control.cli import main
from conformal_control.core import registry
from conformal_control.predictors.base import PredictionQuery
from conformal_control.testing import parametrize_with_checks


# one test per (instance from _unit_test_params(), check): the whole contract in three lines
@parametrize_with_checks([DampedConstantVelocity, DistanceSquaredBarrier])
def test_contract(plugin, check):
    check(plugin)


def test_registered_through_entry_points():
    pred = registry.entry("predictor", "damped_cv")
    bar = registry.entry("barrier", "distance_squared")
    assert pred.origin == bar.origin == "conformal-control-example-plugin"
    assert pred.load() is DampedConstantVelocity and bar.load() is DistanceSquaredBarrier


def test_damped_prediction_values():
    hist = np.array([[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]])  # 1 m per 0.5 s sample = 2 m/s
    q = PredictionQuery(ids=np.array([7]), history=hist, dt=0.5, horizon=3)
    pos = DampedConstantVelocity(window=2, damping=0.5).predict(q).positions
    np.testing.assert_allclose(pos[0, :, 0], [2.5, 2.75, 2.875])  # steps 0.5, 0.25, 0.125 m
    np.testing.assert_allclose(pos[0, :, 1], 0.0)


def test_barrier_values():
    h, ge, ga = DistanceSquaredBarrier(d_c=1.0).evaluate(np.array([3.0, 4.0]), np.zeros(2))
    assert h == 24.0  # 25 - 1
    np.testing.assert_array_equal(ge, [6.0, 8.0])
    np.testing.assert_array_equal(ga, [-6.0, -8.0])


def test_flagship_runs_with_the_example_barrier(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["run", "--scene", "crossing", "--barrier", "distance_squared", "--frames", "200"]
    assert main([*argv, "--out", str(out), "--no-plot"]) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["barrier"]["name"] == "distance_squared"
    si = config["params"]["si"]
    d_c = si["robot_radius"] + si["agent_radius"]
    assert config["barrier"]["params"] == {"d_c": d_c}  # the scene's collision distance
    metrics = json.loads((out / "metrics.json").read_text())
    assert 0 < metrics["frames"] <= 200  # stops early once the goal is reached
    assert metrics["goal_reached"]
    assert metrics["n_collide"] == 0
    assert "results written to" in capsys.readouterr().out


def test_barrier_param_reaches_the_barrier(tmp_path):
    out = tmp_path / "run"
    argv = ["run", "--barrier", "distance_squared", "--barrier-param", "d_c=0.9"]
    assert main([*argv, "--frames", "40", "--out", str(out), "--no-plot"]) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["barrier"] == {"name": "distance_squared", "params": {"d_c": 0.9}}
