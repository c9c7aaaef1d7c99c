"""End to end: the CLI on the built-in scene and on real nexus_4 data."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from conformal_control.cli import main
from conformal_control.runs.episode import run_episode

METRIC_KEYS = {
    "t_goal",
    "goal_reached",
    "n_collide",
    "d_min",
    "l_avg",
    "l_avg_applied",
    "epsilon",
    "eta",
    "lambda_final",
    "n_updates",
    "n_infeasible",
    "n_fallback",
    "fallback_share",
    "identity_residual",
    "frames",
    "wall_s",
}


def read_csv(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open() as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


def test_demo_without_arguments(tmp_path: Path, capsys, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["run"]) == 0
    out = capsys.readouterr().out
    run_dirs = list((tmp_path / "runs").iterdir())
    assert len(run_dirs) == 1 and str(run_dirs[0].name) in out
    files = {p.name for p in run_dirs[0].iterdir()}
    assert {"config.json", "metrics.json", "trace.csv", "trajectory.csv", "plot.png"} <= files
    metrics = json.loads((run_dirs[0] / "metrics.json").read_text())
    assert METRIC_KEYS <= set(metrics)
    assert metrics["goal_reached"] and metrics["t_goal"] > 13.0  # 26 m at <= 2 m/s
    assert metrics["d_min"] > 0


def test_nexus4_done_when_command(tmp_path: Path, sdd_dir: Path) -> None:
    out = tmp_path / "nexus"
    argv = [
        "run",
        "--scene",
        "nexus_4",
        "--data-root",
        str(sdd_dir),
        "--predictor",
        "constant_velocity",
        "--epsilon",
        "-0.25",
        "--eta",
        "1",
        "--tau",
        "4",
        "--param",
        "a=10",
        "--param",
        "K_rep=40",
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    m = json.loads((out / "metrics.json").read_text())
    cfg = json.loads((out / "config.json").read_text())
    # figures of the prototype for this configuration: t_goal 8.3 s, no collision,
    # d_min 1.25 m, l_avg -0.234, no fallback
    assert m["goal_reached"] and 7.5 < m["t_goal"] < 9.5
    assert m["n_collide"] == 0 and m["d_min"] > 1.0
    assert m["identity_residual"] < 1e-9
    assert abs(m["l_avg"] - (-0.25)) < 0.05 and m["n_fallback"] == 0
    assert m["epsilon_attainable"] is True
    # parameters as given (paper units) and in SI
    px, fps = 0.045883871, 30.0
    assert cfg["params"]["given"]["a"] == 10 and cfg["params"]["given"]["tau"] == 4
    si = cfg["params"]["si"]
    assert si["a"] == pytest.approx(10 * fps) and si["tau"] == pytest.approx(4 / fps)
    assert si["rho0"] == pytest.approx(400 * px) and si["K_rep"] == pytest.approx(40 * px**2)
    assert si["eta"] == pytest.approx(1 * fps) and si["loss_scale"] == pytest.approx(fps)
    assert cfg["predictor"]["name"] == "constant_velocity"
    # trace: one row per update, lambda in per-frame units
    cols, rows = read_csv(out / "trace.csv")
    assert cols == ["k", "t", "lambda", "loss"] and len(rows) == m["n_updates"]
    assert float(rows[-1]["lambda"]) == pytest.approx(m["lambda_final"], abs=0.3)
    cols, rows = read_csv(out / "trajectory.csv")
    assert cols == ["frame", "t", "x", "y", "vx", "vy", "d_min"]
    assert int(rows[0]["frame"]) == 50 and float(rows[0]["t"]) == 0.0
    assert [int(r["frame"]) for r in rows] == list(range(50, 50 + len(rows)))
    assert float(rows[0]["x"]) == pytest.approx(0.95 * 1284 * px)


def test_frames_limit_and_no_learning(tmp_path: Path, sdd_dir: Path) -> None:
    out = tmp_path / "short"
    argv = [
        "run",
        "--scene",
        "nexus_4",
        "--data-root",
        str(sdd_dir),
        "--frames",
        "60",
        "--no-learning",
        "--out",
        str(out),
        "--no-plot",
    ]
    assert main(argv) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["frames"] == 60 and not m["goal_reached"] and m["t_goal"] is None
    assert m["l_avg"] is None and m["lambda_final"] == 0.0 and m["identity_residual"] is None


def test_unattainable_epsilon_is_reported(tmp_path: Path, sdd_dir: Path, capsys) -> None:
    out = tmp_path / "floor"
    argv = [
        "run",
        "--scene",
        "nexus_4",
        "--data-root",
        str(sdd_dir),
        "--epsilon",
        "-0.25",
        "--eta",
        "1",
        "--tau",
        "4",
        "--param",
        "a=1",
        "--param",
        "lambda_min=-inf",  # the default lambda floor opened: lambda may sink below the floor
        "--frames",
        "120",
        "--out",
        str(out),
        "--no-plot",
    ]
    assert main(argv) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["epsilon_attainable"] is False
    assert m["lambda_floor"] == pytest.approx(-0.5)  # -a h_max per frame
    assert m["fallback_share"] > 0.5 and m["n_fallback"] == m["n_infeasible"] > 0
    assert "not attainable" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--tau", "-1"], "tau must be a finite number > 0"),
        (["--eta", "-0.5"], "eta must be a finite number >= 0"),
        (["--epsilon", "0.7"], "epsilon must lie in"),
        (["--tau", "0.05"], "whole number of frames"),
        (["--param", "a=-3"], "a must be a finite number > 0"),
        (["--param", "bogus=1"], "unknown parameter"),
        (["--param", "a"], "KEY=VALUE"),
        (["--predictor", "crystal_ball"], "unknown predictor"),
        (["--scene", "nexus_4", "--data-root", "/nonexistent"], "fetch-data"),
    ],
)
def test_nonsensical_input_gives_one_clear_error(argv, message, tmp_path, capsys) -> None:
    assert main(["run", "--out", str(tmp_path / "x"), *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err


def test_run_episode_leaves_the_scene_unchanged(crossing):
    """Parameter overrides reach the run through a copy; the caller's scene is not mutated."""
    before = (crossing.robot_radius, crossing.agent_radius, crossing.goal_radius, crossing.v_max)
    res = run_episode(
        crossing,
        "constant_velocity",
        {"robot_radius": 0.3, "agent_radius": 0.25, "v_max": 1.2},
        max_frames=60,
    )
    after = (crossing.robot_radius, crossing.agent_radius, crossing.goal_radius, crossing.v_max)
    assert after == before
    assert res.config["params"]["si"]["robot_radius"] == pytest.approx(0.3)


def test_collisions_counted_with_the_resolved_radii(nexus4, tmp_path: Path) -> None:
    """n_collide, the animation record and the plot use robot_radius + agent_radius as
    resolved for the run, not the scene's defaults (a radius sweep must count right)."""
    res = run_episode(nexus4, "constant_velocity", {"robot_radius": 3.0}, max_frames=120)
    d_c = 3.0 + nexus4.agent_radius
    d = res.trajectory["d_min"]
    expected = int((d < d_c).sum())
    assert expected > 0  # the enlarged robot does come within d_c of someone
    assert res.metrics["n_collide"] == expected
    assert res.scene.collision_distance == pytest.approx(d_c)
    assert res.animation is not None
    assert float(res.animation["collision_distance"]) == pytest.approx(d_c)
    assert nexus4.collision_distance == pytest.approx(1.0)  # caller's scene untouched


def test_every_ethucy_recording_runs_from_the_command_line(
    data_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The issue's first hour: `run --scene ethucy:crowds_zara01` had no default task, no
    option took metres, a robots file and ``cc.run(start_m=...)`` were refused. Now: the
    default task, metres with their unit on the command line, a robots file in metres,
    and the same task from Python (``start=``, ``start_m=``, ``RunSpec.start_m``)."""
    import numpy as np

    import conformal_control as cc
    from conformal_control.data import load_scene
    from conformal_control.data.ethucy import ETHUCY_RECORDINGS

    base = ["--data-root", str(data_root), "--frames", "20", "-q", "--no-plot"]
    for rec in ETHUCY_RECORDINGS:
        out = tmp_path / rec
        assert main(["run", "--scene", f"ethucy:{rec}", *base, "--out", str(out)]) == 0, rec
        scene = json.loads((out / "config.json").read_text())["scene"]
        default = load_scene(f"ethucy:{rec}", data_root)
        np.testing.assert_allclose(scene["start_m"], default.start)
    out = tmp_path / "metres"
    argv = ["run", "--scene", "ethucy:crowds_zara01", "--start", "1m,5m", "--goal", "14m,5m"]
    assert main([*argv, *base, "--out", str(out)]) == 0
    scene = json.loads((out / "config.json").read_text())["scene"]
    assert scene["start_m"] == [1.0, 5.0] and scene["goals_m"] == [[14.0, 5.0]]
    robots = tmp_path / "robots.json"
    robots.write_text(
        json.dumps(
            {
                "units": "m",
                "robots": [
                    {"start": [1, 5], "goal": [14, 5]},
                    {"start": [14, 6.5], "goal": [1, 6.5]},
                ],
            }
        )
    )
    out = tmp_path / "fleet"
    argv = ["run", "--scene", "ethucy:crowds_zara01", "--robots-file", str(robots)]
    assert main([*argv, *base, "--out", str(out)]) == 0
    fleet = json.loads((out / "config.json").read_text())
    assert [r["start_m"] for r in fleet["robots"]] == [[1.0, 5.0], [14.0, 6.5]]
    capsys.readouterr()
    runs = [
        cc.run("ethucy:zara1", data_root=data_root, start="1m,5m", goal="14m,5m"),
        cc.run("ethucy:zara1", data_root=data_root, start_m=(1, 5), goals_m=[(14, 5)]),
        cc.run("ethucy:zara1", cc.RunSpec(start_m=(1, 5), goals_m=(14, 5)), data_root=data_root),
    ]
    for res in runs:
        assert res.config["scene"]["start_m"] == [1.0, 5.0]
        assert res.config["scene"]["goals_m"] == [[14.0, 5.0]]
    assert runs[1].metrics["t_goal"] == runs[0].metrics["t_goal"] == runs[2].metrics["t_goal"]
    assert cc.RunSpec.from_dict(runs[2].config["spec"]).start_m == (1.0, 5.0)
