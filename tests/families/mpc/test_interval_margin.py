"""``interval_margin_mpc``: the learned safe distances hold over the plan steps one interval
covers (the fixed ``d_c + margin`` beyond), each pedestrian its own; a batch of episodes
plans the same; bad parameters give one-line errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conformal_control.data import load_scene
from conformal_control.experiments.bench.methods import expand_methods
from conformal_control.families.cbf.controller import ControlState
from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.families.cbf.reference import AttractiveField
from conformal_control.families.mpc import Limits, Sampling, SamplingMPC
from conformal_control.families.mpc.batch import plan_all
from conformal_control.families.mpc.interval_margin import IntervalMarginMPC
from conformal_control.predictors.base import PredictionQuery
from conformal_control.predictors.constant_velocity import ConstantVelocityPredictor
from conformal_control.runs.engines.batch import as_run_spec
from conformal_control.runs.engines.mpc_batch import iter_mpc_batch
from conformal_control.runs.episode import run_episode

DT = 0.4
D_C = 0.6
GOAL = (10.0, 0.0)


def _family(cls: type[SamplingMPC] = IntervalMarginMPC, **kw: object) -> SamplingMPC:
    params: dict[str, object] = {
        "predictor": ConstantVelocityPredictor(),
        "dynamics": VelocityTrackingDoubleIntegrator(K_acc=10.0),
        "reference": AttractiveField(K_att=1.0, v_max=1.5),
        "sampling": Sampling(n_samples=200, horizon=8, dt_plan=DT),
        "limits": Limits(v_max=1.5),
        "d_c": D_C,
        "substeps": 1,
        **kw,
    }
    fam = cls(**params)  # type: ignore[arg-type]
    fam.reset()
    return fam


def _standing(points: list[tuple[float, float]]) -> PredictionQuery:
    """Pedestrians standing still (two samples of history), one interval of one sample."""
    cur = np.asarray(points, dtype=float)
    hist = np.stack([cur, cur], axis=1)
    return PredictionQuery(
        ids=np.arange(len(cur)), history=hist, dt=DT, horizon=1, t=0.0, frame=0, scene="t"
    )


def _nearest(fam: SamplingMPC, point: tuple[float, float]) -> float:
    """The closest the current plan's positions come to ``point`` (m)."""
    pos = fam._plan.positions  # type: ignore[union-attr]
    return float(np.hypot(*(pos - np.asarray(point)).T).min())


def _decide(fam: SamplingMPC, points: list[tuple[float, float]], lam: object) -> None:
    fam.begin_interval(_standing(points))
    x = fam.dynamics.initial_state(np.zeros(2), 0.0)
    fam.decide(ControlState(x=x, t=0.0, step=0, goal=np.asarray(GOAL)), lam)  # type: ignore[arg-type]


def test_the_learned_distance_holds_over_the_interval_and_d_c_beyond() -> None:
    """A pedestrian standing 1 m beside the straight line to the goal, reached after about
    2 s: with lambda = -0.8 m over the whole plan (``mpc``) the plan keeps 1.4 m from it;
    with the distance over the interval's one plan step, the straight line (1 m >= d_c)."""
    ped = (3.0, 1.0)
    whole = _family(SamplingMPC)
    _decide(whole, [ped], -0.8)
    assert _nearest(whole, ped) >= D_C + 0.8 - 1e-9
    fam = _family()
    _decide(fam, [ped], -0.8)
    assert fam._k == 1  # one 0.4 s interval: one 0.4 s plan step
    assert D_C <= _nearest(fam, ped) < D_C + 0.8
    # a span of the whole horizon is mpc bit for bit
    full = _family(span=8)
    _decide(full, [ped], -0.8)
    np.testing.assert_array_equal(full._plan.commands, whole._plan.commands)  # type: ignore[union-attr]


def test_within_the_span_the_learned_distance_binds() -> None:
    """A pedestrian 1 m beside the end of the straight line's first plan step (1.35 m from
    it): the plan keeps d_c + 0.8 m = 1.4 m from it over that step, and closer later."""
    ped = (1.5, 1.0)
    fam = _family()
    _decide(fam, [ped], -0.8)
    first = fam._plan.positions[0]  # type: ignore[union-attr]
    assert np.hypot(*(first - np.asarray(ped))) >= D_C + 0.8 - 1e-9
    assert fam._plan.status == "optimal"  # type: ignore[union-attr]
    assert _nearest(fam, ped) < D_C + 0.8  # beyond the span: d_c


def test_each_pedestrian_gets_its_own_distance_when_decide_plans() -> None:
    """Two pedestrians, lambda per pedestrian: the one beside the path at lambda 0, a far
    one at -0.8 m. ``SamplingMPC.decide`` plans with each its own distance (the straight
    line, 1 m from the near one, is allowed; with the smallest lambda for both it would keep
    1.4 m), exactly as a lockstep batch (``plan_all``) plans; a span of the whole horizon is
    the same plan."""
    near, far = (3.0, 1.0), (-20.0, 20.0)
    lam = np.array([0.0, -0.8])
    plain = _family(SamplingMPC)
    _decide(plain, [near, far], lam)
    assert D_C <= _nearest(plain, near) < D_C + 0.8
    shared = _family(SamplingMPC)  # the smallest lambda for both: the old decide's plan
    _decide(shared, [near, far], -0.8)
    assert _nearest(shared, near) >= D_C + 0.8 - 1e-9
    fam = _family(span=8)
    _decide(fam, [near, far], lam)
    np.testing.assert_array_equal(fam._plan.commands, plain._plan.commands)  # type: ignore[union-attr]
    # planned in a batch (plan_begin given the vector): the same plan
    batch = _family(SamplingMPC)
    batch.begin_interval(_standing([near, far]))
    x = batch.dynamics.initial_state(np.zeros(2), 0.0)
    st = ControlState(x=x, t=0.0, step=0, goal=np.asarray(GOAL))
    assert plan_all([(batch, st, lam)]) == 1
    batch.decide(st, lam)  # type: ignore[arg-type]
    np.testing.assert_array_equal(batch._plan.commands, plain._plan.commands)  # type: ignore[union-attr]


def test_batch_episodes_equal_the_loop() -> None:
    """The benchmark method on crossing scenes, in lockstep batches and one after another,
    equals run_episode's loop field by field (lambda per pedestrian, learning)."""
    method = expand_methods(["cc_mpc_margin_agent_interval"])[0]
    kw = method.run_kwargs()
    kw["family_params"] = {**kw["family_params"], "sampling__n_samples": 60}
    run = dataclasses.replace(as_run_spec(**kw), record_animation=False)
    episodes = [
        (load_scene("crossing", seed=s), dataclasses.replace(run, seed=s, max_frames=240), None)
        for s in range(3)
    ]
    together = dict(iter_mpc_batch(iter(episodes), lockstep=True, batch_size=3))
    apart = dict(iter_mpc_batch(iter(episodes), lockstep=False))
    for i, (scene, r, _) in enumerate(episodes):
        alone = run_episode(scene, r, engine="loop")
        for got in (together[i], apart[i]):
            assert got.intervals == alone.intervals
            assert got.steps["cmd"].tobytes() == alone.steps["cmd"].tobytes()
            assert got.metrics.n_collide == alone.metrics.n_collide
    assert sum(r.metrics.n_updates for r in apart.values()) > 0
    # pedestrians at different lambdas decided together: the offsets were exercised
    logs = [iv for r in apart.values() for iv in r.loop.intervals if iv.lams is not None]
    assert any(np.unique(iv.lams).size > 1 for iv in logs)


@pytest.mark.parametrize("span", [0, -2, 1.5, "plan", True])
def test_bad_span_is_a_one_line_error(span: object) -> None:
    with pytest.raises(ValueError, match="span must be 'interval' or a number") as err:
        _family(span=span)
    assert "\n" not in str(err.value)
