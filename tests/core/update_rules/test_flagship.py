"""Update rules, lambda_safe and the guarantee monitor through the flagship's episode and CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conformal_control.cli import main
from conformal_control.core.update_rules import DtACIRule, PIDRule
from conformal_control.runs.episode import run_episode


@pytest.mark.parametrize("rule", ["fixed_eta", "decaying_eta", "pid", "dtaci"])
def test_episode_runs_every_rule_and_records_it(crossing, rule: str) -> None:
    params = {"gammas": "1,3"} if rule == "dtaci" else {}
    res = run_episode(
        crossing, "constant_velocity", {"epsilon": -0.1, "eta": 3.0}, rule=rule, rule_params=params
    )
    m = res.metrics
    assert m["rule"] == rule and m["n_updates"] > 10
    assert res.config["rule"]["name"] == rule
    assert m["guarantee"] == {"fixed_eta": "identity", "decaying_eta": "step_identity"}.get(
        rule, m["guarantee"]
    )
    if rule in ("fixed_eta", "decaying_eta"):
        assert m["identity_residual"] < 1e-9
    if rule == "dtaci":
        assert isinstance(res.loop.monitor.rule, DtACIRule)
        assert res.loop.monitor.rule.n_counterfactual_ == m["n_updates"]


def test_rule_params_are_converted_from_scene_units(nexus4) -> None:
    res = run_episode(
        nexus4,
        "constant_velocity",
        {"epsilon": -0.25, "eta": 1.0},
        rule="pid",
        rule_params={"K_I": 0.5},
        max_frames=60,
    )
    rule = res.loop.monitor.rule
    assert isinstance(rule, PIDRule)
    assert rule.K_I == pytest.approx(0.5 * nexus4.fps)  # per frame -> per second
    assert rule.eta == pytest.approx(1.0 * nexus4.fps)
    assert res.config["rule"]["params_given"] == {"K_I": 0.5}


def test_unknown_rule_param_is_a_clear_error(crossing) -> None:
    with pytest.raises(ValueError, match="has no parameter"):
        run_episode(crossing, "constant_velocity", rule="pid", rule_params={"bogus": 1})
    with pytest.raises(ValueError, match="unknown rule"):
        run_episode(crossing, "constant_velocity", rule="nope")


def test_cli_rule_and_lambda_safe_reach_metrics_and_plot(tmp_path: Path, capsys) -> None:
    out = tmp_path / "run"
    rc = main(
        [
            "run",
            "--epsilon",
            "-0.1",
            "--eta",
            "3",
            "--lambda-safe",
            "-2",
            "--rule",
            "fixed_eta",
            "--rule-param",
            "lambda_min=-6",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["lambda_safe"] == -2 and m["guarantee"] == "identity"
    assert m["theorem2_bound"] == pytest.approx(-0.1 + (0 + 2 + 3) / (3 * m["n_updates"]))
    assert m["theorem2_bound_met"] is True and m["theorem2_assumption"] is True
    # lambda never went down to lambda_safe, so nothing tested the theorem's premise:
    # the bound is met but the monitor does not say "holds"
    assert m["theorem2_premise_tested"] == 0
    assert m["theorem2_verdict"] == "premise_untested" and m["theorem2_holds"] is False
    assert (out / "guarantee.png").stat().st_size > 10_000
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["rule"]["params_given"] == {"lambda_min": -6}


def test_compare_rules_example_small(capsys, data_root) -> None:
    import runpy

    path = Path(__file__).resolve().parents[3] / "examples" / "compare_rules.py"
    main_fn = runpy.run_path(str(path), run_name="example")["main"]
    rows = main_fn(
        [
            "--data-root",
            str(data_root / "sdd"),
            "--epsilons",
            "-0.25",
            "--frames",
            "90",
            "--settings",
            "a = 10 (as the published code ran)",
        ]
    )
    out = capsys.readouterr().out
    assert "| -0.25 | fixed_eta (paper) |" in out and "| -0.25 | dtaci (gammas 0.1..3) |" in out
    by = {r["label"]: r for r in rows}
    assert set(by) == {
        "noLearn",
        "fixed_eta (paper)",
        "decaying_eta (power 1/2)",
        "pid (K_I 0.5, C_sat 1)",
        "dtaci (gammas 0.1..3)",
    }
    assert by["fixed_eta (paper)"]["identity_residual"] < 1e-9
    assert by["fixed_eta (paper)"]["theorem2_bound_met"] is True
    assert by["noLearn"]["lambda_final"] == 0.0
