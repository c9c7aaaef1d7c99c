"""The multi-robot benchmark: layouts, the suite, the runner, the paired report."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conformal_control.data.suites import dump_manifest, load_suite
from conformal_control.experiments.bench.multi import (
    LAYOUTS,
    entry_tasks,
    is_multi_folder,
    layout_tasks,
    load_multi_suite,
    make_multi_manifest,
    multi_tables,
    read_multi_rows,
    run_multi_bench,
    write_multi_report,
)
from conformal_control.runs.fleet import check_tasks

P, Q = (0.0, 0.0), (10.0, 0.0)


def _sep(points: np.ndarray) -> float:
    d = np.hypot(*(points[:, None] - points[None]).transpose(2, 0, 1))
    d[np.diag_indices(len(points))] = np.inf
    return float(d.min())


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("n", [2, 5, 10, 20])
def test_layouts_give_tasks_a_fleet_can_do(layout, n):
    s, g = layout_tasks(layout, n, P, Q, spacing=2.5, seed=3)
    assert s.shape == (n, 2) and len(g) == n
    ends = np.array([gi[-1] for gi in g])
    assert _sep(s) >= 2.5 - 1e-9 and _sep(ends) >= 2.5 - 1e-9
    check_tasks(s, g, robot_radius=0.5)  # no error
    lengths = np.hypot(*(ends - s).T)
    assert (lengths >= 5.0 - 1e-9).all()


def test_swap_puts_two_robots_head_on_on_every_line():
    s, g = layout_tasks("swap", 6, P, Q, spacing=2.5)
    ends = np.array([gi[-1] for gi in g])
    # robots 0-2 go +x, 3-5 go -x along the same three lines
    np.testing.assert_allclose(ends[:3, 0] - s[:3, 0], 10.0)
    np.testing.assert_allclose(ends[3:, 0] - s[3:, 0], -10.0)
    np.testing.assert_allclose(s[:3, 1], s[3:, 1])
    np.testing.assert_allclose(s[:3, 1], [-2.5, 0.0, 2.5])


def test_cross_is_two_perpendicular_streams_and_lanes_alternate():
    s, g = layout_tasks("cross", 4, P, Q, spacing=2.5)
    d = np.array([gi[-1] for gi in g]) - s
    assert np.allclose(d[:2, 1], 0.0) and np.allclose(d[2:, 0], 0.0)
    s, g = layout_tasks("lanes", 4, P, Q, spacing=2.5)
    d = np.array([gi[-1] for gi in g]) - s
    np.testing.assert_allclose(np.sign(d[:, 0]), [1, -1, 1, -1])
    np.testing.assert_allclose(s[:, 1], [-3.75, -1.25, 1.25, 3.75])


def test_random_layout_is_seeded():
    a = layout_tasks("random", 8, P, Q, seed=1)
    b = layout_tasks("random", 8, P, Q, seed=1)
    c = layout_tasks("random", 8, P, Q, seed=2)
    np.testing.assert_array_equal(a[0], b[0])
    assert not np.array_equal(a[0], c[0])


def test_impossible_layouts_are_one_line_errors():
    for args, kw, msg in (
        (("spiral", 4, P, Q), {}, "unknown layout"),
        (("swap", 1, P, Q), {}, "2 to 20 robots"),
        (("swap", 21, P, Q), {}, "2 to 20 robots"),
        (("swap", 4, P, P), {}, "start and a goal apart"),
        (("swap", 4, P, Q), {"spacing": 0.0}, "spacing must be"),
    ):
        with pytest.raises(ValueError, match=msg) as err:
            layout_tasks(*args, **kw)
        assert "\n" not in str(err.value)


def test_the_shipped_suite_is_the_generator_s_output():
    suite = load_multi_suite()
    assert suite.base == "crossings-v2"
    text = dump_manifest(make_multi_manifest(suite.base))
    shipped = (
        __import__("pathlib").Path(__file__).resolve().parents[3]
        / "conformal_control/experiments/bench/multi_manifests/multi-crossings-v1.json"
    )
    assert shipped.read_text() == text
    base = load_suite(suite.base)
    for e in suite.entries:
        sc = base.scenario(e.scenario)
        assert sc.split == e.split and sc.recording == e.recording
    # every layout of every chosen scenario, both splits
    assert {e.layout for e in suite.entries} == set(LAYOUTS)
    assert {e.split for e in suite.entries} == {"dev", "test"}


def test_entry_tasks_follow_the_scenario(tmp_path):
    suite = load_multi_suite()
    e = suite.entries_for("test")[0]
    base, s, _ = entry_tasks(suite, e, 5)
    assert s.shape == (5, 2)
    mid = 0.5 * (np.array(base.start_m) + np.array(base.goal_m))
    assert np.linalg.norm(s.mean(0) - mid) < base.length_m


def test_bad_manifests_are_one_line_errors(tmp_path):
    f = tmp_path / "m.json"
    for content, msg in (
        ("{oops", "not valid JSON"),
        (json.dumps({"schema": "other"}), "not a multi-robot suite"),
        (json.dumps({"schema": "conformal-control/multi-suite"}), "missing key"),
    ):
        f.write_text(content)
        with pytest.raises(ValueError, match=msg):
            load_multi_suite(path=f)
    m = make_multi_manifest()
    m["entries"][0]["layout"] = "spiral"
    f.write_text(json.dumps(m))
    with pytest.raises(ValueError, match="layout 'spiral'"):
        load_multi_suite(path=f)


def _row(entry, rec, pairs, goal, ped=0, layout="swap", robots=5, avoidable=0, near=0):
    return {
        "key": f"{entry}|{rec}",
        "entry": entry,
        "layout": layout,
        "split": "test",
        "robots": robots,
        "method": "nolearn",
        "shift": "nominal",
        "reciprocity": rec,
        "recording": "ethucy:students001" if entry == "e2" else "ethucy:biwi_eth",
        "goal_rate": goal,
        "n_collide_robot_pairs": pairs,
        "n_collide_pedestrian": ped,
        "n_collide_pedestrian_avoidable": avoidable,
        "n_collide_pedestrian_robot_near": near,
        "makespan": 10.0,
        "n_deadlocked": 0,
        "cpu_s": 1.0,
    }


def test_the_paired_reduction_is_computed_from_the_pairs():
    rows = []
    for k, (none, rec) in enumerate([(10, 0), (0, 0), (30, 4), (20, 0)]):
        rows.append(_row(f"e{k}", "none", none, 0.8))
        rows.append(_row(f"e{k}", "reciprocal", rec, 1.0))
    tables = multi_tables(rows)
    (allrow,) = [r for r in tables["paired"] if r["layout"] == "all"]
    point, lo, hi = allrow["reduction"]
    assert point == pytest.approx(1 - 4 / 60)
    assert lo <= point <= hi <= 1.0
    assert allrow["goal_rate_difference"].mean == pytest.approx(0.2)
    assert allrow["pairs"] == 4
    fleet = {r["reciprocity"]: r for r in tables["fleet"]}
    assert fleet["none"]["robot_pair_frames"].mean == pytest.approx(15.0)
    assert fleet["reciprocal"]["episodes_robot_collision"].mean == pytest.approx(0.25)


def test_fleets_are_compared_with_their_robots_alone():
    # fleet / solo pedestrian frames summed over the pairs, per arm; an entry without its
    # solo run is left out; the differences are fleet minus solo
    rows = []
    for k, (solo, none, rec) in enumerate([(10, 12, 30), (0, 0, 5), (20, 18, 25)]):
        rows.append(_row(f"e{k}", "solo", 0, 1.0, ped=solo, avoidable=solo // 2))
        rows.append(_row(f"e{k}", "none", 2, 0.8, ped=none, near=none // 2))
        rows.append(_row(f"e{k}", "reciprocal", 0, 0.9, ped=rec, avoidable=rec, near=rec))
    rows.append(_row("e9", "reciprocal", 0, 0.9, ped=1000))  # no solo run: not paired
    by = {r["reciprocity"]: r for r in multi_tables(rows)["solo"] if r["recording"] == "all"}
    assert set(by) == {"none", "reciprocal"}
    rec = by["reciprocal"]
    assert rec["pairs"] == 3 and rec["pedestrian_frames_solo"] == 30
    assert rec["pedestrian_frames_fleet"] == 60 and rec["avoidable_fleet"] == 60
    assert rec["avoidable_solo"] == 15 and rec["robot_near_fleet"] == 60
    point, lo, hi = rec["ratio"]
    assert point == pytest.approx(2.0) and lo <= point <= hi
    assert rec["goal_rate_difference"].mean == pytest.approx(-0.1)
    assert by["none"]["ratio"][0] == pytest.approx(1.0)
    assert by["none"]["robot_pair_frames_fleet"] == 6 and by["none"]["robot_near_fleet"] == 15
    # the rows' order does not move an interval
    again = {
        r["reciprocity"]: r for r in multi_tables(rows[::-1])["solo"] if r["recording"] == "all"
    }
    assert again["reciprocal"]["ratio"] == rec["ratio"]
    per = [r for r in multi_tables(rows)["solo"] if r["recording"] == "ethucy:students001"]
    (s1,) = [r for r in per if r["reciprocity"] == "reciprocal"]
    assert s1["pedestrian_frames_fleet"] == 25 and s1["pedestrian_frames_solo"] == 20


def test_run_report_and_resume(tmp_path, data_root):
    out = tmp_path / "bench"
    kw = dict(robots=(3,), split="test", limit=1, methods=("nolearn",), data_root=str(data_root))
    first = run_multi_bench(out, workers=1, **kw)
    assert first.ran == 3 and first.failed == 0
    again = run_multi_bench(out, workers=1, **kw)
    assert again.skipped == 3 and again.ran == 0
    assert is_multi_folder(out)
    rows = read_multi_rows(out)
    assert {r["reciprocity"] for r in rows} == {"solo", "none", "reciprocal"}
    for r in rows:
        assert r["robots"] == 3 and 0.0 <= r["goal_rate"] <= 1.0
        assert r["n_collide_pedestrian_avoidable"] <= r["n_collide_pedestrian"]
        assert r["n_collide_pedestrian_robot_near"] <= r["n_collide_pedestrian"]
    (solo,) = [r for r in rows if r["reciprocity"] == "solo"]
    assert solo["n_collide_robot_pairs"] == 0 and solo["n_collide_pedestrian_robot_near"] == 0
    page = write_multi_report(rows, tmp_path / "report")
    text = page.read_text()
    assert "Reciprocal against none" in text and "| 3 | nolearn | nominal |" in text
    assert "Fleets against their robots alone" in text and "| solo |" in text


def test_the_solo_baseline_is_each_robot_run_alone(tmp_path, data_root):
    # the solo arm's figures, recomputed from the run directories of each robot of the
    # entry run alone on its own task (run_multi with that one task, saved)
    from conformal_control.experiments.bench.multi import entry_scene
    from conformal_control.experiments.bench.suite import plan_methods
    from conformal_control.runs.fleet import run_multi

    out = tmp_path / "bench"
    res = run_multi_bench(
        out, robots=(3,), split="test", limit=1, methods=("nolearn",), reciprocity=("solo",),
        data_root=str(data_root), workers=1,
    )  # fmt: skip
    assert res.ran == 1
    (row,) = read_multi_rows(out)
    suite = load_multi_suite()
    entry = suite.entries_for("test")[0]
    base, starts, goals = entry_tasks(suite, entry, 3)
    scene = entry_scene(base, suite.time_factor, str(data_root))
    (method,) = plan_methods(["nolearn"])
    ped, reached, avoidable = 0, 0, 0
    for i in range(3):
        run = run_multi(
            scene, starts=starts[i : i + 1], goals=[goals[i]], max_frames=scene.meta["max_frames"],
            seed=i, **method.run_kwargs(),
        )  # fmt: skip
        d = run.save(tmp_path / f"robot{i}") / "robots" / "robot_00"
        traj = np.genfromtxt(d / "trajectory.csv", delimiter=",", names=True)
        ped += int(np.sum(traj["d_min"] < scene.collision_distance))
        m = json.loads((d / "metrics.json").read_text())
        reached += bool(m["goal_reached"])
        avoidable += m["n_collide_avoidable"]
    assert row["n_collide_pedestrian"] == ped
    assert row["n_collide_pedestrian_avoidable"] == avoidable
    assert row["goal_rate"] == pytest.approx(reached / 3)


def test_the_base_run_gives_predictor_seed_and_the_robots_information():
    from conformal_control.core.exceptions import InputError
    from conformal_control.core.spec import Robots, RunSpec
    from conformal_control.experiments.bench.multi import multi_bench_base

    assert multi_bench_base(None) == ("constant_velocity", 0, "plan", "pedestrians", {})
    base = RunSpec(
        predictor="oracle",
        seed=3,
        robots=Robots(information="position", lambda_scope="both", sidestep=0.0),
    )
    assert multi_bench_base(base) == ("oracle", 3, "position", "both", {"sidestep": 0.0})
    with pytest.raises(InputError, match=r"drop learn, robots\.layout"):
        multi_bench_base(RunSpec(learn=False, robots=Robots(layout="antipodal")))
    # a floor margin other than the default is an option of the reciprocal runs
    fm = multi_bench_base(RunSpec(robots=Robots(floor_margin=0.0)))
    assert fm == ("constant_velocity", 0, "plan", "pedestrians", {"floor_margin": 0.0})


def test_bench_run_robots_set_gives_the_reciprocal_options_and_refuses_the_rest(
    tmp_path, monkeypatch, capsys
):
    # `bench run --robots M --set KEY=VALUE` used to drop --set without a word
    import conformal_control.experiments.bench.multi as bm
    from conformal_control.cli import main

    seen = {}

    class Done:
        failed, unfinished = 0, 0

        def summary(self):
            return "done"

    def fake(out, **kw):
        seen.update(multi_bench_base=bm.multi_bench_base(kw["base"]))
        return Done()

    monkeypatch.setattr(bm, "run_multi_bench", fake)
    argv = ["bench", "run", "--robots", "3", "--out", str(tmp_path / "b")]
    assert main([*argv, "--set", "floor_margin=0", "--set", "priority=robots"]) == 0
    assert seen["multi_bench_base"][4] == {"floor_margin": 0.0, "priority": "robots"}
    capsys.readouterr()
    assert main([*argv, "--set", "K_rep=0.3"]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "floor_margin" in err and "drop params" in err, err
    assert main([*argv, "--set", "floor_margin=-1"]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "floor_margin must be a finite distance" in err
    # which floor cores hold is a reciprocal runs' option too
    assert main([*argv, "--set", "floor_core=none"]) == 0
    assert seen["multi_bench_base"][4] == {"floor_core": "none"}
    capsys.readouterr()
    assert main([*argv, "--set", "floor_core=sometimes"]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "floor_core must be one of always, inside" in err


def test_the_paired_reduction_does_not_depend_on_the_order_of_the_rows():
    rows = []
    for k, (none, rec) in enumerate([(10, 0), (0, 3), (30, 4), (20, 0), (5, 5), (8, 1)]):
        rows.append(_row(f"e{k}", "none", none, 0.8))
        rows.append(_row(f"e{k}", "reciprocal", rec, 1.0))
    first = multi_tables(rows)["paired"]
    for seed in range(3):
        order = np.random.default_rng(seed).permutation(len(rows))
        assert multi_tables([rows[i] for i in order])["paired"] == first


def test_a_worker_killed_leaves_fleet_episodes_unfinished_not_failed(
    tmp_path, data_root, monkeypatch, capsys
):
    """A pool worker killed used to end the command (BrokenProcessPool); its episodes are
    now left unfinished, the summary says so, and the report says so on its first line."""
    import conformal_control.experiments.bench.multi as multi

    monkeypatch.setattr(multi, "_run_one", _dies_when_reciprocal)
    out = tmp_path / "bench"
    kw = dict(robots=(3,), split="test", limit=2, methods=("nolearn",), data_root=str(data_root))
    res = run_multi_bench(out, workers=2, **kw)
    assert res.failed == 0 and res.unfinished >= 1
    assert "left unfinished, not failed" in res.summary()
    assert "BrokenProcessPool" in res.summary()
    planned, unfinished = multi.multi_unfinished(out)
    assert planned == res.n_runs and unfinished == res.unfinished
    assert multi.report_command(out, tmp_path / "report") == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith(f"**INCOMPLETE: {unfinished} of the {planned} episodes")


def _dies_when_reciprocal(run, suite_path, data_root):
    """A stand-in for a fleet episode whose worker dies on the reciprocal runs."""
    import os

    if run.reciprocity == "reciprocal":
        os._exit(3)  # the worker dies with this run
    return {
        **_row(run.entry.id, run.reciprocity, 0, 1.0, robots=run.n_robots),
        "key": run.key,
        "status": "ok",
        "elapsed_s": 0.0,
    }
