"""AgentMonitor: lambda run per agent, each entry its own rule on its own losses.

Synthetic per-agent losses with a known safe lambda: agent j's loss at lambda is
0.4 tanh(lambda - theta_j,k) with thresholds theta in [-1, 1], so lambda <= -1 keeps every
agent's loss <= 0 = epsilon (Theorem 2's premise holds exactly, lambda_safe = -1).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.core.loop import close_agent_interval
from conformal_control.core.monitor import AgentMonitor
from conformal_control.core.update_rules import DtACIRule, FixedEtaRule, PIDRule


def _drive(monitor, keys_per_step, rng, eta_check=None):
    """Feed the monitor one interval per entry of ``keys_per_step``."""
    for keys in keys_per_step:
        lams = monitor.values(keys)
        theta = rng.uniform(-1.0, 1.0, size=len(keys))
        losses = 0.4 * np.tanh(lams - theta)
        monitor.update(keys, losses)


def test_each_agent_meets_its_own_theorem2_bound_and_the_pooled_one():
    rng = np.random.default_rng(0)
    eta, lam_safe = 0.5, -1.0
    mon = AgentMonitor.for_rule(
        FixedEtaRule(epsilon=0.0, eta=eta, lambda_init=2.0), lambda_safe=lam_safe, prior=0.5
    )
    # agents come and go: 1 throughout, 2 for the first half, 3 late, 4 for 3 intervals
    steps = []
    for k in range(200):
        keys = [1]
        if k < 100:
            keys.append(2)
        if k >= 120:
            keys.append(3)
        if 50 <= k < 53:
            keys.append(4)
        steps.append(keys)
    _drive(mon, steps, rng)
    per = mon.agents(min_intervals=1)
    assert sorted(per["key"].tolist()) == [1, 2, 3, 4]
    # each agent: the exact identity and its own Theorem-2 bound
    for key, n, avg, lam1 in zip(per["key"], per["n"], per["l_avg"], per["lambda_1"], strict=True):
        entry = mon.entries[int(key)]
        assert entry.identity_residual < 1e-13
        assert avg == pytest.approx(0.0 + (lam1 - entry.lam) / (eta * n), abs=1e-12)
        assert avg <= 0.0 + (lam1 - lam_safe + eta) / (eta * n) + 1e-12
        assert entry.verdict in ("holds", "premise_untested")  # untested: never that low
    # pooled: the K_j-weighted mean of the agents' averages, under the pooled bound
    pooled = np.sum(per["n"] * per["l_avg"]) / per["n"].sum()
    assert mon.average == pytest.approx(pooled, abs=1e-12)
    c = np.sum(per["lambda_1"] - lam_safe + eta)
    assert mon.bound == pytest.approx(c / (eta * mon.n), abs=1e-12)
    assert mon.bound_holds and mon.verdict in ("holds", "premise_untested")
    s = mon.summary()
    assert s["n_agents"] == 4 and s["n_agents_checked"] == 3  # agent 4 has 3 < 10 losses
    assert s["n_agents_bound_met"] == 3 and s["theorem2_bound_met"] is True
    assert sorted(s["agent_n"]) == sorted(n for n in per["n"].tolist() if n >= 10)


def test_the_verdict_holds_when_every_agent_tested_the_premise():
    # loss +0.3 above lambda_safe = 0, -0.3 at or below: the premise holds and is tested
    mon = AgentMonitor.for_rule(
        FixedEtaRule(epsilon=0.0, eta=1.0, lambda_init=0.5), lambda_safe=0.0, prior=1.0
    )
    for k in range(40):
        keys = [1, 2] if k >= 10 else [1]
        lams = mon.values(keys)
        mon.update(keys, np.where(lams > 0.0, 0.3, -0.3))
    assert mon.entries[2].lambda_1 == pytest.approx(-0.1)  # agent 1 then (q = 1: the largest)
    assert [mon.entries[k].verdict for k in (1, 2)] == ["holds", "holds"]
    assert mon.verdict == "holds" and mon.summary()["theorem2_holds"] is True


def test_an_agent_breaking_the_premise_is_reported():
    mon = AgentMonitor.for_rule(
        FixedEtaRule(epsilon=0.0, eta=1.0, lambda_init=5.0), lambda_safe=5.0
    )
    for _ in range(20):
        mon.values([1, 2])
        mon.update([1, 2], [0.3, -0.45])  # agent 1's loss above epsilon below lambda_safe
    assert mon.entries[1].verdict == "violated" and mon.entries[1].premise_violations == 20
    assert mon.entries[2].verdict == "holds"
    assert mon.verdict == "violated"  # an agent above its own bound, whatever the pool
    assert mon.summary()["theorem2_premise_violations"] == 20


def test_the_prior_of_a_new_agent_is_the_quantile_of_the_current_lambdas():
    rule = FixedEtaRule(epsilon=0.0, eta=1.0, lambda_init=0.25)
    mon = AgentMonitor.for_rule(rule, prior=0.0)
    assert mon.values([5, 6]).tolist() == [0.25, 0.25]  # no agent yet: lambda_init
    mon.update([5, 6], [0.4, -0.3])  # 5 -> -0.15, 6 -> 0.55
    assert mon.values([5, 6]).tolist() == pytest.approx([-0.15, 0.55])
    # two new agents in one interval share the prior: the smallest current lambda (q = 0)
    assert mon.values([7, 8, 5]).tolist() == pytest.approx([-0.15, -0.15, -0.15])
    med = AgentMonitor.for_rule(FixedEtaRule(epsilon=0.0, eta=1.0), prior=0.5)
    med.values([1, 2, 3])
    med.update([1, 2, 3], [0.3, 0.0, -0.4])  # -0.3, 0, 0.4
    assert med.values([9])[0] == pytest.approx(0.0)  # the median
    assert med.prior_value() == pytest.approx(np.quantile([-0.3, 0.0, 0.4, 0.0], 0.5))


def test_an_agent_that_leaves_keeps_its_lambda_and_resumes_its_sequence():
    mon = AgentMonitor.for_rule(FixedEtaRule(epsilon=0.0, eta=1.0))
    mon.values([1, 2])
    mon.update([1, 2], [0.2, 0.1])
    left = mon.values([2])[0]
    for _ in range(5):  # agent 2 away: only 1 is scored
        mon.values([1])
        mon.update([1], [0.3])
    assert mon.values([2])[0] == left  # frozen meanwhile
    mon.update([2], [-0.4])
    assert mon.entries[2].n == 2 and mon.entries[2].lam == pytest.approx(left + 0.4)
    assert mon.entries[2].identity_residual < 1e-15


def test_a_nan_loss_is_no_update_and_an_unknown_agent_an_error():
    mon = AgentMonitor.for_rule(FixedEtaRule(epsilon=0.0, eta=1.0))
    mon.values([1, 2])
    mon.update([1, 2], [math.nan, 0.2])
    assert mon.entries[1].n == 0 and mon.entries[2].n == 1 and mon.n == 1
    with pytest.raises(KeyError, match="agent 3"):
        mon.update([3], [0.1])
    with pytest.raises(ValueError, match="2 keys but 1 losses"):
        mon.update([1, 2], [0.1])
    with pytest.raises(ValueError, match="quantile"):
        AgentMonitor.for_rule(FixedEtaRule(), prior=1.5)


def test_counterfactual_rules_get_each_agents_own_loss_function():
    rule = DtACIRule(epsilon=0.0, gammas=(0.1, 1.0), sigma=0.01, lambda_init=0.0)
    mon = AgentMonitor.for_rule(rule)
    tops = np.array([0.3, -0.2])  # agent i's loss at lambda: tanh(top_i + lambda) / 4
    seen = []

    def at(i, lam):
        seen.append(i)
        return float(np.tanh(tops[i] + lam)) / 4

    for _ in range(5):
        lams = mon.values([10, 11])
        mon.update([10, 11], np.tanh(tops + lams) / 4, at)
    assert set(seen) == {0, 1}
    assert mon.entries[10].rule.n_counterfactual_ == 5 == mon.entries[11].rule.n_counterfactual_
    # the badly predicted agent (positive top) ends more conservative than the other
    assert mon.entries[10].lam < mon.entries[11].lam


def test_long_run_rules_report_a_pooled_long_run_bound():
    rng = np.random.default_rng(1)
    mon = AgentMonitor.for_rule(PIDRule(epsilon=0.0, eta=0.2, K_I=0.5, C_sat=1.0))
    _drive(mon, [[1, 2]] * 50, rng)
    per = [mon.entries[k].long_run_bound for k in (1, 2)]
    assert mon.long_run_bound == pytest.approx(np.mean(per))
    assert mon.long_run_holds is True


def test_close_agent_interval_logs_the_largest_term_and_updates_each_agent():
    class Parts:
        def components(self, record, truth, lam):
            from conformal_control.core.base import KeyedLosses

            return KeyedLosses(np.array([3, 1]), np.array([0.1, np.nan]) + 0 * lam[:2])

        def diagnostics(self, record, truth, lam):
            return {"x": 1.0}

    mon = AgentMonitor.for_rule(FixedEtaRule(epsilon=0.0, eta=1.0))
    keys = np.array([1, 3, 4])
    lams = mon.values(keys)
    log, lam = close_agent_interval(0, keys, lams, 5, monitor=mon, loss=Parts(), record=None)
    assert log.loss == 0.1 and log.lam == 0.0 and log.diagnostics == {"x": 1.0}
    assert np.array_equal(log.agent_losses, [np.nan, 0.1, np.nan], equal_nan=True)
    assert mon.entries[3].lam == pytest.approx(-0.1) and mon.entries[1].n == 0
    assert lam == mon.prior_value()


def test_the_premise_is_checked_at_every_interval_and_per_agent():
    # agent j's loss at lambda is 0.4 tanh(lambda - theta_j): theta_1 = -1 always, agent 2's
    # theta is -1 except at 3 intervals where it is -3 (the premise at lambda_safe = -1
    # fails there: 0.4 tanh(2) > 0); lambda never goes down to -1 (epsilon high)
    theta = {1: -1.0, 2: -1.0}
    mon = AgentMonitor.for_rule(
        FixedEtaRule(epsilon=0.3, eta=0.1, lambda_init=0.5), lambda_safe=-1.0
    )
    for k in range(30):
        theta[2] = -3.0 if k in (4, 10, 20) else -1.0
        keys = [1, 2]
        lams = mon.values(keys)
        th = np.array([theta[1], theta[2]])
        losses = 0.4 * np.tanh(lams - th)
        mon.update(keys, losses, lambda i, lam, th=th: float(0.4 * np.tanh(lam - th[i])))
    fig = mon.premise_figures()
    assert fig["n_premise_checks"] == 60 and fig["n_premise_exceeded"] == 3
    assert fig["n_agents_premise_exceeded"] == 1
    assert mon.safe_checks == {1: [30, 0], 2: [30, 3]}
    assert fig["n_agents_premise_tested"] == 0 and fig["n_agents_premise_failed"] == 0
    assert mon.summary()["n_premise_exceeded"] == 3
    # without lambda_safe: no figures; without ``at``: nothing re-evaluated
    plain = AgentMonitor.for_rule(FixedEtaRule(epsilon=0.3, eta=0.1))
    plain.values([1])
    plain.update([1], [0.1])
    assert set(plain.premise_figures().values()) == {None}
    blind = AgentMonitor.for_rule(FixedEtaRule(epsilon=0.0, eta=1.0), lambda_safe=5.0)
    blind.values([1])
    blind.update([1], [0.3])  # lambda 0 <= 5: tested, and the loss breaks the premise
    fig = blind.premise_figures()
    assert fig["n_premise_checks"] == 0
    assert fig["n_agents_premise_tested"] == 1 and fig["n_agents_premise_failed"] == 1
