"""The ETH/UCY planar protocol (suite fcp-planar): tasks, metrics, time base, runner."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from conformal_control.experiments.bench import planar
from conformal_control.experiments.bench.planar import (
    COLLISION_M,
    PLANAR_METHODS,
    PUBLISHED,
    TASKS,
    PlanarTask,
    dataset_metrics,
    planar_table,
    run_scenario,
    scenario_metrics,
)


@pytest.fixture(scope="module")
def protocol(data_root: Path) -> dict:
    path = data_root / "external" / "fcp-planar" / "protocol.json"
    if not path.is_file():
        pytest.fail(f"{path} is missing (the shared data's external/ folder)", pytrace=False)
    return json.loads(path.read_text())


def test_the_suites_tasks_equal_the_published_protocol(protocol):
    assert planar.STEP_S == protocol["time_step_s"]
    assert planar.FRAMES_PER_STEP == protocol["frames_per_step"]
    assert planar.WARM_UP_STEPS == protocol["warm_up_steps"]
    assert planar.PED_RADIUS_M == protocol["pedestrian_radius_m"]
    assert {k: planar.ROBOT[k] for k in protocol["robot"]} == protocol["robot"]
    assert "<= 0.6 m" in protocol["goal_reached"] and planar.GOAL_TOLERANCE_M == 0.6
    assert f"({COLLISION_M:.3f} m)" in protocol["collision"]
    assert set(TASKS) == set(protocol["datasets"])
    for name, spec in protocol["datasets"].items():
        task = TASKS[name]
        assert spec["recording"].startswith(f"ethucy/{name}/test/{task.recording}.txt")
        assert list(task.start_timesteps) == spec["start_timesteps"]
        assert task.frame_offset == spec["frame_offset"]
        assert task.max_steps == spec["max_steps"]
        assert list(task.init_pose) == spec["init_pose"]
        assert list(task.goal) == spec["goal"]
    assert set(planar.METRICS) == set(protocol["metrics"])


def test_the_published_table_is_the_protocols(protocol):
    pub = protocol["published_table"]
    assert pub["columns"] == ["collision_rate", "infeasible_rate", "steps_to_goal", "ctrl_time_ms"]
    for ds in TASKS:
        assert {k: list(v) for k, v in PUBLISHED[ds].items()} == pub[ds]


def test_scenario_metrics_follow_their_definitions():
    steps = [{"recorded": False, "collision": True, "infeasible": True, "ctrl_ms": None}] * 15
    steps += [
        {"recorded": True, "collision": c, "infeasible": i, "ctrl_ms": ms}
        for c, i, ms in [
            (True, False, 1.0),
            (False, True, 2.0),
            (False, False, 3.0),
            (True, True, 6.0),
        ]
    ]
    m = scenario_metrics(steps, goal_step=19, max_steps=100)
    assert m["collision_rate"] == 2 / 4 and m["infeasible_rate"] == 2 / 4
    assert m["steps_to_goal"] == 19.0 and m["reached"] and m["ctrl_time_ms"] == 3.0
    miss = scenario_metrics(steps, goal_step=None, max_steps=100)
    assert miss["steps_to_goal"] == 100.0 and not miss["reached"]
    # a dataset averages its scenarios; one without a recorded step is left out; the steps
    # read "timeout" only when no scenario reached the goal
    empty = scenario_metrics(steps[:15], goal_step=None, max_steps=100)
    d = dataset_metrics([m, miss, empty], 100)
    assert d["n_scenarios"] == 2 and d["steps_to_goal"] == (19 + 100) / 2 and not d["timeout"]
    assert dataset_metrics([miss, miss], 100)["timeout"]


def write_recording(path: Path, rows: list[tuple[int, int, float, float]]) -> Path:
    path.write_text("".join(f"{f}\t{p}\t{x}\t{y}\n" for f, p, x, y in rows))
    return path


def constructed_recording(tmp_path: Path) -> Path:
    """Pedestrian 1 walks along y = 0 towards x = 0 from frame 0; pedestrian 2 appears at
    frame 200 and stands at (3, 0.5); between frames 300 and 340 nobody has a history."""
    rows = []
    for k in range(30):  # frames 0..290
        rows.append((10 * k, 1, 6.0 - 0.3 * k, 0.0))
    for k in range(20, 30):
        rows.append((10 * k, 2, 3.0, 0.5))
    for k in range(35, 80):  # frames 350..790: pedestrian 3 far away
        rows.append((10 * k, 3, 20.0, 20.0 + 0.01 * k))
    rows.sort()
    return write_recording(tmp_path / "crowds_test.txt", rows)


def test_a_constructed_episode_recomputed_from_the_raw_rows(tmp_path, monkeypatch):
    path = constructed_recording(tmp_path)
    monkeypatch.setattr(planar, "recording", lambda task, root=None: planar._recording(str(path)))
    task = PlanarTask("zara1", "crowds_test", (1,), 0, 40, (0.0, 0.0, 0.0), (4.0, 0.0))
    res = run_scenario(task, 1, PLANAR_METHODS["mpc"], "constant_velocity")
    raw = np.loadtxt(path)
    # recompute every recorded figure from the definitions and the raw file
    by_frame: dict[int, dict[int, np.ndarray]] = {}
    for f, p, x, y in raw:
        by_frame.setdefault(int(f), {})[int(p)] = np.array([x, y])
    count, recorded, coll = 0, 0, 0
    for s in res.steps:
        f = 10 * s["timestep"]
        peds = [p for p in by_frame.get(f, {}) if p in by_frame.get(f - 10, {})]
        assert peds, "a step without a pedestrian with a history was counted"
        assert s["count"] == count
        robot = np.array([s["x"], s["y"]])
        d = min(np.hypot(*(by_frame[f][p] - robot)) for p in peds)
        assert math.isclose(s["d_min"], d, rel_tol=1e-12)
        if s["status"] == "goal":
            assert count >= 15 and np.hypot(*(robot - np.array([4.0, 0.0]))) <= 0.6
            break
        assert s["recorded"] == (count >= 15)
        if count < 15:
            assert (s["x"], s["y"]) == (0.0, 0.0)
        else:
            recorded += 1
            coll += int(d < COLLISION_M)
            assert s["collision"] == (d < COLLISION_M)
        count += 1
    m = res.metrics()
    assert m["n_recorded"] == recorded > 0
    assert math.isclose(m["collision_rate"], coll / recorded)
    # time steps 30..35 (frames 300..350) have nobody with a history: skipped, not counted
    assert [s["timestep"] for s in res.steps][28:31] == [29, 36, 37]


def test_bad_method_and_dataset_names_are_one_line_errors(tmp_path):
    with pytest.raises(ValueError, match="unknown planar method") as info:
        planar.run_planar(tmp_path, methods=["cc_mcp"])
    assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match="unknown dataset"):
        planar.run_planar(tmp_path, datasets=["eth2"])


def test_a_stopped_run_resumes_keeping_only_rows_of_the_same_definition(tmp_path, monkeypatch):
    calls: list[tuple[str, int, int]] = []

    def fake(task, start, method, pred, data_root=None, seed=0):
        calls.append((method.name, seed, start))
        res = planar.ScenarioResult(task.dataset, method.name, pred, start, task.max_steps)
        res.steps = [{"recorded": True, "collision": seed == 1, "infeasible": False}]
        res.ended, res.goal_step = "max_steps", None
        return res

    monkeypatch.setattr(planar, "run_scenario", fake)
    monkeypatch.setattr(planar, "warm_up_kernels", lambda: None)
    tasks = {"zara1": dataclasses.replace(TASKS["zara1"], start_timesteps=(100, 200))}
    kw = {"methods": ["mpc", "cc_mpc"], "predictors": ["constant_velocity"], "tasks": tasks}
    first = planar.run_planar(tmp_path, seeds=[0, 1], **kw)
    assert len(calls) == 8
    # stopped after three rows, the fourth cut off mid-write
    lines = (tmp_path / "rows.jsonl").read_text().splitlines()
    (tmp_path / "rows.jsonl").unlink()
    (tmp_path / "rows.jsonl.part").write_text("\n".join(lines[:3]) + "\n" + lines[3][:20])
    calls.clear()
    seen: list[str] = []
    again = planar.run_planar(tmp_path, seeds=[0, 1], progress=seen.append, **kw)
    assert len(calls) == 5 and ("mpc", 1, 200) in calls and ("mpc", 0, 100) not in calls
    assert seen[0].startswith("resuming: 3 rows")
    assert json.dumps(again) == json.dumps(first)  # the same rows in the same order
    assert (tmp_path / "rows.jsonl").read_text().splitlines() == lines
    # another definition of cc_mpc: its rows run again, mpc's are kept
    cc = PLANAR_METHODS["cc_mpc"]
    other = dataclasses.replace(cc, rule_params={**cc.rule_params, "epsilon": 0.2})
    monkeypatch.setitem(PLANAR_METHODS, "cc_mpc", other)
    calls.clear()
    planar.run_planar(tmp_path, seeds=[0, 1], **kw)
    assert sorted({c[0] for c in calls}) == ["cc_mpc"] and len(calls) == 4
    calls.clear()
    planar.run_planar(tmp_path, seeds=[0, 1], resume=False, **kw)
    assert len(calls) == 8


def test_the_table_prints_our_rows_beside_the_published_ones():
    rows = [
        {
            "dataset": "hotel",
            "method": "cc_mpc",
            "predictor": "constant_velocity",
            "n_recorded": 50,
            "collision_rate": 0.01,
            "infeasible_rate": 0.1,
            "steps_to_goal": 70.0,
            "reached": True,
            "ctrl_time_ms": 2.0,
        },
    ]
    text, table = planar_table(rows)
    ours = [r for r in table if r["source"] == "ours"]
    assert len(ours) == 1 and ours[0]["collision_rate"] == 0.01
    assert (
        "| hotel | **cc_mpc** | ours | constant_velocity | 0.010 | 1/1 | 0.100 | 70.0 | 2.00 | 1 "
        "| ours |" in text
    )
    assert (
        "| hotel | ECP-MPC | published | Trajectron++ | 0.020 | | 0.213 | 85.7 | 50.16 | | "
        "published |" in text
    )


def test_several_seeds_show_their_mean_and_range():
    base = {
        "dataset": "zara1",
        "method": "fcp_mpc_hard_pub",
        "predictor": "recorded",
        "n_recorded": 50,
        "infeasible_rate": 0.1,
        "ctrl_time_ms": 2.0,
    }
    rows = [
        {**base, "seed": sd, "collision_rate": c, "steps_to_goal": st, "reached": st < 100}
        for sd, c, st in ((0, 0.02, 60.0), (0, 0.04, 100.0), (1, 0.10, 80.0), (1, 0.0, 70.0))
    ]
    text, table = planar_table(rows)
    ours = next(r for r in table if r["source"] == "ours")
    assert ours["n_seeds"] == 2 and ours["n_reached"] == 3 and ours["n_scenarios"] == 4
    assert math.isclose(ours["collision_rate"], (0.03 + 0.05) / 2)
    assert (ours["collision_rate_min"], ours["collision_rate_max"]) == (0.03, 0.05)
    assert (
        "| zara1 | **fcp_mpc_hard_pub (FCP-MPC (hard))** | published | recorded | "
        "0.040 (0.030-0.050) | 3/4 | 0.100 (0.100-0.100) | 77.5 (75.0-80.0) | 2.00 | 2 | ours |"
    ) in text


def small_grid(method: planar.PlanarMethod) -> planar.PlanarMethod:
    """An offline-calibrated fcp_mpc method on a 24 x 24 grid (a fast calibration)."""
    if method.calibration is None:
        return method
    return dataclasses.replace(
        method, family_params={**method.family_params, "calibration__grid_size": 24}
    )


@pytest.mark.parametrize("name", list(PLANAR_METHODS))
def test_every_method_runs_a_scenario_of_the_real_protocol(name, data_root):
    task = TASKS["hotel"]
    method = small_grid(PLANAR_METHODS[name])
    res = run_scenario(task, task.start_timesteps[0], method, data_root=data_root)
    m = res.metrics()
    assert m["n_recorded"] > 0 and 0.0 <= m["collision_rate"] <= 1.0
    assert all(s["count"] == k for k, s in enumerate(res.steps))
    if method.family in ("mpc", "acp_mpc", "ecp_mpc", "fcp_mpc", "soft_mpc"):
        assert res.stats["n_plans"] == m["n_recorded"]


def test_the_oracle_predicts_the_recorded_future(data_root):
    task = TASKS["zara1"]
    rec = planar.recording(task, data_root)
    oracle = planar.RecordingOracle(rec)
    oracle.reset()
    i = rec.sample(150, task.frame_offset)
    cols = rec.pedestrians(i)
    from conformal_control.predictors.base import PredictionQuery

    query = PredictionQuery(
        ids=rec.ids[cols], history=rec.history(i, cols), dt=0.4, horizon=12, t=0.0,
        frame=150 + task.frame_offset // 10, scene="zara1",
    )  # fmt: skip
    got = oracle.predict(query).positions
    want = rec.positions[i + 1 : i + 13][:, cols].transpose(1, 0, 2)
    np.testing.assert_array_equal(got, want)
    assert np.isfinite(got).any() and np.isnan(got).any()  # some leave within 4.8 s


def test_offline_calibration_leaves_the_scenario_window_out(data_root):
    task = TASKS["zara1"]
    pub = small_grid(PLANAR_METHODS["fcp_mpc_hard_pub"])
    ours = small_grid(PLANAR_METHODS["fcp_mpc"])
    full = planar.scenario_envelope(task, 100, pub, "constant_velocity", data_root)
    held = planar.scenario_envelope(task, 100, ours, "constant_velocity", data_root)
    rec = planar.recording(task, data_root)
    from conformal_control.experiments.bench.planar_fcp import scenario_samples

    lo, hi = scenario_samples(rec, rec.sample(100, task.frame_offset), task.max_steps)
    assert hi - lo + 1 >= task.max_steps
    n_full = [s.n_fields for s in full.steps]
    n_held = [s.n_fields for s in held.steps]
    # the window's samples (and the horizon before it) are the only difference
    window = [
        sum(1 for i in range(lo - 12, hi + 1) if rec.pedestrians(i).size and
            np.isfinite(rec.at(i + h, rec.pedestrians(i))).all(axis=1).any())
        for h in range(1, 13)
    ]  # fmt: skip
    assert [a - b for a, b in zip(n_full, n_held, strict=True)] == window
    assert full.grid == held.grid and full.grid.size == 24


def test_the_mpc_plans_against_the_recorded_csv_values_at_sample_times(data_root):
    import csv
    import gzip

    task = TASKS["zara1"]
    ts = 150
    rec = planar.recording(task, data_root)
    i = rec.sample(ts, task.frame_offset)
    cols = rec.pedestrians(i)
    pred = planar._predictor("recorded", task, data_root)
    family, _, _, _ = planar.build_method(PLANAR_METHODS["mpc"], pred)
    family.reset()
    from conformal_control.predictors.base import PredictionQuery

    family.begin_interval(
        PredictionQuery(
            ids=rec.ids[cols],
            history=rec.history(i, cols),
            dt=0.4,
            horizon=1,
            t=0.0,
            frame=ts,
            scene="zara1",
        )
    )
    planned = family.predicted_at(0.4 * np.arange(1, 13))  # (M, 12, 2)
    rows = {}
    with gzip.open(data_root / "external" / "trajectron-ethucy" / "zara1.csv.gz", "rt") as fh:
        for r in csv.DictReader(fh):
            if int(r["frame"]) == 10 * ts:
                rows[(int(r["track_id"]), int(r["step"]))] = (float(r["x"]), float(r["y"]))
    assert rows, "no recorded prediction at that frame"
    n = 0
    for a, pid in enumerate(rec.ids[cols].tolist()):
        for step in range(1, 13):
            if (pid, step) in rows:
                assert tuple(planned[a, step - 1]) == rows[(pid, step)]
                n += 1
    assert n >= 12


def test_bench_run_and_report_on_the_planar_suite(tmp_path, data_root, capsys):
    from conformal_control.cli import main

    out = tmp_path / "planar"
    args = ["bench", "run", "--suite", "fcp-planar", "--methods", "mpc,cbf_nolearn"]
    args += ["--predictor", "constant_velocity", "--datasets", "hotel", "--out", str(out)]
    args += ["--data-root", str(data_root)]
    assert main(args) == 0
    rows = planar.read_planar_rows(out)
    assert {(r["method"], r["start_timestep"]) for r in rows} == {
        (m, s) for m in ("mpc", "cbf_nolearn") for s in TASKS["hotel"].start_timesteps
    }
    config = json.loads((out / "config.json").read_text())
    assert config["suite"] == "fcp-planar" and config["protocol"]["warm_up_steps"] == 15
    capsys.readouterr()
    assert main(["bench", "report", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| hotel | **mpc** | ours | constant_velocity |" in printed
    assert (
        "| hotel | CC-MPC | published | Trajectron++ | 0.049 | | N/A | 99.3 | 1.48 | | published |"
        in printed
    )
    assert (out / "report" / "planar.csv").is_file()


def test_a_delayed_predictor_on_the_protocol(data_root):
    from conformal_control.predictors.base import PredictionQuery
    from conformal_control.predictors.shift import DelayedPredictor

    task = TASKS["zara1"]
    late = planar._predictor("constant_velocity@delay-0.8s", task, data_root)
    assert isinstance(late.predictor, DelayedPredictor) and late.predictor.delay_s == 0.8
    rec = planar.recording(task, data_root)
    i = rec.sample(150, 0)
    cols = rec.pedestrians(i)
    q = PredictionQuery(rec.ids[cols], rec.history(i, cols), 0.4, 3, 0.0, 150, "zara1")
    late.reset()
    direct = DelayedPredictor("constant_velocity", delay_s=0.8)
    direct.reset()
    np.testing.assert_array_equal(late.predict(q).positions, direct.predict(q).positions)
    assert planar.predictors_for("eth", ["recorded@delay-0.8s", "oracle"]) == [
        "recorded@delay-0.8s",
        "oracle",
    ]
    assert planar.predictors_for("univ", ["recorded@delay-0.8s"]) == []
    with pytest.raises(ValueError, match="unknown planar predictor shift") as err:
        planar._predictor("recorded@noise-1m", task, data_root)
    assert "\n" not in str(err.value)
