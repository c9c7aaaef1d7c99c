"""Second domains through the same loop: the factory and online conformal discs."""

from __future__ import annotations

import math
import runpy
from pathlib import Path

import numpy as np
import pytest

from conformal_control.core.losses import BallRecord, conformal_radius
from conformal_control.core.update_rules import ACIRule, DtACIRule, FixedEtaRule
from conformal_control.families.domains.factory import FactoryEnvironment, defect_rate, run_factory
from conformal_control.families.domains.intervals import load_series, run_intervals

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"


def example(name: str):
    return runpy.run_path(str(EXAMPLES / name), run_name="example")["main"]


def test_factory_example_small(capsys) -> None:
    rows = example("factory.py")(["--runs", "3", "--T", "100"])
    out = capsys.readouterr().out
    assert "| fixed_eta (paper) | identity |" in out
    by = {r["rule"]: r for r in rows}
    assert set(by) == {"fixed_eta (paper)", "decaying_eta", "pid", "dtaci"}
    paper = by["fixed_eta (paper)"]
    assert paper["theorem2_held"] == "3/3"
    assert paper["theorem2_bound"] == pytest.approx(0.05 + 0.2 / (0.1 * 100))
    assert paper["l_avg_max"] <= paper["theorem2_bound"]
    assert by["decaying_eta"]["long_run_held"] == "3/3"


def test_factory_defects_are_binomial_at_the_speed_used() -> None:
    assert defect_rate(-1.0, 0.75) == 0.0 and defect_rate(0.1, 0.75) == pytest.approx(0.075)
    assert defect_rate(10.0, 0.75) == 1.0
    # frozen speed 0.4 -> defect rate 0.3: the average loss estimates it
    _, fig = run_factory(FixedEtaRule(epsilon=0.05, eta=0.0, lambda_init=0.4), T=2000, p=10)
    assert fig["speed_avg"] == pytest.approx(0.4)
    assert abs(fig["l_avg"] - 0.3) < 4 * math.sqrt(0.3 * 0.7 / 20000)
    with pytest.raises(ValueError, match="integers >= 1"):
        FactoryEnvironment(T=0).reset()


def test_online_intervals_example_small(capsys, data_root) -> None:
    rows = example("online_intervals.py")(
        ["--scenes", "zara1", "--max-steps", "600", "--data-root", str(data_root)]
    )
    out = capsys.readouterr().out
    assert "| zara1 | aci (gamma=0.005) | 600 |" in out
    for r in rows:
        assert r["n"] == 600
        assert 0.8 < r["coverage"] < 0.97, r
        assert 0.0 < r["radius_median"] < 2.0


def test_series_is_time_ordered_with_valid_histories(data_root) -> None:
    steps = load_series("zara1", data_root=data_root, history=8, max_steps=300)
    frames = [s.frame for s in steps]
    assert frames == sorted(frames)
    for s in steps:
        assert s.history.shape == (8, 2) and np.isfinite(s.history[-1]).all()
        assert np.isfinite(s.target).all()
        valid = np.isfinite(s.history).all(axis=1)
        assert np.all(np.diff(valid.astype(int)) >= 0)  # NaN only at the front


def test_dtaci_intervals_use_counterfactual_coverage(data_root) -> None:
    steps = load_series("zara1", data_root=data_root, max_steps=400)
    rule = DtACIRule(epsilon=0.1, gammas=(0.005, 0.05))
    _, fig = run_intervals(rule, steps)
    assert rule.n_counterfactual_ == 400
    assert 0.8 < fig["coverage"] < 0.97


def test_conformal_radius_and_ball() -> None:
    scores = np.arange(1.0, 10.0)  # 9 scores
    assert conformal_radius(scores, 0.0) == math.inf
    assert conformal_radius(scores, 1.0) == -math.inf
    assert conformal_radius(scores, 0.1) == 9.0  # ceil(10 * 0.9) = 9th
    assert conformal_radius(scores, 0.5) == 5.0
    assert conformal_radius(scores, 0.05) == math.inf  # ceil(10 * 0.95) = 10 > 9
    assert conformal_radius(scores, -0.3, "radius") == 0.3
    assert conformal_radius(scores, 0.3, "radius") == -math.inf
    with pytest.raises(ValueError, match="parametrisation"):
        conformal_radius(scores, 0.1, "bogus")
    ball = BallRecord(np.zeros(2), scores)
    assert ball.covers(np.array([3.0, 4.0]), 0.5) and not ball.covers(np.array([3.0, 4.1]), 0.5)
    assert ball.covers(np.array([100.0, 0.0]), -0.1)  # lambda <= 0: everything


def test_aci_on_a_series_tracks_alpha(data_root) -> None:
    steps = load_series("eth", data_root=data_root, max_steps=1500)
    _, fig = run_intervals(ACIRule(alpha=0.2, gamma=0.02), steps)
    assert abs(fig["miscoverage"] - 0.2) <= fig["long_run_bound"]
    assert fig["long_run_holds"] is True
