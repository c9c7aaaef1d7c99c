"""bench run / report end to end on a few scenarios; one scenario per method family."""

from __future__ import annotations

from pathlib import Path

import pytest

from conformal_control.bench.methods import (
    DEFAULT_METHODS,
    METHOD_FAMILIES,
    available,
    expand_methods,
)
from conformal_control.bench.runner import bench_configs, read_rows, run_bench
from conformal_control.cli import main


def test_every_method_family_is_available_and_runs_one_scenario(data_root: Path) -> None:
    """One scenario end to end for each method family, through the public builder."""
    from conformal_control.data import load_scene
    from conformal_control.sim import run_episode

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
    assert seen["acp"].config["decision_family"]["name"] == "acp"
    assert seen["conformal"].config["decision_family"]["name"] == "cbf"
    assert seen["inflated"].config["barrier"]["params"]["d_c"] == pytest.approx(1.0 + 0.25)
    assert seen["fallback:relax"].config["fallback"] == "relax"
    assert seen["nolearn"].metrics["n_updates"] == 0 and seen["conformal"].metrics["n_updates"] > 0


def test_configs_carry_the_scenario_and_method(data_root: Path) -> None:
    methods = expand_methods(["nolearn", "conformal"])
    cfgs = bench_configs("crossings-v1", "dev", methods, limit=2)
    assert len(cfgs) == 2 * len(methods)
    assert len({c.key for c in cfgs}) == len(cfgs)
    c = cfgs[1]
    assert c.scene.startswith("scenario:crossings-v1/") and c.episode["units"] == "si"
    assert c.meta["method"] == methods[1].name and c.meta["split"] == "dev"
    with pytest.raises(ValueError, match="unknown method 'conformall'; did you mean"):
        expand_methods(["conformall"])


def test_bench_run_resume_and_report(tmp_path: Path, data_root: Path, capsys) -> None:
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
    assert main(["bench", "report", str(out)]) == 0
    report = out / "report"
    assert "| `conformal[eps=-0.1]` | 2 |" in (report / "leaderboard.md").read_text()
    assert (report / "frontier.png").stat().st_size > 10_000


def test_default_methods_are_known() -> None:
    assert set(DEFAULT_METHODS) <= set(METHOD_FAMILIES)
