"""The MPC families run where the CBF family runs: run_episode, cc.run, the CLI, the
bench's methods and shifts, sweeps, reactive crowds, several robots, a unicycle robot."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import conformal_control as cc
from conformal_control.data.synthetic import crossing_scene
from conformal_control.experiments.bench.methods import expand_methods
from conformal_control.runs.episode import run_episode

FAST = {"sampling__n_samples": 60, "sampling__horizon": 6, "sampling__replan_every": 2}


@pytest.fixture(scope="module")
def scene():
    return crossing_scene(duration=20.0)


@pytest.mark.parametrize(
    ("family", "rule", "rule_params", "unit"),
    [
        ("mpc", "fixed_eta", {}, "m"),
        ("acp_mpc", "aci", {"alpha": 0.2, "gamma": 0.05}, "level"),
        ("ecp_mpc", "aci", {"alpha": 0.2, "gamma": 0.05}, "level"),
    ],
)
def test_run_episode_runs_every_mpc_family(scene, family, rule, rule_params, unit):
    res = run_episode(
        scene,
        family=family,
        family_params=FAST,
        rule=rule,
        rule_params=rule_params,
        max_frames=80,
        record_animation=False,
    )
    m = res.metrics
    assert res.config["engine"] == "loop"
    assert res.config["family"]["name"] == family
    assert m["n_steps"] > 0 and m["n_updates"] > 0
    assert m.unit("lambda_final") == unit
    # the family's own default loss and its counters reach the metrics
    default = {
        "mpc": "distance_shortfall",
        "acp_mpc": "plan_miscoverage",
        "ecp_mpc": "ego_miscoverage",
    }[family]
    assert res.config["loss"]["name"] == default
    assert m["n_infeasible"] >= 0 and m["fallback_share"] <= 1.0


def test_a_fixed_margin_mpc_keeps_further_away_than_none(scene):
    near = run_episode(
        scene, family="mpc", family_params=FAST, learn=False, max_frames=150, record_animation=False
    )
    far = run_episode(
        scene,
        family="mpc",
        family_params={**FAST, "margin": 1.5},
        learn=False,
        max_frames=150,
        record_animation=False,
    )
    assert far.metrics["d_min"] >= near.metrics["d_min"]


def test_the_front_door_and_a_unicycle(scene):
    res = cc.run(
        scene,
        family="mpc",
        family_params=FAST,
        dynamics="unicycle",
        dynamics_params={"v_max": 1.5, "omega_max": 1.5},
        units="si",
        epsilon=0.1,
        eta=0.2,
        max_frames=60,
    )
    assert res.config["dynamics"]["name"] == "unicycle"
    assert res.steps["x"].shape[1] == 4 and res.metrics["n_steps"] > 0
    # the unicycle starts facing its goal and never exceeds its limits
    v = np.hypot(res.steps["x"][:, 2], res.steps["x"][:, 3])
    assert v.max() <= 1.5 + 1e-9


def test_the_cbf_family_drives_a_unicycle_through_the_lookahead_point(scene):
    res = run_episode(
        scene,
        dynamics="unicycle_lookahead",
        dynamics_params={"v_max": 2.0, "omega_max": 2.0, "lookahead": 0.3},
        params={"barrier_margin": 0.3},
        max_frames=60,
        record_animation=False,
        engine="loop",
    )
    assert res.metrics["n_steps"] > 0
    assert np.isfinite(res.trajectory["x"]).all()


def test_a_reactive_crowd_with_the_mpc(scene):
    res = run_episode(
        scene,
        family="mpc",
        family_params=FAST,
        crowd="social_force",
        max_frames=60,
        record_animation=False,
    )
    assert res.config["crowd"]["crowd"] == "social_force" and res.metrics["n_steps"] > 0


def test_cli_run_family_mpc(tmp_path, capsys):
    from conformal_control.cli import main

    out = tmp_path / "run"
    assert (
        main(
            [
                "run",
                "--family",
                "mpc",
                "--family-param",
                "sampling__n_samples=40",
                "--family-param",
                "sampling__horizon=5",
                "--frames",
                "40",
                "--no-plot",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    config = json.loads((out / "config.json").read_text())
    assert config["family"]["name"] == "mpc"
    assert config["family"]["params"]["sampling__n_samples"] == 40


def test_cli_rejects_an_unknown_family_in_one_line(capsys):
    from conformal_control.cli import main

    assert main(["run", "--family", "mcp", "--frames", "5"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mcp" in err[0] and "mpc" in err[0]


def test_bench_methods_run_the_mpc_families(scene):
    for m in expand_methods(["mpc", "cc_mpc", "oracle_mpc", "acp_mpc", "ecp_mpc"]):
        kw = m.run_kwargs()
        kw["family_params"] = {**kw.get("family_params", {}), **FAST}
        res = run_episode(scene, max_frames=30, record_animation=False, **kw)
        assert res.config["family"]["name"] == kw["family"]
        assert math.isfinite(res.metrics["lambda_final"])


def test_several_robots_run_the_mpc_family(tmp_path, capsys):
    # run --robots with --family mpc: two planners swapping places on the crossing scene
    # keep their sides of the shared lines (reciprocity) and both arrive
    from conformal_control.cli import main

    out = tmp_path / "fleet"
    # (200 frames: with lambda's default ceiling, issue 30, no plan comes closer than d_c
    # and the second robot needs more than the 150 frames it took before)
    args = ["run", "--robots", "2", "--family", "mpc", "--frames", "200", "--no-plot"]
    for kv in ("sampling__n_samples=60", "sampling__horizon=6", "sampling__replan_every=2"):
        args += ["--family-param", kv]
    assert main([*args, "--out", str(out)]) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["family"]["name"] == "mpc"
    assert config["family"]["params"]["sampling__n_samples"] == 60
    assert config["reciprocity"]["modes"] == ["reciprocal", "reciprocal"]
    fleet = json.loads((out / "metrics.json").read_text())["fleet"]
    assert fleet["n_collide_robot_pairs"] == 0 and fleet["success_rate"] == 1.0
    assert fleet["d_min_robot"] >= 2 * config["params"]["si"]["robot_radius"]
    robots = json.loads((out / "metrics.json").read_text())["robots"]
    assert [r["eta"] for r in robots] == [0.2, 0.2]  # the mpc family's rule


def test_a_sweep_over_mpc_parameters_records_the_family(tmp_path):
    import csv

    from conformal_control.experiments import SweepSpec, run_sweep

    spec = SweepSpec(
        base={
            "scene": "crossing",
            "frames": 30,
            "family": "mpc",
            "family_params": {"sampling__n_samples": 40, "sampling__replan_every": 2},
            "units": "si",
        },
        grid={"family_params.sampling__horizon": [4, 6], "epsilon": [0.05, 0.2]},
    )
    runs = spec.expand()
    assert len(runs) == 4
    assert runs[0].spec.role("family")[1] == {
        "sampling__n_samples": 40,
        "sampling__replan_every": 2,
        "sampling__horizon": 4,
    }
    report = run_sweep(spec, tmp_path / "sw", "serial", plot=False, progress=False)
    assert not report.failed and len(report.ran) == 4
    with (tmp_path / "sw" / "results.csv").open() as fh:
        table = list(csv.DictReader(fh))
    assert {r["episode.family"] for r in table} == {"mpc"}
    assert {json.loads(r["episode.family_params"])["sampling__horizon"] for r in table} == {4, 6}
    assert {float(r["param.epsilon"]) for r in table} == {0.05, 0.2}
    for r in table:
        config = json.loads((tmp_path / "sw" / r["run_dir"] / "config.json").read_text())
        fam = config["family"]
        assert fam["name"] == "mpc" and fam["params"]["sampling__n_samples"] == 40
        given = json.loads(r["episode.family_params"])
        assert fam["params"]["sampling__horizon"] == given["sampling__horizon"]
        assert config["engine"] == "loop" and float(r["n_steps"]) > 0


def test_a_dotted_family_parameter_needs_a_mapping():
    from conformal_control.experiments import SweepSpec

    spec = SweepSpec(base={"scene": "crossing", "family_params": 3}, grid={"family_params.x": [1]})
    with pytest.raises(ValueError, match="'family_params' must be a mapping, got 3"):
        spec.expand()


def test_the_metrics_report_the_family_defaults_the_rule_uses(scene):
    # the scene's epsilon and eta are the CBF's; the mpc family's own apply (and are reported)
    res = run_episode(
        scene, family="mpc", family_params=FAST, max_frames=30, record_animation=False
    )
    rule = res.config["rule"]["params_si"]
    assert (rule["epsilon"], rule["eta"], rule["lambda_min"]) == (0.1, 0.2, -1.0)
    assert res.metrics["epsilon"] == 0.1 and res.metrics["eta"] == 0.2
    assert res.config["params"]["si"]["epsilon"] == 0.1
    assert scene.defaults["epsilon"] != 0.1  # the scene's value is another
    given = run_episode(
        scene,
        family="mpc",
        family_params=FAST,
        params={"epsilon": 0.3},
        units="si",
        max_frames=30,
        record_animation=False,
    )
    assert given.metrics["epsilon"] == given.config["rule"]["params_si"]["epsilon"] == 0.3


@pytest.mark.parametrize(
    ("shift", "crowd", "predictor"),
    [("delay-0.5s", "replay", "delayed"), ("nominal", "social_force", "constant_velocity")],
)
def test_the_bench_runs_the_mpc_families_under_a_shift_and_a_reactive_crowd(
    tmp_path, data_root, shift, crowd, predictor
):
    from conformal_control.core.spec import RunSpec
    from conformal_control.experiments.bench.suite import run_bench

    run = run_bench(
        tmp_path / "b",
        suite="crossings-v1",
        split="test",
        methods=["cc_mpc", "mpc"],
        grids={"mpc": [0.0]},
        shifts=[shift],
        tuned=None,
        base=RunSpec(crowd=crowd, units="si"),
        limit=1,
        executor="serial",
        data_root=str(data_root),
        progress=False,
    )
    assert run.failed == 0 and run.ran == 2
    rows = [json.loads(line) for line in (tmp_path / "b" / "results.jsonl").open()]
    assert {r["status"] for r in rows} == {"ok"}
    for r in rows:
        config = json.loads((tmp_path / "b" / r["run_dir"] / "config.json").read_text())
        assert config["family"]["name"] == "mpc"
        assert config["predictor"]["name"] == predictor
        assert config["crowd"]["crowd"] == crowd
        if predictor == "delayed":
            assert config["predictor"]["params"]["delay_s"] == 0.5
        # cc_mpc learns its distance, mpc[margin=0m] keeps lambda at 0
        learned = r["metrics"]["n_updates"] > 0
        assert learned == ("cc_mpc" in r["run_dir"])
