"""The compiled APF control step returns what the generic Python path returns."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conformal_control.core import registry
from conformal_control.families.cbf import (
    APFBarrier,
    AttractiveField,
    ConformalCBFController,
    ConformalConstraint,
    Exact2DSafetyFilter,
    VelocityTrackingDoubleIntegrator,
)
from conformal_control.families.cbf import kernels2d as k
from conformal_control.families.cbf.reciprocal import Reciprocity
from conformal_control.runs.params import resolve_params
from conformal_control.world.replay import ReplayEnvironment


def twin_controllers(scene, params, fallback="lambda_search"):
    """The replay environment, and two controllers differing only in the compiled step
    (the paper's APF barrier, attractive field and tracking law, from the run parameters)."""
    resolved = resolve_params(scene, params)
    si = resolved.si
    scene = dataclasses.replace(
        scene,
        robot_radius=si["robot_radius"],
        agent_radius=si["agent_radius"],
        goal_radius=si["goal_radius"],
        v_max=si["v_max"],
    )
    env = ReplayEnvironment(
        scene,
        VelocityTrackingDoubleIntegrator(K_acc=si["K_acc"]),
        tau_frames=resolved.tau_frames,
        substeps=si["substeps"],
        sensing_radius=si["sensing_radius"],
        history_frames=resolved.history_frames,
    )
    barrier = APFBarrier(
        K_rep=si["K_rep"],
        rho0=si["rho0"],
        d_c=si["robot_radius"] + si["agent_radius"],
        convention=si["convention"],
        delta=si["delta"],
    )
    constraint = ConformalConstraint(barrier, a=si["a"])
    reference = AttractiveField(K_att=si["K_att"], v_max=si["v_max"])

    def controller(compiled: bool) -> ConformalCBFController:
        f = Exact2DSafetyFilter(
            v_max=si["v_max"],
            fallback=fallback,
            speed_sides=si["speed_sides"],
            compiled_step=compiled,
        )
        return ConformalCBFController(
            registry.create("predictor", "constant_velocity"),
            constraint,
            f,
            reference,
            substeps=si["substeps"],
        )

    return env, controller(True), controller(False)


def run_lockstep(env, fused, generic, schedule) -> dict[str, int]:
    """Drive the scene with the compiled controller; at every control instant the generic
    one decides on the same state and lambda. Returns the statuses seen."""
    env.reset()
    fused.reset()
    generic.reset()
    assert fused._fused and not generic._fused
    seen: dict[str, int] = {}
    k_int = 0
    while not env.done:
        lam = schedule[k_int % len(schedule)]
        obs = env.sense()
        fused.begin_interval(obs)
        generic.begin_interval(obs)
        for _ in range(env.control_instants()):
            st = env.state()
            d1 = fused.decide(st, lam)
            d2 = generic.decide(st, lam)
            np.testing.assert_allclose(d1, d2, rtol=0, atol=1e-9)
            env.apply(d1)
            if env.done:
                break
        env.reveal()
        r1, r2 = fused.interval_record(), generic.interval_record()
        assert r1.status == r2.status
        np.testing.assert_allclose(r1.lam_applied, r2.lam_applied, rtol=1e-9, atol=1e-9)
        for s in r1.status:
            seen[s] = seen.get(s, 0) + 1
        k_int += 1
    assert fused.stats() == generic.stats()
    return seen


PARAMS = {"a": 10, "K_rep": 40, "tau": 4, "eta": 1, "epsilon": -0.25}


@pytest.mark.data
def test_compiled_step_matches_python_path_on_nexus4(nexus4) -> None:
    env, fused, generic = twin_controllers(nexus4, PARAMS)
    floor = fused.constraint.lambda_floor()
    # lambda from above the floor to below it (every step there falls back)
    seen = run_lockstep(env, fused, generic, [0.0, 0.95 * floor, 1.5 * floor, 0.8 * floor])
    assert seen.get("optimal", 0) > 10 and seen.get("lambda_search", 0) > 100
    assert seen.get("unconstrained", 0) > 20


@pytest.mark.parametrize("fallback", ["lambda_search", "brake", "hold", "relax"])
def test_compiled_step_matches_python_path_on_crossing(crossing, fallback) -> None:
    env, fused, generic = twin_controllers(crossing, {"a": 2.0}, fallback=fallback)
    floor = fused.constraint.lambda_floor()
    seen = run_lockstep(env, fused, generic, [0.0, 0.9 * floor, 2.0 * floor])
    assert seen.get("optimal", 0) > 5 and seen.get(fallback, 0) > 5


@pytest.mark.parametrize("fallback", ["lambda_search", "relax"])
def test_compiled_acp_step_matches_its_python_path(crossing, fallback) -> None:
    """The acp family's compiled step (the barrier's d_c raised per horizon step, no
    slack) decides as its generic path (constraint_rows, slack 0)."""
    from conformal_control.families.cbf.acp import ACPController

    env, fused, generic = twin_controllers(crossing, {"a": 2.0}, fallback=fallback)
    parts = ("predictor", "constraint", "safety_filter", "reference", "substeps")
    fused = ACPController(**{k: getattr(fused, k) for k in parts}, window=50, max_inflation=0.6)
    generic = ACPController(**{k: getattr(generic, k) for k in parts}, window=50, max_inflation=0.6)
    # levels: infinite regions (capped), finite ones, empty ones
    seen = run_lockstep(env, fused, generic, [0.0, 0.3, 0.1, 0.6, 1.0, 0.05])
    assert fused.n_capped_ > 10 and fused.n_scored_ > 100
    assert seen.get("optimal", 0) > 5 and seen.get("unconstrained", 0) > 5


def test_other_barriers_and_fallbacks_take_the_generic_path(crossing) -> None:
    class MyAPF(APFBarrier):
        """A subclass may change the barrier: not fused."""

    _, fused, _ = twin_controllers(crossing, {"a": 2.0})
    fused.constraint.barrier = MyAPF(**fused.constraint.barrier.get_params())
    fused.reset()
    assert not fused._fused
    # a fallback the compiled step does not decide (relax) decides on its rows in Python,
    # but not with robots (their rows are built by the generic path)
    _, relax, _ = twin_controllers(crossing, {"a": 2.0}, fallback="relax")
    relax.reset()
    assert relax._fused
    relax.reciprocity = Reciprocity()
    relax.reset()
    assert not relax._fused


def test_kernels_run_interpreted_too() -> None:
    # the compiled functions are plain Python: their originals give the same answers
    rng = np.random.default_rng(1)
    S = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    s = np.full(4, 2.0)
    verts = np.array([[2.0, 2.0], [-2.0, 2.0], [-2.0, -2.0], [2.0, -2.0]])
    for _ in range(20):
        m = 5
        A, b = rng.normal(size=(m, 2)), rng.normal(size=m) - 1.0
        out = k.smallest_lambda(A, b, S, s, verts, 2.0**0.5 * 2, np.zeros((m, 2)), np.zeros(m))
        lam, v0, v1 = out
        assert np.all(A @ [v0, v1] + b + lam >= -1e-12)
        G, h = np.zeros((m + 4, 2)), np.zeros(m + 4)
        ok1 = k.solve_rows(1.0, 3.0, A, b + lam + 1e-6, S, s, 2.9, G, h)
        ok2 = k.solve_rows.py_func(1.0, 3.0, A, b + lam + 1e-6, S, s, 2.9, G, h)
        assert ok1[0] and ok2[0]
        np.testing.assert_allclose(ok1[1:], ok2[1:], atol=1e-12)
