"""The controller's compiled step records the interval itself, bit for bit as before.

``ConformalCBFController.decide`` with the APF barrier and the exact 2-D filter runs one
compiled call (``kernels2d.apf_control``) that also writes the interval's record. These
tests hold it to the fused path it replaced, written out here as it was (reference
velocity from ``AttractiveField.__call__``, ``Exact2DSafetyFilter.step_apf`` on the
interpolated predictions, lists appended in Python): the same bits for every decision,
status, lambda applied, counter and record, on random problems covering every outcome
(unconstrained, optimal, lambda search, brake, hold, more agents than the buffers were
laid out for, more decisions than an interval has instants). And to the generic Python
path (``compiled_step=False``) up to round-off.
"""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from conformal_control.families.cbf import (
    APFBarrier,
    AttractiveField,
    ConformalCBFController,
    ConformalConstraint,
    ControlState,
    Exact2DSafetyFilter,
)
from conformal_control.families.cbf.interp import interpolate_at_substeps
from conformal_control.predictors import OraclePredictor, PredictionQuery

HORIZON, SUBSTEPS, DT = 4, 4, 0.1
STEPS = HORIZON * SUBSTEPS


def make(fallback: str, compiled: bool = True, K_att: float = 1.0) -> ConformalCBFController:
    ctrl = ConformalCBFController(
        OraclePredictor(),
        ConformalConstraint(APFBarrier(K_rep=0.5, rho0=5.0, d_c=0.7), a=2.0),
        Exact2DSafetyFilter(v_max=2.0, fallback=fallback, compiled_step=compiled),
        AttractiveField(K_att=K_att, v_max=2.0),
        substeps=SUBSTEPS,
    )
    ctrl.reset()
    return ctrl


class PreviousFusedPath:
    """The controller's fused path as it was before the compiled step wrote the record:
    the reference velocity from ``AttractiveField.__call__`` (numpy), one
    ``step_apf`` call on the interpolated predictions, the record appended in Python."""

    def __init__(self, ctrl: ConformalCBFController) -> None:
        self.reference = ctrl.reference
        self.filter = ctrl.safety_filter
        barrier = ctrl.constraint.barrier
        K, rho0, d_c, delta = barrier._checked()
        self.filter.reset()
        self.filter.configure_apf(
            (K, rho0, d_c, delta, barrier.convention == "surface"),
            ctrl.constraint.a,
            ctrl.constraint.edge_settings(),  # the edge rule as the controller has it
        )

    def begin_interval(self, q: PredictionQuery) -> None:
        samples = np.concatenate([q.current[:, None, :], q.ground_truth[:, :HORIZON]], axis=1)
        self.xp, self.vp = interpolate_at_substeps(samples, q.dt, SUBSTEPS, STEPS)
        self.x: list[np.ndarray] = []
        self.v: list[np.ndarray] = []
        self.lam: list[float] = []
        self.status: list[str] = []

    def decide(self, state: ControlState, lam: float) -> np.ndarray:
        x_ego = state.x[:2]
        v_ref = self.reference(state.x, state.t, state.goal)
        res = self.filter.step_apf(x_ego, self.xp[state.step], self.vp[state.step], v_ref, lam)
        self.x.append(x_ego.copy())
        self.v.append(res.decision)
        self.lam.append(res.lambda_applied)
        self.status.append(res.status if res.fallback is None else res.fallback)
        return res.decision


def random_interval(rng: np.random.Generator, n: int) -> PredictionQuery:
    """n agents around the origin walking roughly at it (near ones make the rows bind)."""
    ang = rng.uniform(-np.pi, np.pi, n)
    r = rng.uniform(0.5, 8.0, n)
    cur = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    vel = -rng.uniform(0.0, 1.5, (n, 1)) * cur / r[:, None] + rng.normal(0.0, 0.3, (n, 2))
    hist = cur[:, None, :] - vel[:, None, :] * (np.arange(5)[::-1][None, :, None] * DT)
    fut = cur[:, None, :] + vel[:, None, :] * (np.arange(1, HORIZON + 1)[None, :, None] * DT)
    return PredictionQuery(ids=np.arange(n), history=hist, dt=DT, horizon=HORIZON, ground_truth=fut)


def same_bits(a: object, b: object) -> bool:
    x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return x.shape == y.shape and x.tobytes() == y.tobytes()


# lambdas from far above to far below the feasibility floor (which is near -2 here)
LAMBDAS = (5.0, 0.0, -0.5, -1.0, -1.6, -2.5, -10.0, -1e3)


@pytest.mark.parametrize("fallback", ["lambda_search", "brake", "hold"])
def test_compiled_record_is_bit_identical_to_the_previous_fused_path(fallback) -> None:
    rng = np.random.default_rng(7)
    new = make(fallback)
    old = PreviousFusedPath(make(fallback))
    assert new._fused
    seen: dict[str, int] = {}
    for k in range(40):
        # up to 40 agents: more than the 16 the filter's buffers start with
        q = random_interval(rng, int(rng.choice([1, 2, 5, 20, 40])))
        new.begin_interval(q)
        old.begin_interval(q)
        goal = rng.uniform(-25.0, 25.0, 2) if k % 3 else rng.uniform(-1.0, 1.0, 2)
        # every instant, then some again: more decisions than the interval's instants
        for j in [*range(STEPS), *rng.integers(0, STEPS, 5 if k % 4 == 0 else 0)]:
            x = np.concatenate([rng.normal(0.0, 0.8, 2), rng.normal(0.0, 1.0, 2)])
            state = ControlState(x=x, t=0.1 * j, step=int(j), goal=goal)
            lam = float(rng.choice(LAMBDAS)) + rng.normal(0.0, 0.05)
            d_new = new.decide(state, lam)
            d_old = old.decide(state, lam)
            assert same_bits(d_new, d_old), (k, j)
            f_new, f_old = new.safety_filter, old.filter
            assert same_bits(f_new._last, f_old._last) and f_new._fell_back == f_old._fell_back
        rec = new.interval_record()
        assert rec.status == old.status
        assert same_bits(rec.x_ego, np.array(old.x))
        assert same_bits(rec.v_ego, np.array(old.v))
        assert same_bits(rec.lam_applied, np.array(old.lam, dtype=float))
        assert same_bits(rec.x_pred, old.xp[: rec.n_steps])
        assert same_bits(rec.v_pred, old.vp[: rec.n_steps])
        assert new.safety_filter.stats() == old.filter.stats()
        for s in rec.status:
            seen[s] = seen.get(s, 0) + 1
    # every outcome was exercised
    assert seen.get("unconstrained", 0) > 20 and seen.get("optimal", 0) > 20
    assert seen.get(fallback, 0) > 20
    assert new.safety_filter._cap > 16  # the buffers grew


def test_compiled_step_matches_the_generic_path_on_random_problems() -> None:
    rng = np.random.default_rng(3)
    fused, generic = make("lambda_search"), make("lambda_search", compiled=False)
    assert fused._fused and not generic._fused
    seen: set[str] = set()
    for _ in range(30):
        q = random_interval(rng, int(rng.integers(1, 30)))
        fused.begin_interval(q)
        generic.begin_interval(q)
        goal = rng.uniform(-25.0, 25.0, 2)
        for j in range(STEPS):
            state = ControlState(x=rng.normal(0.0, 1.0, 4), t=0.1 * j, step=j, goal=goal)
            lam = float(rng.choice(LAMBDAS))
            d1, d2 = fused.decide(state, lam), generic.decide(state, lam)
            np.testing.assert_allclose(d1, d2, rtol=0, atol=1e-9)
        r1, r2 = fused.interval_record(), generic.interval_record()
        assert r1.status == r2.status
        seen.update(r1.status)
        for name in ("x_ego", "v_ego", "x_pred", "v_pred", "lam_applied"):
            a, b = getattr(r1, name), getattr(r2, name)
            assert a.shape == b.shape
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9)
    assert fused.stats() == generic.stats()
    assert seen >= {"unconstrained", "optimal", "lambda_search"}


def test_attractive_field_scalar_path_has_the_same_bits() -> None:
    rng = np.random.default_rng(0)
    for K_att, v_max in ((1.0, 2.0), (30.0, 2.0), (3, 1), (0.37, 1e-3)):
        field = AttractiveField(K_att=K_att, v_max=v_max)
        for _ in range(500):
            x = rng.normal(0.0, 10.0 ** rng.uniform(-6, 3), 4)
            goal = rng.normal(0.0, 10.0 ** rng.uniform(-6, 3), 2)
            v0, v1 = field.velocity(*x[:2].tolist(), *goal.tolist())
            assert same_bits((v0, v1), field(x, 0.0, goal))


def test_returned_decisions_stay_put_and_the_record_is_a_copy() -> None:
    rng = np.random.default_rng(5)
    ctrl = make("lambda_search")
    goal = np.array([20.0, 0.0])
    ctrl.begin_interval(random_interval(rng, 20))
    first = ctrl.decide(ControlState(np.zeros(4), 0.0, 0, goal), 0.0)
    kept = first.copy()
    rec = ctrl.interval_record()
    ctrl.begin_interval(random_interval(rng, 20))
    for j in range(STEPS):
        ctrl.decide(ControlState(rng.normal(0, 1, 4), 0.0, j, goal), -10.0)
    assert same_bits(first, kept)  # a later interval never writes over an earlier decision
    before = rec.v_ego.copy()
    ctrl.interval_record().v_ego[:] = 99.0
    assert same_bits(rec.v_ego, before)


def test_steps_outside_the_interval_and_non_finite_input() -> None:
    rng = np.random.default_rng(11)
    new = make("lambda_search")
    old = PreviousFusedPath(make("lambda_search"))
    q = random_interval(rng, 5)
    new.begin_interval(q)
    old.begin_interval(q)
    goal = np.array([3.0, 1.0])
    x = np.array([0.1, -0.2, 0.0, 0.0])
    # a negative step counts from the end, as numpy indexing did
    assert same_bits(
        new.decide(ControlState(x, 0.0, -1, goal), 0.0),
        old.decide(ControlState(x, 0.0, -1, goal), 0.0),
    )
    for step in (STEPS, -STEPS - 1):
        with pytest.raises(IndexError):
            new.decide(ControlState(x, 0.0, step, goal), 0.0)
        with pytest.raises(IndexError):
            old.decide(ControlState(x, 0.0, step, goal), 0.0)
    for lam, xx in ((math.nan, x), (0.0, np.array([np.inf, 0.0, 0.0, 0.0]))):
        with pytest.raises(ValueError, match="non-finite"):
            new.decide(ControlState(xx, 0.0, 2, goal), lam)
        with pytest.raises(ValueError, match="non-finite"), np.errstate(invalid="ignore"):
            old.decide(ControlState(xx, 0.0, 2, goal), lam)
    assert new.interval_record().status == old.status  # nothing recorded for the failures
    assert new.n_steps_ == 1
    assert new.safety_filter.stats() == old.filter.stats()


def test_a_controller_pickled_mid_interval_decides_the_same() -> None:
    rng = np.random.default_rng(2)
    ctrl = make("hold")
    goal = np.array([20.0, 0.0])
    ctrl.begin_interval(random_interval(rng, 20))
    states = [ControlState(rng.normal(0, 1, 4), 0.0, j, goal) for j in range(STEPS)]
    lams = rng.choice(LAMBDAS, STEPS)
    for j in range(5):
        ctrl.decide(states[j], float(lams[j]))
    copy = pickle.loads(pickle.dumps(ctrl))
    for j in range(5, STEPS):
        assert same_bits(ctrl.decide(states[j], lams[j]), copy.decide(states[j], lams[j]))
    r1, r2 = ctrl.interval_record(), copy.interval_record()
    assert r1.status == r2.status and same_bits(r1.v_ego, r2.v_ego)
    assert same_bits(r1.lam_applied, r2.lam_applied)
    assert ctrl.stats() == copy.stats()
