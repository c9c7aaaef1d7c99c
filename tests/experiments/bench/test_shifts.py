"""The shift table, methods as data, the tuning rule, and bench folders."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conformal_control.cli import main
from conformal_control.experiments.bench import shifts as shifts_module
from conformal_control.experiments.bench.methods import (
    FAMILIES,
    Family,
    expand_methods,
    register_family,
)
from conformal_control.experiments.bench.shifts import SHIFTS, get_shift, parse_shifts
from conformal_control.experiments.bench.suite import (
    _BenchLock,
    bench_configs,
    plan_methods,
    read_bench,
)
from conformal_control.experiments.bench.tune import RULE, choose


def test_every_shift_is_documented_in_the_table():
    doc = shifts_module.__doc__ or ""
    for name in SHIFTS:
        assert f"``{name}``" in doc, name
    assert parse_shifts(None) == [SHIFTS["nominal"]]
    assert [s.name for s in parse_shifts("delay-0.5s, frozen,delay-0.5s")] == [
        "delay-0.5s",
        "frozen",
    ]


def test_a_bad_shift_name_is_a_one_line_error(capsys, tmp_path):
    with pytest.raises(ValueError, match=r"unknown shift 'delay-0.5'; did you mean 'delay-0.5s'"):
        get_shift("delay-0.5")
    rc = main(["bench", "run", "--shift", "nominal,delai-1s", "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "unknown shift 'delai-1s'" in err
    assert not (tmp_path / "b").exists()


def test_shifts_wrap_the_method_predictor_and_carry_into_the_rows():
    methods = expand_methods(["nolearn", "oracle"])
    cfgs = bench_configs("crossings-v2", "test", methods, limit=2, shifts=["nominal", "delay-0.5s"])
    assert len(cfgs) == 2 * 2 * 2 and len({c.key for c in cfgs}) == len(cfgs)
    by = {(c.meta["shift"], c.meta["method"]): c for c in cfgs}
    assert by[("nominal", "nolearn")].spec.role("predictor") == ("constant_velocity", {})
    d = by[("delay-0.5s", "nolearn")]
    assert d.spec.role("predictor") == (
        "delayed",
        {"delay_s": 0.5, "predictor": "constant_velocity"},
    )
    assert by[("delay-0.5s", "oracle")].spec.role("predictor")[1]["predictor"] == "oracle"
    assert d.label.startswith("delay-0.5s-")


def test_learned_runs_only_on_the_recordings_it_covers():
    cfgs = bench_configs(
        "crossings-v2", "test", expand_methods(["nolearn"]), shifts=["learned"],
        data_root="/data",
    )  # fmt: skip
    recs = {c.meta["recording"] for c in cfgs}
    assert recs == {"ethucy:biwi_eth:corrected", "ethucy:crowds_zara01"}
    name, pp = cfgs[0].spec.role("predictor")
    assert name == "recorded" and pp["data_root"] == "/data"
    assert pp["path"]["biwi_eth:corrected"]["step_s"] == pytest.approx(2 / 3)


def test_a_new_method_is_one_entry(data_root, tmp_path):
    fam = Family(
        "conformal_slow",
        "the paper's rule with a tenth of its learning rate",
        setting="params.epsilon",
        label="eps={:g}",
        settings=(-0.1,),
        params={"eta": 3.0},
    )
    register_family(fam)
    try:
        (m,) = expand_methods(["conformal_slow"])
        assert m.name == "conformal_slow[eps=-0.1]" and m.params["eta"] == 3.0
        assert main([
            "bench", "run", "--methods", "conformal_slow", "--split", "dev", "--limit", "1",
            "--out", str(tmp_path / "b"), "--data-root", str(data_root), "--progress", "off",
        ]) == 0  # fmt: skip
        with pytest.raises(ValueError, match="exists already"):
            register_family(fam)
    finally:
        FAMILIES.pop("conformal_slow")
    with pytest.raises(ValueError, match="setting must be params"):
        Family("x", "y", setting="lambda_init")


def test_every_family_is_data():
    for fam in FAMILIES.values():
        for v in fam.settings:
            m = fam.method(v)
            assert m.family == fam.name
            if fam.setting:
                where, *path = fam.setting.split(".")
                holder = {"params": m.params, "rule_params": m.rule_params}.get(where)
                assert holder is None or holder[path[-1]] == v


def test_tuned_values_plan_the_methods():
    from conformal_control.experiments.bench.suite import Tuned

    tuned = Tuned({"fixed": -10.0, "conformal": -0.1}, "x", "0", {})
    names = [m.name for m in plan_methods(["nolearn", "fixed", "conformal"], tuned)]
    # the reference family runs its whole grid; the others their tuned setting
    assert names == [
        "nolearn",
        *[f"fixed[lambda={v:g}/s]" for v in FAMILIES["fixed"].tune],
        "conformal[eps=-0.1]",
    ]
    # a --grid entry wins
    names = [m.name for m in plan_methods(["conformal"], tuned, {"conformal": [0.0]})]
    assert names == ["conformal[eps=0]"]


def _row(setting, success, collide, t=5.0):
    return {
        "family": "conformal",
        "setting": setting,
        "status": "ok",
        "success": success,
        "goal_reached": True,
        "n_collide": collide,
        "t_goal": t,
        "time_limit": 10.0,
    }


def test_the_tuning_rule():
    rows = [
        _row("eps=-0.1", True, 0), _row("eps=-0.1", False, 3),
        _row("eps=0", True, 0), _row("eps=0", False, 1),
        _row("eps=-0.2", False, 0), _row("eps=-0.2", False, 0),
    ]  # fmt: skip
    value, cands = choose(rows, "conformal", [-0.2, -0.1, 0.0])
    # -0.1 and 0 tie on success (50 %); 0 has fewer collision frames
    assert value == 0.0
    assert [c["n"] for c in cands] == [2, 2, 2]
    assert [c["success"] for c in cands] == [0.0, 0.5, 0.5]
    # equal success and collisions: the shorter time to goal wins, then the grid's order
    tied = [_row("eps=-0.1", True, 0, t=6.0), _row("eps=0", True, 0, t=4.0)]
    assert choose(tied, "conformal", [-0.1, 0.0])[0] == 0.0
    same = [_row("eps=-0.1", True, 0), _row("eps=0", True, 0)]
    assert choose(same, "conformal", [0.0, -0.1])[0] == 0.0
    assert "ties: fewer collision frames" in RULE


def test_a_second_run_into_a_busy_folder_is_refused(tmp_path, capsys):
    out = tmp_path / "b"
    out.mkdir()
    (out / "bench.json").write_text('{"mine": 1}\n')
    with _BenchLock(out):
        rc = main(["bench", "run", "--limit", "1", "--out", str(out), "--methods", "nolearn"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1
    assert "is in use by another bench run (PID" in err
    assert json.loads((out / "bench.json").read_text()) == {"mine": 1}


def test_runs_of_another_condition_are_refused(tmp_path, data_root, capsys):
    out = tmp_path / "b"
    base = ["bench", "run", "--split", "dev", "--limit", "1", "--methods", "nolearn",
            "--out", str(out), "--data-root", str(data_root), "--progress", "off"]  # fmt: skip
    assert main(base) == 0
    before = (out / "bench.json").read_text()
    capsys.readouterr()
    other = tmp_path / "tuned.json"
    other.write_text(
        '{"suite": "crossings-v2", "split": "dev", "families": {"fixed": {"setting": -7.0}}}'
    )
    for extra in (["--crowd", "social_force"], ["--set", "K_rep=0.3"], ["--tuned", str(other)]):
        rc = main(base + extra)
        err = capsys.readouterr().err
        assert rc == 2 and "holds benchmark runs of another condition" in err, extra
        assert err.count("\n") == 1
        assert (out / "bench.json").read_text() == before
    # the same condition with more methods is fine, and recorded
    assert main([*base[:7], "nolearn,inflated", *base[8:]]) == 0
    assert {m["family"] for m in read_bench(out)["methods"]} == {"nolearn", "inflated"}


def test_report_refuses_pooled_conditions(tmp_path: Path):
    from conformal_control.experiments.bench.report import write_report

    rows = [
        {"scenario": "s1", "method": "nolearn", "family": "nolearn", "status": "ok",
         "success": True, "goal_reached": True, "n_collide": 0, "time_limit": 10.0,
         "t_goal": 5.0}
        for _ in range(3)
    ]  # fmt: skip
    with pytest.raises(ValueError, match="hold 3 runs of method nolearn on scenario s1"):
        write_report(rows, tmp_path)


def test_tune_refuses_families_without_a_grid(tmp_path):
    from conformal_control.experiments.bench.tune import tune

    with pytest.raises(ValueError, match="method 'nolearn' has no setting to tune"):
        tune(tmp_path / "t", families=["nolearn"])
    with pytest.raises(ValueError, match="unknown method 'fixd'"):
        tune(tmp_path / "t", families=["fixd"])
    assert not (tmp_path / "t").exists()


def test_a_method_redefined_under_its_name_is_refused(tmp_path, data_root, capsys):
    """A method of the same name with other parameters would pool two definitions."""
    out = tmp_path / "b"
    base = ["bench", "run", "--split", "dev", "--limit", "1", "--methods", "nolearn",
            "--out", str(out), "--data-root", str(data_root), "--progress", "off"]  # fmt: skip
    assert main(base) == 0
    desc = json.loads((out / "bench.json").read_text())
    (entry,) = desc["methods"]
    entry["params"] = {**entry["params"], "eta": 3.0}  # as an older definition had it
    (out / "bench.json").write_text(json.dumps(desc))
    before = (out / "bench.json").read_text()
    capsys.readouterr()
    assert main(base) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "method nolearn is defined differently" in err and "params" in err
    assert (out / "bench.json").read_text() == before


def test_report_names_what_differs_between_pooled_runs(tmp_path: Path):
    """Rows of two conditions in one folder (written by an older version, or by hand):
    the report refuses them and names the configuration that differs."""
    from conformal_control.experiments.bench.report import write_report

    def row(crowd, k_rep):
        return {"scenario": "s1", "method": "nolearn", "family": "nolearn", "status": "ok",
                "success": True, "goal_reached": True, "n_collide": 0, "time_limit": 10.0,
                "t_goal": 5.0, "crowd": crowd, "param.K_rep": k_rep, "seed": 0,
                "d_min": 1.5, "wall_s": 0.1}  # fmt: skip

    rows = [row("replay", 0.2), row("social_force", 0.2), row("replay", 0.3)]
    with pytest.raises(ValueError) as info:
        write_report(rows, tmp_path)
    msg = str(info.value)
    assert "\n" not in msg
    assert "crowd ('replay', 'social_force')" in msg and "param.K_rep (0.2, 0.3)" in msg
    assert "d_min" not in msg and "wall_s" not in msg  # outcomes, not configuration


def test_the_tuned_values_ship_with_the_package():
    """`bench run` uses the dev-tuned values shipped for the default suite."""
    from conformal_control.experiments.bench.suite import DEFAULT_SUITE, load_tuned
    from conformal_control.experiments.bench.tune import DEFAULT_TUNED, RULE

    tuned = load_tuned("default", DEFAULT_SUITE)
    assert tuned is not None, "conformal_control/experiments/bench/tuned/crossings-v2.json missing"
    assert tuned.source == "shipped:conformal_control/experiments/bench/tuned/crossings-v2.json"
    assert tuned.data["split"] == "dev" and tuned.data["rule"] == RULE
    # the default families, and families tuned since with `bench tune --methods`
    assert set(DEFAULT_TUNED) <= set(tuned.values)
    for fam, value in tuned.values.items():
        assert value in FAMILIES[fam].tune
        # the chosen setting is the one the rule picks from the stored candidates
        cands = tuned.data["families"][fam]["candidates"]
        best = min(
            range(len(cands)),
            key=lambda i: (-cands[i]["success"], cands[i]["collision_frames"], cands[i]["time"], i),
        )
        assert cands[best]["setting"] == value
    assert load_tuned("default", "crossings-v1") is None  # nothing shipped for v1
