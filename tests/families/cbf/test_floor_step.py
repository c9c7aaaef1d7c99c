"""Each agent's own floor stepping down while it binds (``lambda_floor_step``): an agent
whose lambda sits at its floor while its loss still exceeds epsilon gets a lower floor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.core.exceptions import InputError
from conformal_control.core.monitor import AgentMonitor
from conformal_control.core.update_rules.dtaci import DtACIRule
from conformal_control.core.update_rules.fixed_eta import FixedEtaRule


def _run(mon: AgentMonitor, losses: dict[int, float], n: int) -> None:
    keys = np.array(sorted(losses))
    for _ in range(n):
        mon.values(keys)
        mon.update(keys, [losses[int(k)] for k in keys])


def test_only_the_missed_agent_at_its_floor_gets_a_lower_floor():
    """Pedestrian 7 keeps missing (loss 0.4 > epsilon), pedestrian 9 is met (loss -0.3):
    with the step on, 7's floor steps 5/s at a time down to the limit -45/s and its
    lambda follows; 9 never reaches the floor and keeps the run's. Off: both stop at -30."""
    for step, want7 in ((0.0, -30.0), (5.0, -45.0)):
        mon = AgentMonitor(
            FixedEtaRule(epsilon=-0.05, eta=30.0, lambda_min=-30.0),
            floor_step=step,
            floor_limit=-45.0,
        )
        _run(mon, {7: 0.4, 9: -0.3}, 30)
        lam7, lam9 = mon.values([7, 9])
        assert lam7 == pytest.approx(want7)
        assert lam9 > 0.0
        assert mon.agent_floors == ({7: -45.0} if step else {})
        assert mon.n_floor_stepped == (3 if step else 0)  # -30 -> -35 -> -40 -> -45


def test_the_floor_steps_only_while_the_agent_is_missed_at_it():
    """A miss above the floor, or a met interval at the floor, leaves the floor alone."""
    mon = AgentMonitor(FixedEtaRule(epsilon=-0.05, eta=30.0, lambda_min=-30.0), floor_step=5.0)
    _run(mon, {1: 0.2}, 1)  # lambda 0 -> -7.5: a miss far above the floor
    assert mon.n_floor_stepped == 0
    _run(mon, {1: 0.4}, 3)  # -7.5 -> -21 -> -30 (clipped); the third miss is at the floor
    assert mon.n_floor_stepped == 1 and mon.agent_floors == {1: -35.0}
    assert mon.values([1])[0] == pytest.approx(-35.0)
    _run(mon, {1: -0.05}, 2)  # at the floor, loss = epsilon: no miss, no step
    assert mon.n_floor_stepped == 1
    assert mon.agent_floors[1] == -35.0
    # no limit given: the floor keeps stepping while the agent is missed at it
    _run(mon, {1: 0.4}, 4)
    assert mon.agent_floors[1] == -55.0


def test_a_dtaci_agent_is_at_its_floor_when_every_expert_is():
    """DtACI's output mixes its experts: it sits at the floor once every expert does (the
    slowest, 3/s, last); then the floor steps and every expert follows it down."""
    mon = AgentMonitor(
        DtACIRule(epsilon=-0.05, gammas=(3.0, 90.0), lambda_min=-30.0),
        floor_step=5.0,
        floor_limit=-40.0,
    )
    _run(mon, {1: 0.45}, 15)  # the fast expert at the floor, the slow one not yet
    rule = mon.entries[1].rule
    assert rule is not None
    assert float(rule.experts_.min()) == -30.0 < float(rule.experts_.max())
    assert -30.0 < mon.values([1])[0] and mon.n_floor_stepped == 0
    _run(mon, {1: 0.45}, 25)
    assert mon.agent_floors == {1: -40.0}
    assert float(rule.experts_.min()) == -40.0
    assert mon.values([1])[0] < -35.0
    off = AgentMonitor(DtACIRule(epsilon=-0.05, gammas=(3.0, 90.0), lambda_min=-30.0))
    _run(off, {1: 0.45}, 40)
    assert off.values([1])[0] >= -30.0


def test_without_learning_no_floor_moves():
    mon = AgentMonitor(FixedEtaRule(lambda_min=-30.0, lambda_init=-30.0), learn=False,
                       floor_step=5.0)  # fmt: skip
    _run(mon, {1: 0.4}, 5)
    assert mon.n_floor_stepped == 0 and mon.agent_floors == {}


def test_bad_floor_step_settings_are_refused_in_one_line(crossing):
    from conformal_control.runs.episode import run_episode

    for kw, msg in (
        ({"floor_step": -1.0}, "lambda_floor_step must be a finite rate >= 0, got -1.0"),
        ({"floor_step": math.inf}, "lambda_floor_step must be a finite rate"),
        ({"floor_limit": math.nan}, "lambda_floor_limit must be a number or -inf"),
        ({"floor_step": 5.0, "floor_limit": -10.0}, r"must not exceed lambda_min \(-30.0\)"),
    ):
        with pytest.raises(ValueError, match=msg):
            AgentMonitor(FixedEtaRule(lambda_min=-30.0), **kw)
    for params, msg in (
        ({"lambda_per": "agent", "lambda_floor_step": -1.0}, "finite rate >= 0, got -1.0"),
        ({"lambda_floor_step": 0.1}, "needs lambda_per='agent'"),
        (
            {"lambda_per": "agent", "lambda_min": -0.3, "lambda_floor_step": 0.1,
             "lambda_floor_limit": 0.0},
            "must not exceed lambda_min",
        ),
    ):  # fmt: skip
        with pytest.raises(InputError, match=msg) as err:
            run_episode(crossing, params=params, units="si", max_frames=20)
        assert "\n" not in str(err.value)


def test_a_run_with_the_step_goes_below_its_floor_and_without_never(crossing):
    """The synthetic crossing under a 0.5 s delay, per-agent fixed-eta rule, floor -0.3/s: with the
    step some agent's lambda goes below the run's floor (never below the limit); without
    it none does. Bit for bit the same run when the step is 0."""
    from conformal_control.runs.episode import run_episode

    kw = dict(
        params={"lambda_per": "agent", "epsilon": -0.2, "lambda_min": -0.3},
        units="si",
        predictor="delayed",
        predictor_params={"delay_s": 0.5},
        max_frames=200,
    )
    off = run_episode(crossing, **kw)
    zero = run_episode(crossing, **{**kw, "params": {**kw["params"], "lambda_floor_step": 0.0}})
    on = run_episode(
        crossing,
        **{**kw, "params": {**kw["params"], "lambda_floor_step": 0.1, "lambda_floor_limit": -0.6}},
    )

    def low(res):
        return min(float(np.min(iv.lams)) for iv in res.loop.intervals if iv.lams.size)

    assert low(off) >= -0.3
    assert -0.6 <= low(on) < -0.3
    assert on.loop.monitor.n_floor_stepped > 0
    assert off.metrics.as_dict() == {**zero.metrics.as_dict(), "wall_s": off.metrics.wall_s}
