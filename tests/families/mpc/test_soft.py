"""soft_mpc (the published CC-MPC): the reward for distance and the negative-distance loss."""

from __future__ import annotations

import math

import numpy as np

from conformal_control.core import registry
from conformal_control.core.update_rules import FixedEtaRule
from conformal_control.families.cbf.controller import ControlState
from conformal_control.families.cbf.dynamics import Unicycle
from conformal_control.families.mpc import NegativeDistanceLoss, Sampling, SoftRewardMPC
from conformal_control.families.mpc.fieldcp import step_distances
from conformal_control.predictors.base import Forecast, PredictionQuery, Predictor

DT = 0.4


class Frozen(Predictor):
    def predict(self, query: PredictionQuery) -> Forecast:
        return Forecast(np.repeat(query.current[:, None, :], query.horizon, axis=1))


def plan(lam: float):
    fam = SoftRewardMPC(
        Frozen(),
        Unicycle(v_min=-0.8, v_max=0.8, omega_max=0.7, integrator="euler"),
        sampling=Sampling(n_samples=200, horizon=6, dt_plan=DT),
        substeps=1,
        continuous=False,
    )
    fam.reset()
    ped = np.array([[1.5, 0.2]])
    fam.begin_interval(
        PredictionQuery(np.arange(1), np.repeat(ped[:, None], 8, axis=1), DT, 1, 0.0)
    )
    state = ControlState(x=np.zeros(5), t=0.0, step=0, goal=np.array([6.0, 0.0]))
    p = fam.plan(state, lam)
    cost = p.cost
    return fam, p, cost, ped


def test_every_candidate_is_kept_and_the_weight_buys_distance():
    fam, near, _, ped = plan(-0.01)
    assert near.status == "optimal" and near.n_safe == fam.sampling.n_samples + 1
    _, far, _, _ = plan(-20.0)  # the same candidates, a large weight on distance
    pred = np.repeat(ped[:, None], 6, axis=1)
    d_near = step_distances(near.positions[None], pred).sum()
    d_far = step_distances(far.positions[None], pred).sum()
    assert d_far > d_near + 0.5


def test_the_cost_is_the_base_cost_plus_lambda_times_the_distances():
    _, p, cost, ped = plan(-3.0)
    pred = np.repeat(ped[:, None], 6, axis=1)
    d = step_distances(p.positions[None], pred).sum()
    g = np.array([6.0, 0.0])
    base = ((p.positions[:-1] - g) ** 2).sum() + 10 * ((p.positions[-1] - g) ** 2).sum()
    base += 0.001 * (p.commands**2).sum()
    assert math.isclose(cost, base - 3.0 * d, rel_tol=1e-9)


def test_the_loss_is_minus_the_distance_now_and_the_published_update():
    loss = NegativeDistanceLoss()
    rec, truth = NegativeDistanceLoss._unit_test_inputs()[0]
    d = np.linalg.norm(truth.samples[:, 0] - rec.x_ego[0], axis=1).min()
    assert loss(rec, truth, -1.0) == -d
    assert registry.get("loss", "negative_distance") is NegativeDistanceLoss
    # the published weight -lambda: closer than 2 m raises it by 5000 per metre, at least 0.01
    rule = FixedEtaRule(
        **{**SoftRewardMPC.capabilities.default_rule_params, "lambda_min": -math.inf}
    )
    rule.reset()
    assert math.isclose(rule.update(-1.5), -1.0 + 5000 * (-2.0 + 1.5))  # 1.5 m: weight up
    assert rule.update(-10.0) == -0.01  # far: the weight drops to its floor
