"""APF barrier: value against the literal formula, exact gradients, guards."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.families.cbf import APFBarrier


def literal_h(b: APFBarrier, x_ego: np.ndarray, x_agent: np.ndarray) -> float:
    """h = 1/(1 + U(rho)) - delta with U written exactly as in the paper."""
    d = float(np.linalg.norm(x_ego - x_agent))
    rho = d - b.d_c if b.convention == "surface" else d
    if rho <= 0:
        return -b.effective_delta
    u = 0.5 * b.K_rep * (1.0 / rho - 1.0 / b.rho0) ** 2 if rho < b.rho0 else 0.0
    return 1.0 / (1.0 + u) - b.effective_delta


BARRIERS = [
    APFBarrier(K_rep=0.0842, rho0=18.35, d_c=1.0, convention="surface"),
    APFBarrier(K_rep=0.0842, rho0=18.35, d_c=1.0, convention="centre"),
    APFBarrier(K_rep=2.0, rho0=5.0, d_c=0.7, convention="surface", delta=0.3),
]


@pytest.mark.parametrize("barrier", BARRIERS, ids=lambda b: f"{b.convention}-{b.K_rep}")
def test_value_matches_literal_formula(barrier: APFBarrier) -> None:
    rng = np.random.default_rng(0)
    ego = rng.uniform(-10, 10, size=(200, 2))
    agent = ego + rng.uniform(-8, 8, size=(200, 2))
    h = barrier.value(ego, agent)
    expected = [literal_h(barrier, e, a) for e, a in zip(ego, agent, strict=True)]
    np.testing.assert_allclose(h, expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("barrier", BARRIERS, ids=lambda b: f"{b.convention}-{b.K_rep}")
def test_gradients_match_central_differences(barrier: APFBarrier) -> None:
    rng = np.random.default_rng(1)
    eps = 1e-6
    checked = 0
    for _ in range(300):
        ego = rng.uniform(-5, 5, size=2)
        agent = ego + rng.normal(size=2) * rng.uniform(0.2, 10)
        d = np.linalg.norm(ego - agent)
        rho = d - barrier.d_c if barrier.convention == "surface" else d
        if not (1e-3 < rho < barrier.rho0 - 1e-3):
            continue  # the two kinks (overlap, rho0) are tested separately
        _, g_ego, g_agent = barrier.evaluate(ego, agent)
        fd_ego = np.array(
            [
                (barrier.value(ego + eps * e, agent) - barrier.value(ego - eps * e, agent))
                / (2 * eps)
                for e in np.eye(2)
            ]
        )
        fd_agent = np.array(
            [
                (barrier.value(ego, agent + eps * e) - barrier.value(ego, agent - eps * e))
                / (2 * eps)
                for e in np.eye(2)
            ]
        )
        scale = max(1.0, np.abs(fd_ego).max())
        np.testing.assert_allclose(g_ego, fd_ego, atol=1e-6 * scale, rtol=1e-5)
        np.testing.assert_allclose(g_agent, fd_agent, atol=1e-6 * scale, rtol=1e-5)
        checked += 1
    assert checked > 100


def test_safe_gap_is_the_zero_level() -> None:
    b = APFBarrier(K_rep=40 * 0.045883871**2, rho0=400 * 0.045883871, d_c=1.0)
    # h >= 0 iff gap >= 1/(sqrt(2 (1/delta - 1)/K_rep) + 1/rho0): ~4.4 px ~ 0.2 m here
    delta = b.effective_delta
    gap = 1.0 / (np.sqrt(2.0 * (1.0 / delta - 1.0) / b.K_rep) + 1.0 / b.rho0)
    assert 0.15 < gap < 0.25
    h = b.value(np.array([0.0, 0.0]), np.array([b.d_c + gap, 0.0]))
    assert abs(h) < 1e-12


def test_centre_convention_is_zero_at_collision_distance() -> None:
    b = APFBarrier(K_rep=0.0842, rho0=18.35, d_c=1.0, convention="centre")
    assert abs(b.value(np.zeros(2), np.array([0.0, 1.0]))) < 1e-12
    # the paper's barrier read literally is almost flat: h in [-0.96, 0.036]
    assert b.upper_bound < 0.05


def test_guards_overlap_zero_distance_and_beyond_rho0() -> None:
    b = APFBarrier(K_rep=1.0, rho0=5.0, d_c=1.0)
    same = np.array([3.0, -2.0])
    for agent in (same, same + np.array([0.5, 0.0])):  # zero distance, overlap
        h, g_e, g_a = b.evaluate(same, agent)
        assert h == pytest.approx(-0.5)
        assert np.all(np.isfinite(g_e)) and np.all(g_e == 0) and np.all(g_a == 0)
    h, g_e, _ = b.evaluate(same, same + np.array([7.0, 0.0]))
    assert h == pytest.approx(b.upper_bound) and np.all(g_e == 0)
    # continuity across the overlap boundary and across rho0
    for rho in (1e-9, b.rho0 - 1e-9):
        h_in = b.value(np.zeros(2), np.array([b.d_c + rho, 0.0]))
        h_edge = b.value(np.zeros(2), np.array([b.d_c + (0.0 if rho < 1 else b.rho0), 0.0]))
        assert h_in == pytest.approx(h_edge, abs=1e-6)


def test_broadcasting_over_steps_and_agents() -> None:
    b = BARRIERS[0]
    ego = np.zeros((7, 1, 2))
    agents = np.random.default_rng(2).normal(size=(7, 5, 2)) * 5
    h, g_e, g_a = b.evaluate(ego, agents)
    assert h.shape == (7, 5) and g_e.shape == (7, 5, 2)
    np.testing.assert_array_equal(g_a, -g_e)
    h0 = b.value(ego[3, 0], agents[3, 2])
    assert h[3, 2] == h0


@pytest.mark.parametrize(
    "kwargs",
    [
        {"K_rep": 0.0},
        {"K_rep": -1.0},
        {"rho0": 0.0},
        {"d_c": -1.0},
        {"convention": "edge"},
        {"K_rep": float("nan")},
    ],
)
def test_nonsensical_parameters_are_rejected(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        APFBarrier(**kwargs).evaluate(np.zeros(2), np.ones(2))
