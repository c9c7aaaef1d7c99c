"""The generic conformal loop (``ConformalLoop``, ``ConformalStepper``) on hand-made parts.

The parts are as small as they can be: an environment revealing one threshold per
interval, a family deciding lambda itself, the loss ``clip(lam - threshold)`` (so every
lambda has a loss we can compute by hand), and the fixed-step rule.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.core.base import DecisionFamily, Environment, Loss
from conformal_control.core.loop import ConformalLoop, ConformalStepper, IntervalLog
from conformal_control.core.update_rules import FixedEtaRule

THRESHOLDS = [0.3, -0.2, 0.1, None, 0.4, 0.0, None, -0.1]


class ThresholdEnv(Environment):
    """Reveals ``thresholds[k]`` after interval k; ``instants`` decisions per interval.

    Parameters
    ----------
    thresholds : list of float or None
        One per interval (None: nothing to score).
    instants : int
        Control instants per interval.
    stop_after : int, optional
        The episode ends after this many decisions in all (possibly inside an interval).
    """

    def __init__(self, thresholds=None, instants=2, stop_after=None):
        self.thresholds = thresholds
        self.instants = instants
        self.stop_after = stop_after

    def reset(self):
        self.calls_ = ["reset"]
        self.k_, self.applied_, self.decisions_ = 0, 0, []

    @property
    def done(self):
        out_of_data = self.k_ >= len(self.thresholds)
        return out_of_data or (self.stop_after is not None and self.applied_ >= self.stop_after)

    def sense(self):
        self.calls_.append("sense")
        return {"k": self.k_}

    def control_instants(self):
        self.calls_.append("control_instants")
        return self.instants

    def state(self):
        self.calls_.append("state")
        return self.applied_

    def apply(self, decision):
        self.calls_.append("apply")
        self.decisions_.append(decision)
        self.applied_ += 1

    def reveal(self):
        self.calls_.append("reveal")
        self.k_ += 1
        return self.thresholds[self.k_ - 1]


class LambdaFamily(DecisionFamily):
    """Decides lambda itself; the record is the interval's decisions."""

    def reset(self):
        self.observations_ = []
        self.n_resets_ = getattr(self, "n_resets_", 0) + 1

    def begin_interval(self, observation):
        self.observations_.append(observation)
        self.record_ = []

    def decide(self, state, lam):
        self.record_.append(lam)
        return lam

    def interval_record(self):
        return list(self.record_)


class ThresholdLoss(Loss):
    """l = clip(lam - threshold, -0.5, 0.5); None without a threshold."""

    def __call__(self, record, truth, lam):
        if truth is None:
            return None
        return float(np.clip(lam - truth, -0.5, 0.5))

    def diagnostics(self, record, truth, lam):
        return {"n_decided": float(len(record))}


def by_hand(thresholds, rule_params, learn=True):
    """(lambda, loss) of every interval, computed without the loop."""
    eps, eta, lam = rule_params["epsilon"], rule_params["eta"], rule_params["lambda_init"]
    out = []
    for th in thresholds:
        loss = None if th is None else float(np.clip(lam - th, -0.5, 0.5))
        out.append((lam, loss))
        if loss is not None and learn:
            lam = lam + eta * (eps - loss)
    return out, lam


RULE = {"epsilon": 0.05, "eta": 0.5, "lambda_init": 0.2}


def make_loop(thresholds=THRESHOLDS, *, instants=2, stop_after=None, rule=None, **kw):
    env = ThresholdEnv(list(thresholds), instants=instants, stop_after=stop_after)
    rule = FixedEtaRule(**RULE) if rule is None else rule
    return ConformalLoop(env, LambdaFamily(), ThresholdLoss(), rule, **kw), env


def test_run_matches_the_update_by_hand():
    loop, env = make_loop()
    result = loop.run()
    expected, lam_final = by_hand(THRESHOLDS, RULE)
    assert [iv.lam for iv in result.intervals] == pytest.approx([lam for lam, _ in expected])
    assert [iv.loss is None for iv in result.intervals] == [x is None for _, x in expected]
    assert result.losses == pytest.approx([x for _, x in expected if x is not None])
    assert result.lambda_final == pytest.approx(lam_final)
    assert env.done and len(result.intervals) == len(THRESHOLDS)
    # each interval decided with its lambda_k at each of its instants
    assert env.decisions_ == [lam for lam, _ in expected for _ in range(2)]
    assert [iv.n_steps for iv in result.intervals] == [2] * len(THRESHOLDS)


def test_max_intervals_stops_early():
    loop, env = make_loop()
    result = loop.run(max_intervals=3)
    assert [iv.k for iv in result.intervals] == [0, 1, 2]
    assert not env.done and env.k_ == 3
    expected, _ = by_hand(THRESHOLDS[:3], RULE)
    assert result.lambda_final == pytest.approx(expected[-1][0] + 0.5 * (0.05 - expected[-1][1]))
    assert len(loop.run(max_intervals=0).intervals) == 0  # a second run starts afresh


def test_on_interval_called_once_per_interval_with_its_log():
    seen: list[IntervalLog] = []
    loop, _ = make_loop(on_interval=seen.append)
    result = loop.run()
    assert seen == result.intervals and all(
        a is b for a, b in zip(seen, result.intervals, strict=True)
    )
    expected, _ = by_hand(THRESHOLDS, RULE)
    scored = []
    for k, (log, (lam, loss)) in enumerate(zip(seen, expected, strict=True)):
        assert log.k == k and log.n_steps == 2
        assert log.lam == pytest.approx(lam)
        if loss is None:
            assert log.loss is None and log.diagnostics == {}
        else:
            scored.append(loss)
            assert log.loss == pytest.approx(loss)
            assert log.diagnostics == {"n_decided": 2.0}  # the record reached the loss
        # running average after this interval's update (None without a loss)
        assert log.l_avg == (pytest.approx(np.mean(scored)) if loss is not None else None)


def test_on_interval_sees_the_log_before_the_next_interval():
    lams_at_callback = []
    loop, env = make_loop(on_interval=lambda log: lams_at_callback.append(len(env.decisions_)))
    loop.run()
    assert lams_at_callback == [2 * (k + 1) for k in range(len(THRESHOLDS))]


def test_learn_false_keeps_lambda_and_still_averages():
    loop, _ = make_loop(learn=False, lambda_safe=0.0)
    result = loop.run()
    assert {iv.lam for iv in result.intervals} == {RULE["lambda_init"]}
    assert result.lambda_final == RULE["lambda_init"]
    expected, _ = by_hand(THRESHOLDS, RULE, learn=False)
    losses = [loss for _, loss in expected if loss is not None]
    assert result.l_avg == pytest.approx(np.mean(losses))
    g = result.guarantee
    assert g["guarantee"] == "none" and g["identity_residual"] is None
    assert g["theorem2_bound"] is None and g["theorem2_verdict"] == "not_applicable"
    assert g["n_losses"] == len(losses)


def test_intervals_without_loss_do_not_update():
    loop, _ = make_loop()
    result = loop.run()
    ivs = result.intervals
    for k, th in enumerate(THRESHOLDS[:-1]):
        if th is None:  # no loss: lambda carried over unchanged
            assert ivs[k].loss is None and ivs[k + 1].lam == ivs[k].lam
        else:
            assert ivs[k + 1].lam != ivs[k].lam
    n_scored = sum(th is not None for th in THRESHOLDS)
    assert result.n_updates == n_scored == result.monitor.n
    assert len(result.losses) == len(result.lambdas) == n_scored
    assert loop.rule.n_updates_ == n_scored


def test_all_intervals_without_loss():
    loop, _ = make_loop([None, None, None])
    result = loop.run()
    assert len(result.intervals) == 3 and result.n_updates == 0
    assert math.isnan(result.l_avg) and result.lambda_final == RULE["lambda_init"]
    assert all(iv.l_avg is None for iv in result.intervals)


def test_episode_ending_inside_an_interval():
    loop, env = make_loop([0.1, 0.2, 0.3, 0.4], instants=3, stop_after=7)
    result = loop.run()
    # intervals of 3, 3 and then 1 decision: the episode ends after the 7th apply()
    assert [iv.n_steps for iv in result.intervals] == [3, 3, 1]
    assert env.applied_ == 7 and env.done
    # the interval cut short is still revealed and scored
    assert env.calls_[-2:] == ["apply", "reveal"] and result.intervals[-1].loss is not None
    per_interval = ["sense", "control_instants"] + ["state", "apply"] * 3 + ["reveal"]
    cut = ["sense", "control_instants", "state", "apply", "reveal"]
    assert env.calls_ == ["reset", *per_interval, *per_interval, *cut]


def test_zero_instant_interval_still_scored():
    loop, env = make_loop([0.1, 0.2], instants=0)
    result = loop.run()
    assert [iv.n_steps for iv in result.intervals] == [0, 0]
    assert env.decisions_ == [] and result.n_updates == 2


class ProbingRule(FixedEtaRule, uses_loss_function=True):
    """Fixed step that asks for l_k(.) and evaluates it at other lambdas."""

    def reset(self):
        self.fn_ = None
        self.probes_: list[tuple[float, list]] = []
        return super().reset()

    def set_loss_function(self, fn):
        self.fn_ = fn

    def update(self, loss):
        assert self.fn_ is not None, "update() before set_loss_function()"
        self.probes_.append((loss, [self.fn_(lam) for lam in (-1.0, 0.0, 0.25, 2.0)]))
        self.fn_ = None
        return super().update(loss)


def test_rules_using_the_loss_function_get_l_k_at_other_lambdas():
    rule = ProbingRule(**RULE)
    loop, _ = make_loop(rule=rule)
    result = loop.run()
    scored = [th for th in THRESHOLDS if th is not None]
    assert len(rule.probes_) == len(scored)  # once per update, never without a loss
    for (loss, values), th, iv in zip(rule.probes_, scored, result.updates, strict=True):
        assert values == [float(np.clip(lam - th, -0.5, 0.5)) for lam in (-1.0, 0.0, 0.25, 2.0)]
        assert loss == iv.loss
    # the probing changes nothing: same lambdas as the plain rule
    plain = make_loop()[0].run()
    assert [iv.lam for iv in result.intervals] == [iv.lam for iv in plain.intervals]


def test_rules_not_using_it_never_get_a_loss_function():
    class Refusing(FixedEtaRule):
        def set_loss_function(self, fn):
            raise AssertionError("set_loss_function called on a rule that does not use it")

    make_loop(rule=Refusing(**RULE))[0].run()  # would raise


def test_stepper_misuse_errors():
    stepper = ConformalStepper(LambdaFamily(), ThresholdLoss(), FixedEtaRule(**RULE))
    stepper.start()
    with pytest.raises(RuntimeError, match=r"decide\(\) called outside an interval"):
        stepper.decide(0)
    with pytest.raises(RuntimeError, match=r"end_interval\(\) called without begin_interval"):
        stepper.end_interval(0.1)
    stepper.begin_interval({"k": 0})
    with pytest.raises(RuntimeError, match=r"begin_interval\(\) called twice"):
        stepper.begin_interval({"k": 0})
    stepper.decide(0)
    stepper.end_interval(0.1)
    with pytest.raises(RuntimeError, match=r"decide\(\) called outside an interval"):
        stepper.decide(1)  # the interval is closed
    assert len(stepper.result().intervals) == 1  # the failed calls logged nothing


def test_stepper_by_hand_equals_the_loop():
    thresholds = [0.3, None, -0.2, 0.1, 0.45, None, 0.0]
    seen_loop: list[IntervalLog] = []
    loop, _ = make_loop(thresholds, instants=3, on_interval=seen_loop.append, lambda_safe=-0.5)
    from_loop = loop.run()

    seen_stepper: list[IntervalLog] = []
    family, rule = LambdaFamily(), FixedEtaRule(**RULE)
    stepper = ConformalStepper(
        family, ThresholdLoss(), rule, lambda_safe=-0.5, on_interval=seen_stepper.append
    )
    lam_1 = stepper.start()
    assert lam_1 == RULE["lambda_init"] == stepper.lam and family.n_resets_ == 1
    for k, th in enumerate(thresholds):
        stepper.begin_interval({"k": k})
        for i in range(3):
            assert stepper.decide(i) == stepper.lam
        stepper.end_interval(th)
    by_stepper = stepper.result()

    assert by_stepper.intervals == from_loop.intervals
    assert seen_stepper == seen_loop
    assert by_stepper.lambda_final == from_loop.lambda_final
    assert by_stepper.guarantee == from_loop.guarantee
    assert by_stepper.guarantee["theorem2_bound"] is not None  # lambda_safe reached the monitor


def test_stepper_keeps_the_record_its_loss_scored():
    """``record_`` is the record the loss was given at the last end_interval (built once:
    a caller reads the interval's decisions from it without asking the family again)."""
    given = []

    class Keeping(ThresholdLoss):
        def __call__(self, record, truth, lam):
            given.append(record)
            return super().__call__(record, truth, lam)

    family = LambdaFamily()
    calls = []
    build = family.interval_record
    family.interval_record = lambda: calls.append(1) or build()  # type: ignore[method-assign]
    stepper = ConformalStepper(family, Keeping(), FixedEtaRule(**RULE))
    stepper.start()
    assert stepper.record_ is None
    for k, th in enumerate([0.3, None, -0.2]):
        stepper.begin_interval({"k": k})
        lams = [stepper.decide(i) for i in range(k + 1)]
        stepper.end_interval(th)
        assert stepper.record_ is given[-1] and stepper.record_ == lams
    assert len(calls) == 3  # one record per interval
