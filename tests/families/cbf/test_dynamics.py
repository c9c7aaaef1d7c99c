"""Unicycle plants against their closed forms; rollouts against the step loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.families.cbf.dynamics import (
    DoubleIntegrator,
    Unicycle,
    UnicycleLookahead,
    VelocityTrackingDoubleIntegrator,
)
from conformal_control.families.cbf.roles import Dynamics


def test_exact_unicycle_follows_the_circle_of_constant_v_and_omega():
    # v = 0.5 m/s, omega = 0.4 rad/s: a circle of radius R = v / omega about the centre
    # c = p0 + R (-sin th0, cos th0); after t seconds the heading is th0 + omega t
    plant = Unicycle(v_max=1.0, omega_max=1.0)
    th0, v, w = 0.3, 0.5, 0.4
    x = plant.initial_state(np.array([1.0, -2.0]), th0)
    centre = np.array([1.0, -2.0]) + v / w * np.array([-math.sin(th0), math.cos(th0)])
    for k in range(1, 40):
        x = plant.step(x, np.array([v, w]), 0.25)
        th = th0 + w * 0.25 * k
        expected = centre + v / w * np.array([math.sin(th), -math.cos(th)])
        np.testing.assert_allclose(x[:2], expected, rtol=0, atol=1e-12)
        assert math.isclose(math.cos(x[4]), math.cos(th), abs_tol=1e-12)
        assert math.isclose(math.sin(x[4]), math.sin(th), abs_tol=1e-12)
        np.testing.assert_allclose(x[2:4], v * np.array([math.cos(th), math.sin(th)]), atol=1e-12)


def test_exact_unicycle_goes_straight_without_turning():
    plant = Unicycle()
    x = plant.step(plant.initial_state(np.zeros(2), 0.5), np.array([0.8, 0.0]), 2.0)
    np.testing.assert_allclose(x[:2], 1.6 * np.array([math.cos(0.5), math.sin(0.5)]), atol=1e-15)


def test_euler_unicycle_is_the_protocols_forward_euler_step():
    plant = Unicycle(integrator="euler")
    x = plant.initial_state(np.array([5.0, 1.0]), math.pi / 2)
    x1 = plant.step(x, np.array([0.6, 0.3]), 0.4)
    assert x1[0] == 5.0 + 0.4 * 0.6 * math.cos(math.pi / 2)
    assert x1[1] == 1.0 + 0.4 * 0.6 * math.sin(math.pi / 2)
    assert math.isclose(x1[4], math.pi / 2 + 0.12)


def test_unicycle_saturates_its_command():
    plant = Unicycle(v_min=-0.5, v_max=0.8, omega_max=0.7)
    x = plant.step(plant.initial_state(np.zeros(2)), np.array([3.0, -9.0]), 1.0)
    ref = plant.step(plant.initial_state(np.zeros(2)), np.array([0.8, -0.7]), 1.0)
    np.testing.assert_array_equal(x, ref)


def test_lookahead_point_moves_with_the_commanded_velocity():
    # the point l ahead of the centre is fully actuated: over a short step its velocity
    # is the command (to O(dt)) whatever the heading, also sideways
    plant = UnicycleLookahead(v_min=-5, v_max=5, omega_max=50, lookahead=0.3)
    for th in (0.0, 1.0, -2.5):
        x = plant.initial_state(np.array([1.0, 1.0]), th)
        u = np.array([-0.2, 0.4])
        dt = 1e-5
        x1 = plant.step(x, u, dt)

        def point(s):
            return s[:2] + 0.3 * np.array([math.cos(s[4]), math.sin(s[4])])

        np.testing.assert_allclose((point(x1) - point(x)) / dt, u, atol=1e-4)


@pytest.mark.parametrize(
    "plant",
    [
        DoubleIntegrator(),
        VelocityTrackingDoubleIntegrator(K_acc=4.0),
        Unicycle(),
        Unicycle(integrator="euler"),
        UnicycleLookahead(lookahead=0.25),
    ],
    ids=lambda p: type(p).__name__,
)
def test_vectorised_rollout_equals_the_step_loop(plant):
    rng = np.random.default_rng(3)
    x0 = plant.initial_state(np.array([0.5, -1.0]), 0.7)
    x0[2:4] = [0.3, -0.1] if plant.state_dim == 4 else x0[2:4]
    cmds = rng.uniform(-1.2, 1.2, (9, 6, 2))
    fast = plant.rollout(x0, cmds, 0.4)
    slow = Dynamics.rollout(plant, x0, cmds, 0.4)
    np.testing.assert_allclose(fast, slow, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"v_max": -0.5}, "need v_min <= 0 <= v_max"),
        ({"v_min": 0.2}, "need v_min <= 0 <= v_max"),
        ({"omega_max": -1.0}, "omega_max must be >= 0"),
        ({"v_max": math.nan}, "must be finite"),
        ({"integrator": "rk4"}, "integrator must be"),
    ],
)
def test_bad_unicycle_limits_give_one_line_errors(params, message):
    plant = Unicycle(**params)
    with pytest.raises(ValueError, match=message) as info:
        plant.step(plant.initial_state(np.zeros(2)), np.zeros(2), 0.1)
    assert "\n" not in str(info.value)


def test_bad_lookahead_is_a_one_line_error():
    plant = UnicycleLookahead(lookahead=0.0)
    with pytest.raises(ValueError, match="lookahead must be a finite distance > 0"):
        plant.step(plant.initial_state(np.zeros(2)), np.ones(2), 0.1)
