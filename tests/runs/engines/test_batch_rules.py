"""The batch engine with any update rule, the safety losses and any predictor: the metrics
(and every interval's row) of run_episode, field by field."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.core import registry
from conformal_control.data import load_scene
from conformal_control.families.cbf.controller import PredictorError
from conformal_control.families.cbf.loss import CBFGapLoss
from conformal_control.predictors.base import Forecast, Predictor
from conformal_control.runs.engines.batch import run_batch, supports
from conformal_control.runs.engines.batch.episode import GapLossAt
from conformal_control.runs.episode import run_episode

ETA = 30.0  # the benchmark's eta, 1 per frame at 30 fps, in 1/s
FRAMES = 150


@pytest.fixture(scope="module")
def crossings():
    """The built-in crossing scene with three seeds."""
    return [load_scene("crossing", seed=s) for s in range(3)]


RULES = {
    # the default lambda floor opened: lambda moves freely (else two of the three sit on it)
    "pid": ({"epsilon": -0.1, "eta": ETA, "lambda_min": -math.inf}, {"K_I": ETA / 2, "C_sat": 1.0}),
    "dtaci": ({"epsilon": -0.1}, {"gammas": (3.0, 9.0, 30.0, 90.0), "sigma": 0.01}),
    "decaying_eta": ({"epsilon": -0.1, "eta": ETA}, {"power": 0.5}),
    "aci": ({}, {"alpha": 0.1, "gamma": ETA, "lambda_init": 0.0}),
}


@pytest.mark.parametrize("rule", sorted(RULES))
def test_update_rules_match_run_episode(crossings, compare_batch, rule):
    params, rule_params = RULES[rule]
    # batch_size 2 < 3 scenes: a freed slot is refilled mid-run
    batched, singles = compare_batch(
        crossings,
        max_frames=FRAMES,
        seeds=[0, 1, 2],
        batch_size=2,
        output="results",
        units="si",
        params=params,
        rule=rule,
        rule_params=rule_params,
    )
    assert all(r.metrics.rule == rule and r.metrics.n_updates > 10 for r in batched)
    # lambda moved, differently in each episode (the comparison is not of idle rules)
    finals = {r.metrics.lambda_final for r in singles}
    assert len(finals) == len(singles) and 0.0 not in finals
    if rule == "dtaci":  # every update evaluated the loss at the experts' lambdas
        for r in batched:
            assert r.loop.monitor.rule.n_counterfactual_ == r.metrics.n_updates


def test_gap_loss_as_a_function_of_lambda_is_the_loss():
    """s(max_gap + lambda) is what CBFGapLoss returns at any lambda, bit for bit."""
    lams = [0.0, 1e-17, -0.3, 0.7, 12.5, -1e3, 3e5, -np.pi]
    for params in CBFGapLoss._unit_test_params():
        loss = CBFGapLoss(**params)
        for record, truth in CBFGapLoss._unit_test_inputs():
            gaps = loss.gaps(record, truth)
            if not np.isfinite(gaps).any():
                continue
            at = GapLossAt(loss, np.nanmax(gaps))
            for lam in lams:
                assert at(lam) == loss(record, truth, lam), (lam, params)
    with pytest.raises(ValueError, match="lambda that is a number"):
        at(math.nan)


def test_collision_loss_with_aci_as_the_benchmark_runs_it(suite_scenes, compare_batch):
    from conformal_control.experiments.bench.methods import expand_methods

    [m] = expand_methods(["conformal_aci"])
    frames = [sc.meta["max_frames"] for sc in suite_scenes]
    batched, _ = compare_batch(
        suite_scenes, max_frames=frames, batch_size=2, output="results", **m.run_kwargs()
    )
    assert {r.metrics.rule for r in batched} == {"aci"}
    scored = [iv for r in batched for iv in r.intervals if iv["loss"] is not None]
    assert scored and {iv["loss"] for iv in scored} <= {0.0, 1.0}


def test_distance_shortfall_with_counterfactual_rule(crossings, compare_batch):
    """A record-scored loss handed to a rule as a function of lambda (dtaci)."""
    _, singles = compare_batch(
        crossings,
        max_frames=FRAMES,
        seeds=[0, 1, 2],
        batch_size=2,
        output="results",
        units="si",
        params={"epsilon": 0.2},
        rule="dtaci",
        rule_params={"gammas": (3.0, 30.0)},
        loss="distance_shortfall",
        loss_params={"d_safe": 6.0, "d_c": 1.0},
    )
    losses = {iv["loss"] for r in singles for iv in r.intervals if iv["loss"] is not None}
    assert len(losses) > 5 and min(losses) >= 0.0 and max(losses) <= 1.0  # not all clipped


@pytest.fixture(scope="module")
def suite_scenes(data_root):
    from conformal_control.data.suites import load_suite

    ids = [sc.id for sc in load_suite("crossings-v1").scenarios_for("dev")][:3]
    return [load_scene(f"scenario:crossings-v1/{i}", str(data_root)) for i in ids]


# ------------------------------------------------------------------ predictors
def test_var_predictor_matches_run_episode(crossings, compare_batch):
    batched, _ = compare_batch(
        crossings, max_frames=FRAMES, seeds=[0, 1, 2], batch_size=2, predictor="var"
    )
    assert all(m.n_updates > 0 for m in batched)


class _PatchyOracle(Predictor):
    """The true future, shifted by a deterministic offset, NaN for every other agent after
    the first sample at every other call (the controller's counted fallback), with counters and
    messages in ``info``; raises on its ``fail_on``-th call."""

    def __init__(self, offset: float = 0.1, fail_on: int = 0) -> None:
        self.offset = offset
        self.fail_on = fail_on

    def reset(self) -> None:
        self.calls_ = 0

    def predict(self, query):
        self.calls_ += 1
        if self.calls_ == self.fail_on:
            raise RuntimeError("deliberate failure")
        pos = query.future()[:, : query.horizon].copy() + self.offset * self.calls_ % 0.5
        pos = np.where(np.isfinite(pos), pos, query.current[:, None, :])
        if self.calls_ % 2:
            pos[::2, 1:] = np.nan
        return Forecast(pos, info={"n_calls": 1, "notes": [f"frame {query.frame}"]})


@pytest.fixture
def patchy():
    registry.register("predictor", "patchy_oracle_test", _PatchyOracle)
    yield "patchy_oracle_test"
    registry.unregister("predictor", "patchy_oracle_test")


def test_any_registered_predictor_with_counters_and_info(crossings, compare_batch, patchy):
    batched, _ = compare_batch(
        crossings, max_frames=FRAMES, seeds=[0, 1, 2], batch_size=2, predictor=patchy
    )
    for m in batched:
        assert m.n_nonfinite_predictions > 0
        assert m.predictor_info["n_calls"] == len(m.predictor_info["notes"]) > 0


def test_a_failing_predictor_raises_the_same_error(crossings, patchy):
    kw = {"predictor": patchy, "predictor_params": {"fail_on": 3}, "max_frames": FRAMES}
    with pytest.raises(PredictorError) as single:
        run_episode(crossings[0], record_animation=False, engine="loop", **kw)
    with pytest.raises(PredictorError) as batched:
        run_batch(crossings[:1], **kw)
    assert str(batched.value) == str(single.value)
    assert "_PatchyOracle failed on scene crossing at frame" in str(single.value)


# ------------------------------------------------------------------ what it accepts
@pytest.mark.parametrize(
    "kwargs",
    [
        {"rule": "pid"},
        {"rule": "dtaci", "loss": "collision"},
        {"rule": "decaying_eta", "loss": "distance_shortfall"},
        {"predictor": "var", "rule": "aci"},
        {"predictor": "kalman"},
    ],
)
def test_supports_any_rule_and_predictor_by_name(kwargs):
    assert supports(**kwargs) is None


def test_benchmark_methods_now_batched():
    from conformal_control.experiments.bench.methods import expand_methods

    methods = {m.family: supports(**m.run_kwargs()) for m in expand_methods(["conformal_pid"])}
    for fam in ("conformal_dtaci", "conformal_aci"):
        methods[fam] = supports(**expand_methods([fam])[0].run_kwargs())
    for fam in ("fallback:relax", "acp"):
        methods[fam] = supports(**expand_methods([fam])[0].run_kwargs())
    assert methods == dict.fromkeys(methods)
    why = supports(**expand_methods(["mpc"])[0].run_kwargs())
    assert why is not None and "family 'mpc'" in why


SHIFTS = {
    "delayed": {"delay_s": 0.4},
    "noisy": {"sigma_m": 0.3},
    "scaled": {"scale": 0.5},
    "dropout": {"p": 0.3, "duration_s": 0.5},
}


@pytest.mark.parametrize("shift", sorted(SHIFTS))
@pytest.mark.parametrize("base", ["constant_velocity", "oracle"])
def test_predictor_shifts_match_run_episode(crossings, compare_batch, shift, base):
    # the benchmark's shift axis: every wrapper around a compiled and a recorded-future base,
    # learning, seeds differing per episode (the wrappers' draws hash the run's seed)
    params = {**SHIFTS[shift], "predictor": base}
    if shift in ("noisy", "dropout"):
        params["random_state"] = None  # build_flagship passes each run's seed
    batched, _ = compare_batch(
        crossings,
        predictor=shift,
        predictor_params=params,
        params={"epsilon": -0.1, "eta": ETA},
        max_frames=FRAMES,
        seeds=[3, 4, 5],
        batch_size=2,
        output="results",
    )
    if base == "oracle" and shift == "dropout":
        return  # the recorded future does not depend on the detections a dropout removes
    # the shift took effect: the run differs from the unshifted one
    plain = run_batch(crossings, base, {"epsilon": -0.1, "eta": ETA}, max_frames=FRAMES)
    assert any(
        b.metrics.lambda_final != p.lambda_final for b, p in zip(batched, plain, strict=True)
    )
