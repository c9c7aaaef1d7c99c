"""The social force model: Moussaïd's interaction in closed form, integration, parameters."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.world.crowds import SocialForceModel

NONE2 = np.zeros((0, 2))
NONE1 = np.zeros(0)


def _model(**kw) -> SocialForceModel:
    m = SocialForceModel(**kw)
    m.reset(np.random.default_rng(0))
    return m


def test_head_on_interaction_is_pure_braking_with_the_papers_magnitude() -> None:
    # i at the origin walking +x at 1 m/s, j standing 2 m ahead: e = t = (1, 0), theta = 0,
    # D = lambda * 1 + 1 = 3, B = gamma * 3, f = -A exp(-d / B) t (Moussaïd et al. 2009)
    m = _model()
    fx, fy = m.pair_forces(np.array([2.0]), np.array([0.0]), np.array([1.0]), np.array([0.0]))
    expected = -4.5 * np.exp(-2.0 / (0.35 * 3.0))
    assert fx[0] == pytest.approx(expected, rel=1e-12)
    assert fy[0] == pytest.approx(0.0, abs=1e-15)


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_turning_term_steers_away_from_the_side_of_the_other(side: float) -> None:
    m = _model()
    # j slightly to the left (side = +1) or right of i's path: i is turned the other way
    fx, fy = m.pair_forces(
        np.array([3.0]), np.array([0.3 * side]), np.array([1.3]), np.array([0.0])
    )
    assert fx[0] < 0  # braking
    assert np.sign(fy[0]) == -side


def test_equal_velocities_and_coincident_agents_give_no_force() -> None:
    m = _model()
    fx, fy = m.pair_forces(np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1))
    assert fx[0] == 0.0 and fy[0] == 0.0


def test_alone_the_velocity_relaxes_to_the_preferred_one_within_tau() -> None:
    m = _model(tau=0.5)
    pos, vel = np.array([[0.0, 0.0]]), np.array([[0.2, 0.0]])
    v_pref = np.array([[1.2, 0.0]])
    dt = 0.1
    p, v = m.step(pos, vel, np.full(1, 0.3), v_pref, np.full(1, 5.0), NONE2, NONE2, NONE1, dt)
    assert v[0] == pytest.approx([0.2 + dt * (1.2 - 0.2) / 0.5, 0.0])
    assert p[0] == pytest.approx(dt * v[0])
    assert vel[0, 0] == 0.2  # inputs untouched


def test_speed_is_capped() -> None:
    m = _model(tau=0.05)
    _, v = m.step(
        np.zeros((1, 2)),
        np.zeros((1, 2)),
        np.full(1, 0.3),
        np.array([[10.0, 0.0]]),
        np.full(1, 1.5),
        NONE2,
        NONE2,
        NONE1,
        0.1,
    )
    assert np.hypot(*v[0]) == pytest.approx(1.5)


def test_overlapping_bodies_are_pushed_apart_and_the_cut_off_holds() -> None:
    m = _model(A=0.0)  # interaction off: only the body force is left
    pos = np.array([[0.0, 0.0]])
    zero = np.zeros((1, 2))
    args = (np.full(1, 0.3), zero, np.full(1, 10.0))
    # robot (radius 0.5) 0.6 m to the right: overlap 0.2 m -> pushed left
    _, v = m.step(pos, zero, *args, np.array([[0.6, 0.0]]), zero, np.array([0.5]), 0.01)
    assert v[0, 0] == pytest.approx(-0.01 * 1500.0 * 0.2)
    far = _model(neighbor_dist=5.0)
    _, v = far.step(pos, zero, *args, np.array([[6.0, 0.0]]), zero, np.array([0.5]), 0.01)
    assert np.all(v == 0.0)


def test_noise_is_seeded() -> None:
    def run(seed: int, noise: float) -> np.ndarray:
        m = SocialForceModel(noise=noise)
        m.reset(np.random.default_rng(seed))
        _, v = m.step(
            np.zeros((3, 2)) + np.arange(3)[:, None],
            np.zeros((3, 2)),
            np.full(3, 0.3),
            np.zeros((3, 2)),
            np.full(3, 2.0),
            NONE2,
            NONE2,
            NONE1,
            0.1,
        )
        return v

    assert np.array_equal(run(1, 0.5), run(1, 0.5))
    assert not np.array_equal(run(1, 0.5), run(2, 0.5))
    assert np.array_equal(run(1, 0.0), run(2, 0.0))


@pytest.mark.parametrize(
    "kw, word",
    [
        ({"tau": 0.0}, "tau"),
        ({"A": -1.0}, "A"),
        ({"gamma": float("nan")}, "gamma"),
        ({"noise": "x"}, "noise"),
        ({"neighbor_dist": 0}, "neighbor_dist"),
    ],
)
def test_bad_parameters_are_refused_at_reset(kw: dict, word: str) -> None:
    with pytest.raises(ValueError, match=word):
        SocialForceModel(**kw).reset()
