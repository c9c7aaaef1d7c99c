"""`conformal-control reproduce`: the paper's configurations, checks, tables and figures."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from conformal_control.cli import main
from conformal_control.experiments.reproduce import PAPER_TABLES, auto_executor, plan

#: ``conformal-control reproduce all --frames 90 --executor serial`` on SDD at 68fa01c (the
#: commit before the edge rule), wall time and run folders left out
PAPER_90 = Path(__file__).parent / "paper_90_frames"


def read(path: Path) -> list[dict[str, str]]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


def test_plan_has_the_papers_configurations() -> None:
    rows = plan(["table1", "table2"], predictor="darts", data_root="/d")
    assert len(rows) == 2 * 7 * 2
    t1 = [r for r in rows if r.table.name == "table1"]
    for r in t1:
        p = r.config.spec.params
        assert r.config.scene == "gates_1"
        assert (p["K_acc"], p["K_rep"], p["K_att"], p["rho0"], p["tau"]) == (2, 20, 1, 400, 12)
        assert p["a"] == {"printed": 0.1, "published": 10.0}[r.variant]
        assert p["loss_scale"] == 1.0
        if r.row.learn:
            assert p["eta"] == 100.0 and r.config.spec.role_name("predictor") == "darts"
    eps = sorted({r.config.spec.params["epsilon"] for r in t1 if r.row.learn})
    assert eps == [-0.4, -0.2, 0.0, 0.2, 0.4]
    gt = [r for r in rows if r.row.oracle]
    assert len(gt) == 4 and all(
        r.config.spec.role_name("predictor") == "oracle" and not r.config.spec.learn for r in gt
    )
    nolearn = [r for r in rows if not r.row.learn and not r.row.oracle]
    assert len(nolearn) == 6 and all(
        r.config.spec.role_name("predictor") == "darts" for r in nolearn
    )
    t2 = [r for r in rows if r.table.name == "table2" and r.variant == "printed"]
    assert [
        (r.config.spec.params["tau"], r.config.spec.params.get("eta"), r.config.spec.learn)
        for r in t2
    ] == [
        (4, 0.1, True),
        (4, 1.0, True),
        (4, None, False),
        (8, 0.1, True),
        (8, 1.0, True),
        (8, None, False),
        (4, None, False),
    ]
    assert all(
        r.config.spec.params["epsilon"] == -0.25 and r.config.spec.params["a"] == 1 for r in t2
    )
    assert len({r.key for r in rows}) == len(rows)  # every row is its own run
    # the paper's printed values ride along
    assert PAPER_TABLES["table2"].rows[1].paper == {
        "t_goal": 9.1,
        "n_collide": 2,
        "d_min": 0.8881,
        "l_avg": -0.2415,
    }
    forms = plan(["forms"])
    assert {r.config.scene for r in forms} == {"nexus_4:raw", "nexus_4:trajnet"}
    with pytest.raises(ValueError, match="unknown target"):
        plan(["table3"])


def test_reproduce_short_window(tmp_path: Path, sdd_dir: Path, capsys) -> None:
    out = tmp_path / "rep"
    argv = ["reproduce", "all", "--data-root", str(sdd_dir), "--frames", "90", "--out", str(out)]
    assert main([*argv, "--executor", "serial", "--no-figures"]) == 0
    printed = capsys.readouterr().out
    assert "42 runs (0 reused, 42 ran, 0 failed)" in printed
    assert "update identity holds" in printed and "use the true future" in printed
    for name in ("table1", "table2", "forms"):
        assert (out / f"{name}.md").exists()
    t1 = read(out / "table1.csv")
    assert len(t1) == 14
    learning = [r for r in t1 if r["learn"] == "True"]
    assert len(learning) == 10
    for r in learning:  # the update identity holds whatever the predictor
        assert r["identity_ok"] == "True" and float(r["identity_residual"]) < 1e-9
        assert float(r["abs_lavg_minus_eps"]) == pytest.approx(
            abs(float(r["l_avg"]) - float(r["epsilon"]))
        )
    gt = [r for r in t1 if r["row"] == "gt/noLearn"]
    assert [r["predictor"] for r in gt] == ["oracle", "oracle"]
    assert all(r["oracle_ok"] == "True" and float(r["oracle_max_abs_gap"]) < 1e-9 for r in gt)
    assert {r["paper_t_goal"] for r in t1 if r["row"] == "eps=0.4"} == {"14.63"}
    # the run behind a gt row really replayed the true future with lambda fixed at 0
    cfg = json.loads((Path(gt[0]["run_dir"]) / "config.json").read_text())
    assert cfg["predictor"]["name"] == "oracle" and cfg["learning"] is False
    md = (out / "table2.md").read_text()
    assert "## printed" in md and "## published" in md and "(0.8881)" in md
    forms = read(out / "forms.csv")
    assert {r["scene"] for r in forms} == {"nexus_4:raw", "nexus_4:trajnet"}
    stats = json.loads((out / "forms_data.json").read_text())
    assert stats["raw"]["tracks"] > 0 and stats["trajnet"]["tracks"] > 0
    assert 0.5 < stats["share_matched_1m"] <= 1 and 0 <= stats["median_match_m"] < 0.5
    summary = json.loads((out / "summary.json").read_text())
    assert summary["identity_ok"] and summary["oracle_ok"] and summary["failed"] == 0
    assert summary["max_abs_lavg_minus_eps_eta100"] is not None
    # the paper stays the paper: Algorithm 1 as published (edge="paper", issue 30), the
    # tables equal, cell for cell, those of 68fa01c (before the edge rule), wall time and
    # run folders aside (their run keys hash the configuration, which now says edge)
    for name in ("table1", "table2", "forms"):
        ours = [
            {k: v for k, v in r.items() if k not in ("wall_s", "run_key", "run_dir")}
            for r in read(out / f"{name}.csv")
        ]
        assert ours == read(PAPER_90 / f"{name}.csv"), name
    # a rerun reuses every run and draws the figures
    assert main(["reproduce", "table2", *argv[2:], "--executor", "serial"]) == 0
    assert "14 runs (14 reused, 0 ran" in capsys.readouterr().out
    figs = {p.name for p in (out / "figures").iterdir()}
    assert {
        "table2-printed-paths.png",
        "table2-published-lambda-loss.png",
        "table2-lavg-vs-epsilon.png",
    } <= figs
    assert "figures/table2-published-paths.png" in (out / "table2.md").read_text()
    # one variant only
    one = tmp_path / "one"
    assert (
        main(
            [
                "reproduce",
                "table2",
                *argv[2:-1],
                str(one),
                "--variant",
                "published",
                "--executor",
                "serial",
                "--no-figures",
            ]
        )
        == 0
    )
    assert "7 runs (0 reused, 7 ran, 0 failed)" in capsys.readouterr().out
    assert {r["variant"] for r in read(one / "table2.csv")} == {"published"}


def test_auto_executor_runs_fast_predictors_in_process() -> None:
    """reproduce's default executor: serial for fast predictors, a process pool else."""
    from conformal_control.core import registry

    assert all(
        registry.get("predictor", n).capabilities.batchable
        for n in ("constant_velocity", "oracle", "var")
    )
    assert auto_executor([r.config for r in plan(["table2"])]) == "serial"
    assert auto_executor([r.config for r in plan(["table2"], predictor="var")]) == "serial"
    # the oracle rows stay, but one slow predictor sends the whole plan to the pool
    assert auto_executor([r.config for r in plan(["table2"], predictor="kalman")]) == "process"


def test_unknown_predictor_is_a_clear_error(tmp_path: Path, capsys) -> None:
    assert main(["reproduce", "table2", "--predictor", "nosuch", "--out", str(tmp_path)]) == 2
    assert "unknown predictor 'nosuch'" in capsys.readouterr().err
    assert not (tmp_path / "sweep").exists()
