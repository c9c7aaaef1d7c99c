"""A per-agent lambda floor from each agent's own row feasibility (``lambda_floor_row``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.core.exceptions import InputError
from conformal_control.core.monitor import AgentMonitor
from conformal_control.core.update_rules.dtaci import DtACIRule
from conformal_control.core.update_rules.fixed_eta import FixedEtaRule
from conformal_control.families.cbf.barriers import APFBarrier
from conformal_control.families.cbf.constraint import ConformalConstraint
from conformal_control.families.cbf.feasibility import robot_speed_bound, row_floors
from conformal_control.families.cbf.records import CBFIntervalRecord

A, V = 100.0, 2.0


def _two_pedestrians(s: int = 4) -> tuple[ConformalConstraint, CBFIntervalRecord]:
    """Pedestrian 7 far beyond rho0 (no gradient, h = h_max); pedestrian 9 predicted
    1.5 m ahead of the robot and walking at it."""
    con = ConformalConstraint(APFBarrier(K_rep=0.2, rho0=16.0, d_c=1.0), a=A)
    t = np.arange(s) * 0.1
    x_ego = np.column_stack([0.5 * t, np.zeros(s)])
    far = np.column_stack([np.full(s, 40.0), np.full(s, 30.0)])
    near = np.column_stack([2.0 - 0.8 * t, np.zeros(s)])
    x_pred = np.stack([far, near], axis=1)
    v_pred = np.stack([np.zeros((s, 2)), np.tile([-0.8, 0.0], (s, 1))], axis=1)
    rec = CBFIntervalRecord(
        ids=np.array([7, 9]),
        x_ego=x_ego,
        v_ego=np.tile([0.5, 0.0], (s, 1)),
        x_pred=x_pred,
        v_pred=v_pred,
        lam_applied=np.zeros(s),
    )
    return con, rec


def test_each_rows_floor_is_the_lowest_lambda_it_can_be_met_at():
    con, rec = _two_pedestrians()
    got = row_floors(con, rec, V)
    h_max = con.barrier.upper_bound
    assert got[0] == pytest.approx(-A * h_max)  # far: the global feasibility floor
    # near: instant by instant with the constraint's own rows, the tightest instant
    want = max(
        float(-(b[1] + V * np.hypot(*a_[1])))
        for a_, b in (con.rows(rec.x_ego[t], rec.x_pred[t], rec.v_pred[t]) for t in range(4))
    )
    assert got[1] == pytest.approx(want)
    assert -A * h_max < got[1] < -10.0  # predicted close: a higher floor than the far one
    # at its floor the row is met by the fastest retreat and by nothing else
    t = int(
        np.argmax([-(con.rows(rec.x_ego[k], rec.x_pred[k], rec.v_pred[k])[1][1]) for k in range(4)])
    )
    a_, b = con.rows(rec.x_ego[t], rec.x_pred[t], rec.v_pred[t])
    lam = got[1]
    best = V * np.hypot(*a_[1]) + b[1] + lam
    assert best >= -1e-9


def test_only_the_agent_whose_row_allows_it_goes_below_the_runs_floor():
    """Both pedestrians keep missing (loss 0.4); the run's floor is -30/s. Pedestrian 7's
    row is satisfiable down to -50/s, pedestrian 9's only down to -20/s: with the row
    floor only 7's floor moves (to -50/s); 9 stays at the run's -30/s."""
    for share, want7 in ((0.0, -30.0), (1.0, -50.0), (0.5, -30.0), (0.8, -40.0)):
        mon = AgentMonitor(FixedEtaRule(epsilon=-0.05, eta=30.0, lambda_min=-30.0), row_floor=share)
        keys = np.array([7, 9])
        for _ in range(20):
            mon.values(keys)
            mon.update(keys, [0.4, 0.4], floors=np.array([-50.0, -20.0]))
        lam7, lam9 = mon.values(keys)
        assert lam7 == pytest.approx(want7)
        assert lam9 == -30.0
        assert (mon.n_floor_lowered > 0) == (share * -50.0 < -30.0)
    # a new agent starts at the prior, never below the run's floor (its row is not known)
    mon = AgentMonitor(
        FixedEtaRule(epsilon=-0.05, eta=30.0, lambda_min=-30.0), row_floor=1.0, prior=0.0
    )
    for _ in range(20):
        mon.values([7])
        mon.update([7], [0.4], floors=[-50.0])
    assert mon.values([7, 11]).tolist() == [-50.0, -30.0]
    # a missing floor (NaN) is the run's floor, and so is an update without floors
    mon = AgentMonitor(FixedEtaRule(epsilon=-0.05, eta=30.0, lambda_min=-30.0), row_floor=1.0)
    for floors in (np.array([math.nan]), None, np.array([-50.0]), None):
        mon.values([7])
        mon.update([7], [0.4], floors=floors)
    assert mon.values([7])[0] == -30.0  # lowered once, then clipped back at -30


def test_the_row_floor_clips_every_dtaci_expert():
    mon = AgentMonitor(
        DtACIRule(epsilon=-0.05, gammas=(3.0, 90.0), lambda_min=-30.0), row_floor=1.0
    )
    for _ in range(30):
        mon.values([1])
        mon.update([1], [0.45], floors=[-45.0])
    rule = mon.entries[1].rule
    assert rule is not None
    assert float(rule.experts_.min()) == -45.0
    assert mon.values([1])[0] < -30.0


def test_bad_row_floor_settings_are_refused_in_one_line(crossing):
    from conformal_control.runs.episode import run_episode

    with pytest.raises(ValueError, match=r"lambda_floor_row must be a share in \[0, 1\], got 1.5"):
        AgentMonitor(FixedEtaRule(), row_floor=1.5)
    with pytest.raises(ValueError, match="lambda_floor_row must be a share"):
        AgentMonitor(FixedEtaRule(), row_floor=math.nan)
    mon = AgentMonitor(FixedEtaRule(), row_floor=1.0)
    mon.values([1, 2])
    with pytest.raises(ValueError, match="2 keys but 1 floors"):
        mon.update([1, 2], [0.1, 0.1], floors=[-40.0])
    with pytest.raises(ValueError, match="robot_speed must be a finite number"):
        row_floors(*_two_pedestrians(), -1.0)
    for params, msg in (
        ({"lambda_per": "agent", "lambda_floor_row": 2.0}, r"share in \[0, 1\], got 2.0"),
        ({"lambda_floor_row": 0.5}, "needs lambda_per='agent'"),
    ):
        with pytest.raises(InputError, match=msg) as err:
            run_episode(crossing, params=params, max_frames=20)
        assert "\n" not in str(err.value)


def test_the_speed_sets_radius():
    assert robot_speed_bound(2.0, 16) == 2.0
    assert robot_speed_bound(2.0, 0) == pytest.approx(2.0 * math.sqrt(2.0))


def test_the_controller_gives_its_records_floors_and_the_run_reads_them(crossing):
    """The controller's lambda_floors are row_floors of its interval record, and a run with
    the row floor has agents below the run's floor where the loop without has none."""
    from conformal_control.runs.episode import run_episode

    kw = dict(
        params={"lambda_per": "agent", "epsilon": -0.2, "lambda_min": -0.3},
        units="si",
        predictor="delayed",
        predictor_params={"delay_s": 0.5},
        max_frames=200,
    )
    off = run_episode(crossing, **kw)
    kw["params"] = {**kw["params"], "lambda_floor_row": 1.0}
    on = run_episode(crossing, **kw)
    lo_off = min(float(np.min(iv.lams)) for iv in off.loop.intervals if iv.lams.size)
    lo_on = min(float(np.min(iv.lams)) for iv in on.loop.intervals if iv.lams.size)
    # (a = 2/s on the synthetic crossing: far rows are satisfiable down to -a h_max = -1/s)
    assert lo_off >= -0.3
    assert lo_on < -0.3
    mon = on.loop.monitor
    assert mon.n_floor_lowered > 0 and mon.n_floor_bound > 0


def test_the_controllers_floors_are_its_records(crossing):
    from conformal_control.core.loop import ConformalLoop
    from conformal_control.core.spec import RunSpec
    from conformal_control.runs.build import build_flagship

    run = RunSpec.from_settings(
        params={"lambda_per": "agent", "epsilon": -0.2}, units="si", max_frames=120
    )
    fl = build_flagship(crossing, run)
    fam = fl.family
    seen: list[np.ndarray] = []

    def check(log):
        got = fam.lambda_floors()
        want = row_floors(fam.constraint, fam.interval_record(), fam.safety_filter.v_max)
        assert got is not None and np.array_equal(got, want, equal_nan=True)
        assert got.shape == log.keys.shape
        seen.append(got)

    ConformalLoop(
        fl.env, fam, fl.loss, fl.rule, lambda_per="agent", lambda_floor_row=1.0, on_interval=check
    ).run()
    floors = np.concatenate(seen)
    assert floors.size > 10 and np.isfinite(floors).all()
    # far agents near -a h_max = -1/s, those close to the robot higher
    assert floors.min() < -0.9 and floors.max() > floors.min() + 0.5
