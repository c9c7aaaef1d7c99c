"""``conformal-control run --barrier NAME --barrier-param K=V``: any registered barrier drives
the flagship and is recorded in config.json."""

from __future__ import annotations

import json

import numpy as np

from conformal_control.cli import main
from conformal_control.core import registry
from conformal_control.families.cbf.roles import Barrier


class _ScaledDistance(Barrier, run_values={"d_c": "barrier_distance"}):
    """h = gain (|x_ego - x_agent| - d_c), registered at runtime for this test (it asks for
    the run's collision distance as its d_c)."""

    def __init__(self, d_c: float = 1.0, gain: float = 1.0) -> None:
        self.d_c = d_c
        self.gain = gain

    def evaluate(self, x_ego, x_agent):
        diff = np.subtract(x_ego, x_agent, dtype=float)
        d = np.hypot(diff[..., 0], diff[..., 1])
        g = self.gain * diff / np.maximum(d, 1e-12)[..., None]
        return self.gain * (d - self.d_c), g, -g


def test_default_run_records_the_apf_barrier(tmp_path):
    out = tmp_path / "run"
    assert main(["run", "--frames", "20", "--out", str(out), "--no-plot"]) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["barrier"]["name"] == "apf"
    assert config["barrier"]["params"]["convention"] == "surface"


def test_runtime_barrier_with_params_drives_the_run(tmp_path):
    registry.register("barrier", "_kit_scaled", _ScaledDistance)
    try:
        out = tmp_path / "run"
        argv = ["run", "--barrier", "_kit_scaled", "--barrier-param", "gain=2.5"]
        assert main([*argv, "--frames", "60", "--out", str(out), "--no-plot"]) == 0
    finally:
        registry.unregister("barrier", "_kit_scaled")
    config = json.loads((out / "config.json").read_text())
    si = config["params"]["si"]
    assert config["barrier"] == {
        "name": "_kit_scaled",
        "params": {"d_c": si["robot_radius"] + si["agent_radius"], "gain": 2.5},
    }
    assert config["feasibility"]["attainable"] is True  # unbounded barrier: no floor


def test_unknown_barrier_is_one_clear_error(tmp_path, capsys):
    assert main(["run", "--barrier", "apff", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "unknown barrier 'apff'; did you mean 'apf'?" in err


def test_barrier_param_needs_barrier(tmp_path, capsys):
    argv = ["run", "--barrier-param", "d_c=1", "--out", str(tmp_path / "x")]
    assert main(argv) == 2
    assert "--barrier-param needs --barrier NAME" in capsys.readouterr().err
