"""The edge rule: never drive at an agent already within the collision distance.

Issue 30: on overlap the APF barrier is flat (h = -delta, no gradient), so the row could
not be met, every fallback made it vacuous and the nominal velocity drove straight at the
pedestrian. With the edge rule (``ConformalConstraint(edge="escape")``, the default) the
filter neutralises the overlapped agents' rows and decides within the escape polygon
(``kernels2d.escape_polygon``). These tests hold every fallback, both filter backends,
the fused compiled step and the multi-robot paths to it, on constructed cases and on
random ones (hypothesis), and check that ``edge="paper"`` keeps the published behaviour.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog

from conformal_control.families.cbf import (
    APFBarrier,
    AttractiveField,
    ConformalCBFController,
    ConformalConstraint,
    ControlState,
    Exact2DSafetyFilter,
)
from conformal_control.families.cbf.filters.piqp import QPSafetyFilter
from conformal_control.families.cbf.kernels2d import ESCAPE_WIDTH
from conformal_control.families.cbf.reciprocal import PeerView, Reciprocity
from conformal_control.families.cbf.roles import EscapeRows, FilterResult, SafetyFilter
from conformal_control.families.cbf.speed import speed_polygon
from conformal_control.families.cbf.stepwise import StepwiseCBF, Stream
from conformal_control.predictors import ConstantVelocityPredictor

D_C = 1.0
V_MAX = 2.0
FALLBACKS = ("lambda_search", "relax", "brake", "hold", "goal_aware")
#: closing speed tolerated as round-off (m/s)
TOL = 1e-7


def closing(v: np.ndarray, x_ego: np.ndarray, x_agent: np.ndarray, v_agent: np.ndarray) -> float:
    """Rate at which the centre distance shrinks under the command v (m/s)."""
    u = (x_ego - x_agent) / np.hypot(*(x_ego - x_agent))
    return float(-(u @ (v - v_agent)))


def non_closing_exists(escape: EscapeRows, v_max: float = V_MAX, sides: int = 16) -> bool:
    """Whether some command of the speed polygon closes in on none of the agents (an LP)."""
    S, s, _, _ = speed_polygon(sides, v_max)
    k = escape.U.shape[0]
    if not k:
        return True
    # max t s.t. U v + c >= t, S v <= s
    A_ub = np.vstack(
        [np.column_stack([-escape.U, np.ones(k)]), np.column_stack([S, np.zeros(len(S))])]
    )
    b_ub = np.concatenate([escape.c, s])
    res = linprog([0.0, 0.0, -1.0], A_ub=A_ub, b_ub=b_ub, bounds=[(None, None)] * 2 + [(None, 1.0)])
    return bool(res.status == 0 and -res.fun >= -1e-9)


# ------------------------------------------------------------------------------ constructed cases
#: six positions within d_c = 1 m of the robot at the origin (the issue's and more)
POSITIONS = ((0.3, 0.0), (0.9, 0.0), (0.05, 0.0), (0.2, -0.3), (-0.5, 0.5), (0.0, 0.99))


def stepwise(
    fallback: str, compiled: bool = True, edge: str = "escape", escape_margin: float | None = None
) -> StepwiseCBF:
    filt = Exact2DSafetyFilter(v_max=V_MAX, fallback=fallback, compiled_step=compiled)
    barrier = APFBarrier(rho0=10.0, d_c=D_C)
    ctrl = StepwiseCBF(
        "constant_velocity",
        epsilon=-0.1,
        eta=0.5,
        stream=Stream(tau=0.4, dt=0.1),
        barrier=barrier,
        safety_filter=filt,
    )
    ctrl.constraint.edge = edge
    if escape_margin is not None:
        ctrl.constraint.escape_margin = escape_margin
    ctrl.controller.reset()
    return ctrl


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("fallback", FALLBACKS)
@pytest.mark.parametrize("position", POSITIONS)
def test_no_command_closes_in_on_a_pedestrian_within_the_collision_distance(
    position, fallback, compiled
) -> None:
    ctrl = stepwise(fallback, compiled)
    ped = np.array(position)
    ctrl.observe([1], ped[None], t=0.0)
    v = ctrl.step(np.zeros(4), t=0.0, goal=np.array([10.0, 0.0]))
    assert closing(v, np.zeros(2), ped, np.zeros(2)) <= TOL
    # and it moves out at the push speed escape_gain (d_c + escape_margin - d), as far as
    # the speed set allows (its support is at least v_max cos(pi/16); the push rows are
    # loosened by ESCAPE_WIDTH v_max when they bind)
    c = ctrl.constraint
    push = c.escape_gain * (D_C + c.escape_margin - np.hypot(*ped))
    reach = V_MAX * (math.cos(math.pi / 16) - ESCAPE_WIDTH)
    assert closing(v, np.zeros(2), ped, np.zeros(2)) <= -min(push, reach) + 1e-9
    assert np.hypot(*v) <= V_MAX * (1 + 1e-12)


@pytest.mark.parametrize("fallback", FALLBACKS)
def test_paper_mode_keeps_the_published_behaviour(fallback) -> None:
    # edge="paper": the flat row is made vacuous by the fallback, as published (issue 30)
    ctrl = stepwise(fallback, edge="paper")
    ctrl.observe([1], np.array([[0.3, 0.0]]), t=0.0)
    v = ctrl.step(np.zeros(4), t=0.0, goal=np.array([10.0, 0.0]))
    expected = [0.0, 0.0] if fallback in ("brake", "hold") else [2.0, 0.0]
    np.testing.assert_allclose(v, expected, atol=1e-9)


@pytest.mark.parametrize("escape_margin", [None, 0.0])
def test_an_overlapping_pedestrian_does_not_loosen_the_others_rows(escape_margin) -> None:
    """Issue 30: a pedestrian glued to the robot's side at 0.71 m raised the shared lambda,
    and the minimum distance to a second one ahead over 1 s fell from 1.499 m to 1.001 m.

    Without an escape margin the glued pedestrian changes that distance by less than
    0.05 m (+0.027); with the default margin (0.1 m) the robot, pushed out of the glued
    pedestrian's disc at 1.95 m/s instead of 1.45, also keeps further from the second one
    (+0.44 m): the glued pedestrian never brings the robot closer to anyone else."""

    def min_distance(with_glued: bool) -> float:
        ctrl = stepwise("lambda_search", escape_margin=escape_margin)
        x = np.zeros(4)
        goal = np.array([10.0, 0.0])
        ahead = np.array([2.6, 0.0])
        d_min = math.inf
        for k in range(10):
            t = 0.1 * k
            ids, pos = [2], [ahead]
            if with_glued:
                ids, pos = [1, 2], [x[:2] + np.array([0.0, 0.71]), ahead]
            ctrl.observe(ids, np.array(pos), t=t)
            for j in range(ctrl.substeps):
                v = ctrl.step(x, t=t + j * ctrl.dt_control, goal=goal)
                x = np.r_[x[:2] + v * ctrl.dt_control, v]
                d_min = min(d_min, float(np.hypot(*(x[:2] - ahead))))
        return d_min

    alone, glued = min_distance(False), min_distance(True)
    assert alone > D_C
    assert glued > alone - 0.05, (alone, glued)  # never loosened
    if escape_margin == 0.0:
        assert abs(glued - alone) < 0.05, (alone, glued)
    else:  # the margin's stronger push keeps the robot further from everyone
        assert glued > alone + 0.3, (alone, glued)


@pytest.mark.parametrize("compiled", [True, False])
def test_the_escape_margin_gets_the_robot_out_of_the_disc(compiled) -> None:
    """With ``escape_margin`` the push does not fade at the disc's edge: a robot 0.3 m
    inside a standing pedestrian's disc, its goal behind the pedestrian, is out within
    0.5 s; without the margin it only approaches the edge (still inside after 0.5 s)."""

    def distance_after(margin: float, seconds: float = 0.5) -> float:
        ctrl = stepwise("lambda_search", compiled, escape_margin=margin)
        x = np.zeros(4)
        ped = np.array([0.7, 0.0])
        goal = np.array([10.0, 0.0])
        for k in range(round(seconds / 0.1)):
            ctrl.observe([1], ped[None], t=0.1 * k)
            for j in range(ctrl.substeps):
                v = ctrl.step(x, t=0.1 * k + j * ctrl.dt_control, goal=goal)
                x = np.r_[x[:2] + v * ctrl.dt_control, v]
        return float(np.hypot(*(x[:2] - ped)))

    assert distance_after(0.2) >= D_C
    assert distance_after(0.0) < D_C


# ------------------------------------------------------------------------------ random cases
@st.composite
def crowds(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Robot at the origin, 1-6 pedestrians (one or more within d_c), a nominal, lambda."""
    n_in = draw(st.integers(1, 3))
    n_out = draw(st.integers(0, 3))
    coord = st.floats(-1.0, 1.0, allow_nan=False)
    angle = st.floats(-math.pi, math.pi)
    pos = []
    for _ in range(n_in):
        r, a = draw(st.floats(0.02, 0.98)), draw(angle)
        pos.append([r * math.cos(a), r * math.sin(a)])
    for _ in range(n_out):
        r, a = draw(st.floats(1.05, 6.0)), draw(angle)
        pos.append([r * math.cos(a), r * math.sin(a)])
    vel = [[draw(coord) * 1.5, draw(coord) * 1.5] for _ in pos]
    nominal = np.array([draw(coord) * 2.5, draw(coord) * 2.5])
    lam = draw(st.sampled_from([5.0, 0.0, -1.0, -5.0, -50.0, -200.0]))
    return np.zeros(2), np.array(pos), np.array(vel), nominal, lam


CONSTRAINT = ConformalConstraint(APFBarrier(K_rep=1.0, rho0=10.0, d_c=D_C), a=10.0)


def filters(fallback: str) -> list[SafetyFilter]:
    out: list[SafetyFilter] = [
        Exact2DSafetyFilter(v_max=V_MAX, fallback=fallback),
        QPSafetyFilter(v_max=V_MAX, fallback=fallback),
    ]
    for f in out:
        f.reset()
    return out


def fused(fallback: str) -> Exact2DSafetyFilter:
    f = Exact2DSafetyFilter(v_max=V_MAX, fallback=fallback)
    f.reset()
    f.configure_apf((1.0, 10.0, D_C, 0.5, True), 10.0, CONSTRAINT.edge_settings())
    return f


def check_edge(res: FilterResult, escape: EscapeRows) -> None:
    v = res.decision
    assert np.hypot(*v) <= V_MAX * (1 + 1e-9)
    if non_closing_exists(escape):
        assert escape.closing(v).max() <= TOL, (v, escape)


@settings(max_examples=60, deadline=None)
@given(crowds(), st.sampled_from(FALLBACKS))
def test_every_fallback_and_backend_keeps_the_edge_rule(case, fallback) -> None:
    x, xp, vp, nominal, lam = case
    A, b = CONSTRAINT.rows(x, xp, vp)
    escape = CONSTRAINT.escape(x, xp, vp)
    assert escape is not None
    results = []
    # the agents' predicted times to contact, as the fused step hands them to goal_aware
    ttc = fused(fallback).contact_times(x, xp, vp, nominal)
    for f in filters(fallback):
        res = f.solve_escaping(nominal, A, b, lam, escape, ttc)
        check_edge(res, escape)
        results.append(res)
    # the fused compiled step: the same rows built in the kernel, the same decision
    res = fused(fallback).step_apf(x, xp, vp, nominal, lam)
    check_edge(res, escape)
    np.testing.assert_allclose(res.decision, results[0].decision, atol=1e-8)
    assert res.fallback == results[0].fallback


@settings(max_examples=40, deadline=None)
@given(crowds())
def test_hold_never_repeats_a_closing_command(case) -> None:
    x, xp, vp, nominal, lam = case
    A, b = CONSTRAINT.rows(x, xp, vp)
    escape = CONSTRAINT.escape(x, xp, vp)
    for f in [*filters("hold"), fused("hold")]:
        # the previous decision: full speed at the first overlapping pedestrian
        toward = xp[escape.rows[0]] / max(np.hypot(*xp[escape.rows[0]]), 1e-9) * V_MAX * 0.99
        f.solve(toward, np.zeros((0, 2)), np.zeros(0), 0.0)
        if isinstance(f, Exact2DSafetyFilter) and f.fused and f._prm[12] >= 0:
            res = f.step_apf(x, xp, vp, nominal, min(lam, -1e3))
        else:
            res = f.solve_escaping(nominal, A, b, min(lam, -1e3), escape)
        check_edge(res, escape)


def test_a_filter_without_the_rule_brakes_instead_of_closing_in() -> None:
    class Naive(SafetyFilter):
        def solve(self, nominal, A, b, lam):  # the nominal unchanged
            return FilterResult(np.asarray(nominal, dtype=float), "unconstrained", lam)

    x, xp, vp = np.zeros(2), np.array([[0.4, 0.0]]), np.zeros((1, 2))
    A, b = CONSTRAINT.rows(x, xp, vp)
    escape = CONSTRAINT.escape(x, xp, vp)
    res = Naive().solve_escaping(np.array([2.0, 0.0]), A, b, 0.0, escape)
    assert res.fallback == "escape" and np.array_equal(res.decision, [0.0, 0.0])
    away = Naive().solve_escaping(np.array([-1.0, 0.5]), A, b, 0.0, escape)
    assert away.status == "unconstrained"


def test_no_non_closing_command_minimises_the_largest_closing_speed() -> None:
    # two pedestrians walking at the robot from opposite sides faster than it can go
    x = np.zeros(2)
    xp = np.array([[0.5, 0.0], [-0.5, 0.0]])
    vp = np.array([[-3.0, 0.0], [2.5, 0.0]])
    A, b = CONSTRAINT.rows(x, xp, vp)
    escape = CONSTRAINT.escape(x, xp, vp)
    assert not non_closing_exists(escape)
    for f in filters("lambda_search"):
        res = f.solve_escaping(np.array([1.0, 0.0]), A, b, 0.0, escape)
        assert res.fallback == "escape"
        # the worst closing speed is 2.75 m/s whatever the robot does (v_x = -0.25)
        assert escape.closing(res.decision).max() == pytest.approx(2.75, abs=1e-6)


# ------------------------------------------------------------------------------ several robots
def robot_controller(compiled: bool, fallback: str = "lambda_search") -> ConformalCBFController:
    return ConformalCBFController(
        ConstantVelocityPredictor(),
        ConformalConstraint(APFBarrier(K_rep=0.5, rho0=5.0, d_c=0.7), a=2.0),
        Exact2DSafetyFilter(v_max=1.5, fallback=fallback, compiled_step=compiled),
        AttractiveField(K_att=1.0, v_max=1.5),
        substeps=2,
        reciprocity=Reciprocity("reciprocal", "pedestrians", 0.1, 0.3, "last"),
    )


@pytest.mark.parametrize("fallback", ["lambda_search", "brake", "hold", "relax"])
def test_the_rule_holds_with_robot_rows(fallback) -> None:
    from conformal_control.predictors import PredictionQuery

    rng = np.random.default_rng(11)
    seen = 0
    for _trial in range(12):
        n_ped, n_rob = 3, 2
        hist = (
            rng.uniform(-1.2, 1.2, size=(n_ped + n_rob, 1, 2))
            + np.linspace(0, 0.3, 6)[None, :, None]
        )
        q = PredictionQuery(
            ids=np.arange(n_ped + n_rob) + 1,
            history=hist,
            dt=0.1,
            horizon=3,
            robot=np.r_[np.zeros(n_ped, bool), np.ones(n_rob, bool)],
        )
        ctrls = [robot_controller(True, fallback), robot_controller(False, fallback)]
        for c in ctrls:
            c.reset()
            c.begin_interval(q)
        for step in range(6):
            x = np.r_[rng.uniform(-0.5, 0.5, 2), 0.0, 0.0]
            view = PeerView(q.ids[n_ped:], hist[n_ped:, -1], np.array([0.5, 0.5]))
            state = ControlState(x, 0.05 * step, step, np.array([5.0, 1.0]), view)
            lam = float(rng.uniform(-3.0, 0.5))
            decisions = [c.decide(state, lam) for c in ctrls]
            escape = ctrls[1].escape_rows(state)
            np.testing.assert_allclose(decisions[0], decisions[1], atol=1e-8)
            if escape is not None and escape.U.shape[0]:
                seen += 1
                if non_closing_exists(escape, 1.5):
                    assert escape.closing(decisions[0]).max() <= TOL
    assert seen >= 5  # the cases did put pedestrians within the collision distance


def test_escape_rows_are_none_without_overlap_and_in_paper_mode() -> None:
    x, xp, vp = np.zeros(2), np.array([[1.5, 0.0], [0.0, 2.0]]), np.zeros((2, 2))
    assert CONSTRAINT.escape(x, xp, vp) is None
    paper = ConformalConstraint(APFBarrier(d_c=D_C), a=10.0, edge="paper")
    assert paper.escape(x, np.array([[0.5, 0.0]]), np.zeros((1, 2))) is None
    esc = CONSTRAINT.escape(x, np.array([[0.5, 0.0], [3.0, 0.0]]), np.array([[1.0, 0.0], [0, 0]]))
    assert esc is not None and esc.rows.tolist() == [0]
    np.testing.assert_allclose(esc.U, [[-1.0, 0.0]])
    np.testing.assert_allclose(esc.c, [1.0])  # walking away at 1 m/s: distance grows at 1
    np.testing.assert_allclose(
        esc.push, [CONSTRAINT.escape_gain * (0.5 + CONSTRAINT.escape_margin)]
    )
    with pytest.raises(ValueError, match="edge must be one of"):
        ConformalConstraint(APFBarrier(), edge="off").validate()
    with pytest.raises(ValueError, match="collision_distance"):
        ConformalConstraint(APFBarrier(), collision_distance=-1.0).validate()
    with pytest.raises(ValueError, match="escape_gain"):
        ConformalConstraint(APFBarrier(), escape_gain=math.nan).validate()
    for bad in (-0.1, math.inf, "0.2", True):
        with pytest.raises(ValueError, match="escape_margin must be a finite number >= 0"):
            ConformalConstraint(APFBarrier(), escape_margin=bad).validate()


def test_filter_counts_the_rule_deciding_alone() -> None:
    x = np.zeros(2)
    xp = np.array([[0.5, 0.0], [-0.5, 0.0]])
    vp = np.array([[-3.0, 0.0], [2.5, 0.0]])
    f = fused("lambda_search")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = f.step_apf(x, xp, vp, np.array([1.0, 0.0]), 0.0)
    assert res.fallback == "escape" and math.isnan(res.lambda_applied)
    assert f.stats()["n_fallback_escape"] == 1


# ------------------------------------------------------------------------------ lambda's floor
def test_the_cbf_gets_a_default_lambda_floor_unless_the_run_gives_one() -> None:
    from conformal_control.core.exceptions import InputError
    from conformal_control.data import load_scene
    from conformal_control.families.cbf.feasibility import DEFAULT_FLOOR_SHARE
    from conformal_control.runs.build import build_flagship

    scene = load_scene("crossing", seed=0)
    fl = build_flagship(scene, {"a": 4.0}, units="si")
    floor = -fl.constraint.a * fl.barrier.upper_bound  # the feasibility floor, -a h_max
    assert fl.rule.lambda_min == pytest.approx(DEFAULT_FLOOR_SHARE * floor)
    # widened by the user; none in paper mode (Algorithm 1 as published)
    assert build_flagship(scene, {"lambda_min": -100.0}, units="si").rule.lambda_min == -100.0
    assert build_flagship(scene, {"edge": "paper"}, units="si").rule.lambda_min == -math.inf
    with pytest.raises(InputError, match="lambda_min must not exceed lambda_max") as info:
        build_flagship(scene, {"lambda_min": 1.0, "lambda_max": 0.0}, units="si")
    assert "\n" not in str(info.value)
    with pytest.raises(InputError, match="edge must be") as info:
        build_flagship(scene, {"edge": "off"}, units="si")
    assert "\n" not in str(info.value)
    # the step-wise controller's default rule too (a = 10/s, h_max = 1/2)
    ctrl = StepwiseCBF(epsilon=-0.1, eta=0.5)
    assert ctrl.stepper.rule.lambda_min == pytest.approx(-DEFAULT_FLOOR_SHARE * 10.0 * 0.5)


def test_a_fixed_lambda_below_the_default_floor_runs_at_that_lambda() -> None:
    # the default floor clipped a fixed lambda of -45/s to -40/s without a count (issue 31's
    # fixed-lambda grid): a default never overrides the run's own lambda_init
    from conformal_control.data import load_scene
    from conformal_control.families.cbf.feasibility import DEFAULT_FLOOR_SHARE
    from conformal_control.runs.build import build_flagship

    scene = load_scene("crossing", seed=0)
    fl = build_flagship(scene, {"a": 4.0}, units="si")
    floor = DEFAULT_FLOOR_SHARE * -fl.constraint.a * fl.barrier.upper_bound
    below = floor - 0.25
    fixed = build_flagship(scene, {"a": 4.0, "lambda_init": below, "eta": 0.0}, units="si")
    assert fixed.rule.lambda_min == below and fixed.rule.reset() == below
    assert any("the run's lambda_init" in n for n in fixed.params.notes)
    # above the floor the default stays; a floor the run gives is kept (and then a
    # lambda_init below it is an error, not a clip)
    above = build_flagship(scene, {"a": 4.0, "lambda_init": floor + 0.25}, units="si")
    assert above.rule.lambda_min == pytest.approx(floor)
    given = build_flagship(scene, {"a": 4.0, "lambda_init": below, "lambda_min": floor}, units="si")
    with pytest.raises(ValueError, match=r"initial lambda .* lies outside"):
        given.rule.reset()
    # the same through a rule given by name with its own lambda_init
    dt = build_flagship(scene, {"a": 4.0}, units="si", rule=("fixed_eta", {"lambda_init": below}))
    assert dt.rule.lambda_min == below


def test_a_default_lambda_init_starts_inside_the_bounds_a_given_one_never_moves() -> None:
    from conformal_control.data import load_scene
    from conformal_control.runs.build import build_flagship

    scene = load_scene("crossing", seed=0)
    fl = build_flagship(scene, {"lambda_max": -0.5}, units="si")
    assert fl.rule.reset() == -0.5 and fl.params.si["lambda_init"] == -0.5
    assert any("lambda_init: -0.5 (SI), the default 0 moved" in n for n in fl.params.notes)
    named = build_flagship(scene, {}, units="si", rule=("fixed_eta", {"lambda_max": -0.5}))
    assert named.rule.reset() == -0.5
    given = build_flagship(scene, {"lambda_max": -0.5, "lambda_init": 0.0}, units="si")
    with pytest.raises(ValueError, match=r"initial lambda \(0\) lies outside"):
        given.rule.reset()


def test_a_fixed_lambda_below_the_default_floor_is_the_episodes_lambda() -> None:
    import conformal_control as cc
    from conformal_control.core.exceptions import GoalNotReachedWarning

    unit = 30.0  # the crossing scene's lambda is per frame at 30 frames per second
    with pytest.warns(GoalNotReachedWarning):
        m = cc.run("crossing", params={"lambda_init": -45 / unit, "eta": 0.0}).metrics
    assert m["lambda_mean"] == m["lambda_min"] == -1.5 and m["n_lambda_clipped"] == 0


def test_the_escape_margin_is_a_run_parameter() -> None:
    from conformal_control.core.exceptions import InputError
    from conformal_control.data import load_scene
    from conformal_control.runs.build import build_flagship

    scene = load_scene("crossing", seed=0)
    default = build_flagship(scene, {}, units="si").constraint
    assert default.escape_margin == 0.1
    assert default.edge_settings()[2] == 0.1  # what the compiled step is handed
    given = build_flagship(scene, {"escape_margin": 0.3}, units="si").constraint
    assert given.escape_margin == 0.3 and given.edge_settings()[2] == 0.3
    for bad in (-0.1, math.nan, math.inf):
        with pytest.raises(InputError, match="escape_margin must be a finite number >= 0") as info:
            build_flagship(scene, {"escape_margin": bad}, units="si")
        assert "\n" not in str(info.value)
