"""bench run / report end to end on a few scenarios; one scenario per method family."""

from __future__ import annotations

from pathlib import Path

import pytest

from conformal_control.cli import main
from conformal_control.experiments.bench.methods import (
    DEFAULT_METHODS,
    METHOD_FAMILIES,
    available,
    expand_methods,
)
from conformal_control.experiments.bench.suite import bench_configs, read_rows, run_bench


def test_every_method_family_is_available_and_runs_one_scenario(data_root: Path) -> None:
    """One scenario end to end for each method family, through the public builder."""
    from conformal_control.data import load_scene
    from conformal_control.runs.episode import run_episode

    scene = load_scene("scenario:crossings-v1/sdd-little-0-w004", data_root)
    limit = scene.meta["max_frames"]
    seen = {}
    for m in expand_methods(METHOD_FAMILIES):
        assert available(m) is None, f"{m.name}: {available(m)}"
        if m.family in seen:
            continue
        res = run_episode(scene, **m.run_kwargs(), max_frames=limit, record_animation=False)
        seen[m.family] = res
        assert res.metrics["frames"] <= limit + 1
        assert res.config["safety_filter"]["name"] == m.roles.get("safety_filter", "exact2d")
    assert set(seen) == set(METHOD_FAMILIES)
    # the families really differ in what they run
    assert seen["oracle"].config["predictor"]["name"] == "oracle"
    assert seen["oracle_mpc"].config["predictor"]["name"] == "oracle"
    assert seen["oracle_mpc"].config["family"]["name"] == "mpc"
    assert seen["acp"].config["family"]["name"] == "acp"
    assert seen["conformal"].config["family"]["name"] == "cbf"
    assert seen["inflated"].config["barrier"]["params"]["d_c"] == pytest.approx(1.0 + 0.25)
    assert seen["fallback:relax"].config["fallback"] == "relax"
    assert seen["conformal_agent_shortfall"].config["loss"]["name"] == "cbf_shortfall"
    assert seen["conformal_agent_floorstep"].config["params"]["given"]["lambda_floor_step"] > 0
    assert seen["nolearn"].metrics["n_updates"] == 0 and seen["conformal"].metrics["n_updates"] > 0


def test_configs_carry_the_scenario_and_method(data_root: Path) -> None:
    methods = expand_methods(["nolearn", "conformal"])
    cfgs = bench_configs("crossings-v1", "dev", methods, limit=2)
    assert len(cfgs) == 2 * len(methods)
    assert len({c.key for c in cfgs}) == len(cfgs)
    c = cfgs[1]
    assert c.scene.startswith("scenario:crossings-v1/") and c.spec.units == "si"
    assert c.meta["method"] == methods[1].name and c.meta["split"] == "dev"
    with pytest.raises(ValueError, match="unknown method 'conformall'; did you mean"):
        expand_methods(["conformall"])


def test_bench_run_resume_and_report(
    tmp_path: Path, data_root: Path, capsys, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "b"
    argv = [
        "bench", "run", "--split", "dev", "--limit", "2", "--methods", "nolearn,conformal",
        "--grid", "conformal=-0.1", "--executor", "serial", "--out", str(out),
        "--data-root", str(data_root), "--progress", "off",
    ]  # fmt: skip
    assert main(argv) == 0
    assert "4 episodes: 0 already done, 4 ran (0 failed)" in capsys.readouterr().out
    rows = read_rows(out)
    assert len(rows) == 4 and {r["method"] for r in rows} == {"nolearn", "conformal[eps=-0.1]"}
    for r in rows:
        assert r["status"] == "ok" and r["scenario"] and r["time_limit"] > 0
        assert r["success"] == (bool(r["goal_reached"]) and r["n_collide"] == 0)
    assert main(argv) == 0  # resumed: nothing to do
    assert "4 already done, 0 ran" in capsys.readouterr().out
    rerun = run_bench(
        out,
        split="dev",
        methods=["nolearn", "conformal"],
        grids={"conformal": [-0.1]},
        executor="serial",
        limit=2,
        data_root=str(data_root),
        progress=False,
    )
    assert (rerun.skipped, rerun.ran) == (4, 0)
    from conformal_control.experiments.results import ResultsStore

    parsed: list[int] = []
    real_parse = ResultsStore._parse

    def counting(lines, first, out_list):  # type: ignore[no-untyped-def]
        parsed.append(sum(bool(x.strip()) for x in lines))
        return real_parse(lines, first, out_list)

    monkeypatch.setattr(ResultsStore, "_parse", staticmethod(counting))
    assert main(["bench", "report", str(out)]) == 0
    assert parsed == [4]  # the report parses the journal's 4 lines once
    report = out / "report"
    assert "| `conformal[eps=-0.1]` | 2 |" in (report / "leaderboard.md").read_text()
    assert (report / "frontier.png").stat().st_size > 10_000


def test_default_methods_are_known() -> None:
    assert set(DEFAULT_METHODS) <= set(METHOD_FAMILIES)


def test_tune_run_report_end_to_end(tmp_path: Path, data_root: Path, capsys) -> None:
    """bench tune on 10 dev scenarios, bench run with its values on 10 test scenarios under
    two shifts, bench report: every piece carries where it came from."""
    import json

    tune_dir, run_dir = tmp_path / "tune", tmp_path / "run"
    common = ["--limit", "10", "--data-root", str(data_root), "--progress", "off"]
    assert main(["bench", "tune", "--methods", "fixed,conformal", "--out", str(tune_dir),
                 *common]) == 0  # fmt: skip
    printed = capsys.readouterr().out
    tuned = json.loads((tune_dir / "tuned.json").read_text())
    assert tuned["split"] == "dev" and tuned["n_scenarios"] == 10
    assert set(tuned["families"]) == {"fixed", "conformal"}
    fixed = tuned["families"]["fixed"]
    assert len(fixed["candidates"]) == 5 and f"fixed: {fixed['label']}" in printed
    assert main(["bench", "run", "--methods", "nolearn,fixed,conformal", "--shift",
                 "nominal,delay-0.5s", "--tuned", str(tune_dir), "--out", str(run_dir),
                 *common]) == 0  # fmt: skip
    bench = json.loads((run_dir / "bench.json").read_text())
    assert bench["tuned"]["source"] == str(tune_dir / "tuned.json")
    assert bench["tuned"]["values"]["fixed"] == fixed["setting"]
    assert bench["shifts"] == ["nominal", "delay-0.5s"] and bench["wall_s"] > 0
    rows = read_rows(run_dir)
    # 10 scenarios x 2 shifts x (nolearn + 5 fixed + 1 conformal)
    assert len(rows) == 140
    assert {r["shift"] for r in rows} == {"nominal", "delay-0.5s"}
    assert {r["tuned_from"] for r in rows} == {str(tune_dir / "tuned.json")}
    capsys.readouterr()
    assert main(["bench", "report", str(run_dir), "--tune-folder", str(tune_dir)]) == 0
    out = capsys.readouterr().out
    report = run_dir / "report"
    md = (report / "leaderboard.md").read_text()
    assert "## Shift `nominal`" in md and "## Shift `delay-0.5s`" in md
    assert "(tuned on dev)" in md and "a reference that peeks at it" in md
    assert f"Paired with `fixed[lambda={fixed['setting']:g}/s]`" in md
    assert "Run time: `bench tune`" in out and "`delay-0.5s`: `conformal[eps=" in out
    assert (report / "frontier-delay-0.5s.png").stat().st_size > 10_000
    strata = (report / "strata.md").read_text()
    assert "### recording" in strata and "### density" in strata and "### speed" in strata
    assert "| delay-0.5s | `nolearn` |" in (report / "collisions.md").read_text()


def test_the_base_run_gives_predictor_crowd_seed_and_si_parameters_only() -> None:
    from conformal_control.core.exceptions import InputError
    from conformal_control.core.spec import RunSpec
    from conformal_control.experiments.bench.suite import bench_base

    assert bench_base(None) == ("constant_velocity", {}, "replay", {}, 0, {})
    base = RunSpec(
        params={"K_rep": 0.3},
        predictor=("constant_velocity", {"window": 3}),
        crowd=("social_force", {"tau": 0.4}),
        seed=7,
        units="si",
    )
    assert bench_base(base) == (
        "constant_velocity",
        {"window": 3},
        "social_force",
        {"tau": 0.4},
        7,
        {"K_rep": 0.3},
    )
    with pytest.raises(InputError, match="drop rule, learn"):
        bench_base(RunSpec(rule="pid", learn=False))
    with pytest.raises(InputError, match="SI"):
        bench_base(RunSpec(params={"K_rep": 0.3}))


def _tuned_file(tmp_path, split):
    import json

    data = {"suite": "crossings-v2", "families": {"fixed": {"setting": -5}}}
    if split is not None:
        data["split"] = split
    path = tmp_path / f"tuned-{split}.json"
    path.write_text(json.dumps(data))
    return path


def test_a_tuned_file_must_say_its_split(tmp_path) -> None:
    from conformal_control.experiments.bench.suite import load_tuned

    with pytest.raises(ValueError, match="does not say which split its values were tuned on"):
        load_tuned(_tuned_file(tmp_path, None), "crossings-v2")
    assert load_tuned(_tuned_file(tmp_path, "test"), "crossings-v2").data["split"] == "test"


@pytest.mark.parametrize(
    ("tuned_on", "reported", "warned"),
    [("test", "test", True), ("dev", None, True), ("dev", "test", False), ("test", "dev", False)],
)
def test_bench_run_warns_when_the_tuned_split_is_reported(
    tmp_path, tuned_on, reported, warned
) -> None:
    import warnings

    from conformal_control.core.exceptions import TunedOnReportedSplitWarning
    from conformal_control.experiments.bench.suite import check_tuned_split, load_tuned

    tuned = load_tuned(_tuned_file(tmp_path, tuned_on), "crossings-v2")
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        check_tuned_split(tuned, reported)
    got = [w for w in seen if issubclass(w.category, TunedOnReportedSplitWarning)]
    assert bool(got) == warned
    if warned:
        assert f"chosen on the {tuned_on} split" in str(got[0].message)
