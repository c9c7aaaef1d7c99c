"""The sampling MPC family: safety of the chosen plan, determinism, brute force, errors."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from conformal_control.families.cbf.controller import ControlState
from conformal_control.families.cbf.dynamics import (
    DoubleIntegrator,
    Unicycle,
    VelocityTrackingDoubleIntegrator,
)
from conformal_control.families.cbf.reference import AttractiveField
from conformal_control.families.mpc import Costs, Limits, Sampling, SamplingMPC
from conformal_control.families.mpc.kernels import evaluate, evaluate_numpy
from conformal_control.predictors.base import PredictionQuery
from conformal_control.predictors.constant_velocity import ConstantVelocityPredictor

DT = 0.4


def query(current: np.ndarray, velocity: np.ndarray, t: float = 0.0) -> PredictionQuery:
    """Agents moving at constant velocity, with a two-sample history."""
    hist = np.stack([current - velocity * DT, current], axis=1)
    return PredictionQuery(
        ids=np.arange(len(current)), history=hist, dt=DT, horizon=1, t=t, frame=0, scene="t"
    )


def family(**kw) -> SamplingMPC:
    params = {
        "predictor": ConstantVelocityPredictor(),
        "dynamics": VelocityTrackingDoubleIntegrator(K_acc=10.0),
        "reference": AttractiveField(K_att=1.0, v_max=1.5),
        "sampling": Sampling(n_samples=200, horizon=8, dt_plan=DT),
        "limits": Limits(v_max=1.5),
        "substeps": 1,
    }
    params.update(kw)
    fam = SamplingMPC(**params)
    fam.reset()
    return fam


def state(x: np.ndarray, goal=(10.0, 0.0), t: float = 0.0) -> ControlState:
    return ControlState(x=np.asarray(x, dtype=float), t=t, step=0, goal=np.asarray(goal, float))


def random_crowd(rng: np.random.Generator, m: int) -> tuple[np.ndarray, np.ndarray]:
    pos = rng.uniform([1.0, -4.0], [9.0, 4.0], (m, 2))
    vel = rng.normal(0.0, 0.8, (m, 2))
    return pos, vel


def test_kernel_equals_the_numpy_reference():
    rng = np.random.default_rng(0)
    for continuous in (True, False):
        for m in (0, 1, 7):
            pos = rng.normal(0, 3, (50, 6, 2))
            cmds = rng.normal(0, 1, (50, 6, 2))
            pred = rng.normal(0, 3, (m, 6, 2))
            y0 = rng.normal(0, 3, (m, 2))
            radius = rng.uniform(0.5, 1.5, (50, 6))
            args = (pos, cmds, np.zeros(2), pred, y0, radius, np.array([4.0, 1.0]))
            w, last = (1.0, 10.0, 0.01, 0.3), np.array([0.2, -0.1])
            fast = evaluate(*args, w, last, continuous)
            ref = evaluate_numpy(*args, w, last, continuous)
            for a, b in zip(fast, ref, strict=True):
                np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_continuous_check_sees_a_crossing_between_plan_steps():
    # robot from (0, 0) to (2, 0), an agent from (1, -1) to (1, 1) in the same step: the
    # end points are sqrt(2) m apart, but both pass (1, 0) at mid-step
    pos = np.array([[[2.0, 0.0]]])
    pred, y0 = np.array([[[1.0, 1.0]]]), np.array([[1.0, -1.0]])
    args = (pos, np.zeros((1, 1, 2)), np.zeros(2), pred, y0, np.array([1.0]), np.zeros(2))
    _, ends, _ = evaluate(*args, (1, 1, 0, 0), np.zeros(2), False)
    _, whole, _ = evaluate(*args, (1, 1, 0, 0), np.zeros(2), True)
    assert math.isclose(ends[0], math.sqrt(2) - 1.0)
    assert math.isclose(whole[0], -1.0, abs_tol=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_the_chosen_plan_meets_every_constraint_it_reports(seed):
    rng = np.random.default_rng(seed)
    fam = family(random_state=seed)
    x = np.array([0.0, 0.0, 0.5, 0.0])
    for k in range(5):
        pos, vel = random_crowd(rng, 12)
        fam.begin_interval(query(pos, vel, t=k * DT))
        lam = float(rng.uniform(-1.0, 0.5))
        plan = fam.plan(state(x, t=k * DT), lam)
        if plan.status != "optimal":
            continue
        # recompute the plan's clearance from scratch with the numpy reference
        states = fam.dynamics.rollout(x, plan.commands[None], DT)
        times = DT * np.arange(0, fam.sampling.horizon + 1)
        pred = pos[:, None, :] + vel[:, None, :] * times[None, :, None]
        _, clear, _ = evaluate_numpy(
            states[..., :2],
            plan.commands[None],
            x[:2],
            pred[:, 1:],
            pred[:, 0],
            fam.safe_radius(lam),
            np.array([10.0, 0.0]),
            (1, 10, 0, 0),
            np.zeros(2),
            True,
        )
        assert clear[0] >= 0.0
        assert math.isclose(clear[0], plan.clearance, rel_tol=1e-9, abs_tol=1e-12)
        # and at a dense set of instants within the plan (linear motion between steps)
        p = np.concatenate([x[None, :2], states[0, :, :2]])
        for h in range(fam.sampling.horizon):
            for s in np.linspace(0, 1, 21):
                robot = p[h] + s * (p[h + 1] - p[h])
                agents = pred[:, h] + s * (pred[:, h + 1] - pred[:, h])
                d = np.hypot(*(agents - robot).T).min()
                assert d >= fam.safe_radius(lam)[h] - 1e-9


def test_deterministic_with_a_seed_and_different_across_seeds():
    def run(seed):
        fam = family(random_state=seed)
        rng = np.random.default_rng(99)
        x, out = np.array([0.0, 0.0, 0.0, 0.0]), []
        for k in range(4):
            pos, vel = random_crowd(rng, 6)
            fam.begin_interval(query(pos, vel, t=k * DT))
            u = fam.decide(state(x, t=k * DT), 0.0)
            x = fam.dynamics.step(x, u, DT)
            out.append(u)
        return np.array(out)

    np.testing.assert_array_equal(run(3), run(3))
    assert not np.array_equal(run(3), run(4))


def test_equals_a_brute_force_evaluation_on_a_tiny_case():
    fam = family(
        sampling=Sampling(n_samples=6, horizon=3, dt_plan=DT, hold=1),
        costs=Costs(w_effort=0.01, w_comfort=0.1),
        random_state=1,
    )
    pos = np.array([[2.0, 0.3], [1.0, -1.5]])
    vel = np.array([[-1.0, 0.0], [0.0, 1.0]])
    fam.begin_interval(query(pos, vel))
    x = np.array([0.0, 0.0, 0.2, 0.1])
    st, lam = state(x, goal=(3.0, 0.0)), -0.1
    twin = copy.deepcopy(fam)
    plan = fam.plan(st, lam)
    cands = twin.sample_commands(st, 0.0)  # the same candidates (same generator state)
    r = 1.0 + 0.0 + 0.1
    best, best_cost = None, math.inf
    for u in cands:
        xs, cost, ok = x.copy(), 0.0, True
        prev, last = x[:2].copy(), np.zeros(2)
        for h in range(3):
            xs = fam.dynamics.step(xs, u[h], DT)
            g = xs[:2] - np.array([3.0, 0.0])
            cost += (10.0 if h == 2 else 1.0) * float(g @ g)
            cost += 0.01 * float(u[h] @ u[h]) + 0.1 * float((u[h] - last) @ (u[h] - last))
            last = u[h]
            for j in range(2):
                a = prev - (pos[j] + vel[j] * h * DT)
                b = xs[:2] - (pos[j] + vel[j] * (h + 1) * DT)
                dist = min(np.hypot(*(a + s * (b - a))) for s in np.linspace(0, 1, 2001))
                ok &= dist >= r - 1e-6
            prev = xs[:2].copy()
        if ok and cost < best_cost:
            best, best_cost = u, cost
    assert best is not None and plan.status == "optimal"
    np.testing.assert_array_equal(plan.commands, best)
    assert math.isclose(plan.cost, best_cost, rel_tol=1e-12)


def test_a_smaller_lambda_never_admits_more_samples():
    rng = np.random.default_rng(5)
    pos, vel = random_crowd(rng, 10)
    counts = []
    for lam in (-2.0, -1.0, -0.5, 0.0, 0.5, 1.0):
        fam = family(random_state=0)
        fam.begin_interval(query(pos, vel))
        counts.append(fam.plan(state(np.zeros(4)), lam).n_safe)
    assert counts == sorted(counts) and counts[0] < counts[-1]


@pytest.mark.parametrize("fallback", ["brake", "least_violation"])
def test_no_safe_sample_is_a_counted_fallback(fallback):
    fam = family(fallback=fallback)
    fam.begin_interval(query(np.array([[0.1, 0.0]]), np.zeros((1, 2))))  # on the robot
    u = fam.decide(state(np.zeros(4)), 0.0)
    rec = fam.interval_record()
    assert rec.status == [fallback] and math.isnan(rec.lam_applied[0])
    assert fam.stats()["n_infeasible"] == 1 and fam.stats()[f"n_fallback_{fallback}"] == 1
    if fallback == "brake":
        np.testing.assert_array_equal(u, 0.0)
    else:
        assert rec.clearance[0] < 0 and np.hypot(*u) > 0


def test_brake_with_an_acceleration_command_stops_within_a_plan_step():
    fam = family(dynamics=DoubleIntegrator(), limits__a_max=5.0, reference=None)
    fam.begin_interval(query(np.array([[0.1, 0.0]]), np.zeros((1, 2))))
    u = fam.decide(state([0.0, 0.0, 1.0, -0.5]), 0.0)
    np.testing.assert_allclose(u, [-1.0 / DT, 0.5 / DT])


def test_unicycle_commands_stay_within_the_plants_limits():
    plant = Unicycle(v_min=-0.3, v_max=0.8, omega_max=0.7)
    fam = family(dynamics=plant, reference=None)
    rng = np.random.default_rng(2)
    pos, vel = random_crowd(rng, 5)
    fam.begin_interval(query(pos, vel))
    cands = fam.sample_commands(state(plant.initial_state(np.zeros(2))), 0.0)
    assert (cands[..., 0] >= -0.3).all() and (cands[..., 0] <= 0.8).all()
    assert (np.abs(cands[..., 1]) <= 0.7).all()
    u = fam.decide(state(plant.initial_state(np.zeros(2))), 0.0)
    assert -0.3 <= u[0] <= 0.8 and abs(u[1]) <= 0.7


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"sampling__n_samples": 0}, "n_samples must be an integer from 1 to 100,000"),
        ({"sampling__horizon": 0}, "horizon must be an integer from 1 to 1,000"),
        ({"sampling__hold": 1.5}, "hold must be an integer from 1 to 8"),
        ({"sampling__dt_plan": -0.4}, "dt_plan must be a finite number > 0"),
        ({"limits__v_max": -1.0}, "v_max must be a finite number > 0"),
        ({"d_c": -1.0}, "d_c must be a finite distance >= 0"),
        ({"costs__w_goal": -1.0}, "w_goal must be a finite weight >= 0"),
        ({"sampling": "fast"}, "sampling must be a Sampling"),
        ({"fallback": "pray"}, "fallback must be one of brake, least_violation"),
        ({"dynamics": Unicycle(v_max=-0.5)}, "need v_min <= 0 <= v_max"),
    ],
)
def test_bad_parameters_give_one_line_errors(params, message):
    with pytest.raises(ValueError, match=message) as info:
        family(**params)
    assert "\n" not in str(info.value)


def test_a_goal_that_is_not_a_point_is_a_one_line_error():
    fam = family()
    fam.begin_interval(query(np.array([[5.0, 5.0]]), np.zeros((1, 2))))
    with pytest.raises(ValueError, match="the goal must be a finite") as info:
        fam.decide(state(np.zeros(4), goal=(math.nan, 0.0)), 0.0)
    assert "\n" not in str(info.value)
