"""fcp-planar-dense: the shipped tasks regenerated from the data, the split, the report."""

from __future__ import annotations

import json
from importlib import resources

import numpy as np

from conformal_control.experiments.bench import planar, planar_dense
from conformal_control.experiments.bench.planar_dense import (
    dense_report,
    dense_tasks,
    dump_manifest,
    generate_manifest,
    load_manifest,
)
from conformal_control.experiments.bench.planar_fcp import scenario_samples
from conformal_control.experiments.bench.stats import bootstrap_mean, paired_comparison


def test_the_shipped_tasks_are_regenerated_byte_for_byte(data_root):
    shipped = (
        resources.files("conformal_control.experiments.bench")
        / "planar_manifests"
        / "fcp-planar-dense.json"
    ).read_bytes()
    assert dump_manifest(generate_manifest(data_root)).encode() == shipped


def test_at_least_100_test_tasks_split_by_time(data_root):
    man = load_manifest()
    test = dense_tasks("test")
    assert sum(len(t.start_timesteps) for t in test.values()) >= 100
    assert set(test) == set(planar.TASKS)
    for name, spec in man["datasets"].items():
        task = planar.TASKS[name]
        # the published protocol's geometry, start poses and goals
        assert (spec["max_steps"], spec["frame_offset"]) == (task.max_steps, task.frame_offset)
        assert spec["init_pose"] == list(task.init_pose) and spec["goal"] == list(task.goal)
        assert all(s % planar_dense.STRIDE == 0 for s in spec["dev"] + spec["test"])
        if name in planar_dense.TEST_ONLY:
            assert not spec["dev"]
            continue
        assert all(s >= spec["boundary_timestep"] for s in spec["test"])
        # a dev scenario's whole window (its steps, then 12 of truth) ends before the boundary
        rec = planar.recording(task, data_root)
        boundary = rec.sample(spec["boundary_timestep"], task.frame_offset)
        for s in spec["dev"]:
            _, last = scenario_samples(rec, rec.sample(s, task.frame_offset), task.max_steps)
            assert last + 12 < boundary
    assert "univ" not in dense_tasks("dev")


def test_the_report_gives_intervals_and_paired_comparisons():
    rng = np.random.default_rng(0)
    rows = []
    for start in range(0, 200, 20):
        for method, shift in (("mpc", 0.0), ("cc_mpc", -0.02), ("oracle_mpc", -0.04)):
            for seed in (0, 1):
                rows.append(
                    {
                        "dataset": "zara1",
                        "method": method,
                        "predictor": "oracle" if method == "oracle_mpc" else "recorded",
                        "seed": seed,
                        "start_timestep": start,
                        "n_recorded": 50,
                        "collision_rate": max(0.0, 0.05 + shift + rng.normal(0, 0.01)),
                        "infeasible_rate": 0.1,
                        "steps_to_goal": 60.0 + seed,
                        "reached": True,
                    }
                )
    text, table = dense_report(rows)
    cc = next(r for r in table if r["method"] == "cc_mpc")
    per_start = [
        np.mean(
            [
                r["collision_rate"]
                for r in rows
                if r["method"] == "cc_mpc" and r["start_timestep"] == s
            ]
        )
        for s in range(0, 200, 20)
    ]
    want = bootstrap_mean(per_start)
    assert (cc["collision_rate"], cc["collision_rate_low"], cc["collision_rate_high"]) == (
        want.mean,
        want.low,
        want.high,
    )
    assert cc["n"] == 10 and cc["steps_to_goal"] == 60.5
    base = [
        np.mean(
            [r["collision_rate"] for r in rows if r["method"] == "mpc" and r["start_timestep"] == s]
        )
        for s in range(0, 200, 20)
    ]
    c = paired_comparison(per_start, base, metric="collision_rate")
    assert (
        f"| zara1 | cc_mpc | recorded | mpc | collision_rate | {c.wins}/{c.losses}/{c.ties} |"
        in text
    )
    # the oracle ran under its own predictor's name, and is still paired
    assert "| zara1 | cc_mpc | recorded | oracle_mpc | collision_rate |" in text


def test_bench_run_and_report_on_the_dense_suite(tmp_path, data_root, capsys):
    from conformal_control.cli import main

    out = tmp_path / "dense"
    args = ["bench", "run", "--suite", "fcp-planar-dense", "--split", "test"]
    args += ["--methods", "blind_mpc", "--predictor", "constant_velocity", "--datasets", "univ"]
    args += ["--seeds", "0,1", "--out", str(out), "--data-root", str(data_root)]
    assert main(args) == 0
    rows = planar.read_planar_rows(out)
    starts = dense_tasks("test")["univ"].start_timesteps
    assert sorted((r["seed"], r["start_timestep"]) for r in rows) == sorted(
        (s, t) for s in (0, 1) for t in starts
    )
    config = json.loads((out / "config.json").read_text())
    assert config["suite"] == "fcp-planar-dense" and config["seeds"] == [0, 1]
    assert config["protocol"]["datasets"]["univ"]["start_timesteps"] == list(starts)
    capsys.readouterr()
    assert main(["bench", "report", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"| univ | blind_mpc | constant_velocity | {len(starts)} |" in printed
    assert (out / "report" / "dense.csv").is_file()


def test_fcp_calibrates_once_per_part_on_the_other_part(data_root):
    import dataclasses

    from conformal_control.experiments.bench.planar import PLANAR_METHODS, scenario_envelope

    method = PLANAR_METHODS["fcp_mpc"]
    method = dataclasses.replace(
        method, family_params={**method.family_params, "calibration__grid_size": 16}
    )
    for split in ("test", "dev"):
        task = dense_tasks(split)["zara1"]
        first, second = task.start_timesteps[:2]
        env = scenario_envelope(task, first, method, "constant_velocity", data_root)
        assert scenario_envelope(task, second, method, "constant_velocity", data_root) is env
        rec = planar.recording(task, data_root)
        b = rec.sample(load_manifest()["datasets"]["zara1"]["boundary_timestep"], 0)
        # the calibration times: the other part, without the 12 steps that reach across
        times = range(1, b - 12) if split == "test" else range(b, rec.positions.shape[0])
        for h in (1, 12):
            n = sum(
                1
                for i in times
                if rec.pedestrians(i).size
                and np.isfinite(rec.at(i + h, rec.pedestrians(i))).all(axis=1).any()
            )
            assert env.steps[h - 1].n_fields == n


def test_the_report_pools_every_datasets_scenarios():
    rows = [
        {
            "dataset": ds,
            "method": m,
            "predictor": "constant_velocity",
            "seed": 0,
            "start_timestep": st,
            "n_recorded": 40,
            "collision_rate": c,
            "infeasible_rate": 0.0,
            "steps_to_goal": 50.0,
            "reached": True,
        }
        for ds, st, m, c in (
            ("eth", 20, "mpc", 0.1),
            ("hotel", 20, "mpc", 0.3),  # the same start time step in another dataset
            ("eth", 20, "cc_mpc", 0.0),
            ("hotel", 20, "cc_mpc", 0.1),
        )
    ]
    text, table = dense_report(rows)
    pooled = {r["method"]: r for r in table if r["dataset"] == "all"}
    assert pooled["mpc"]["n"] == 2 and np.isclose(pooled["mpc"]["collision_rate"], 0.2)
    assert np.isclose(pooled["cc_mpc"]["collision_rate"], 0.05)
    assert "| all | cc_mpc | constant_velocity | mpc | collision_rate | 2/0/0 |" in text
