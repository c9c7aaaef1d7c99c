"""The crowd-model contract checks catch what they promise to catch."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.testing import ContractError, check_crowd_model
from conformal_control.testing.crowd_model import (
    check_crowd_model_deterministic,
    check_crowd_model_far_robot,
    check_crowd_model_finite,
    check_crowd_model_no_mutation,
)
from conformal_control.world.crowds.base import CrowdModel
from conformal_control.world.crowds.social_force import SocialForceModel


class Walker(CrowdModel):
    """Walks at the preferred velocity, clipped to the bound (a model that is right).

    Parameters
    ----------
    gain : float
        Fraction of the preferred velocity walked.
    """

    def __init__(self, gain: float = 1.0) -> None:
        self.gain = gain

    def step(self, pos, vel, radius, v_pref, v_max, other_pos, other_vel, other_radius, dt):
        v = self.gain * v_pref
        speed = np.hypot(v[:, 0], v[:, 1])
        v = v * np.minimum(1.0, v_max / np.maximum(speed, 1e-12))[:, None]
        return pos + dt * v, v


class Jittery(Walker):
    """Noise from a generator of its own, not the one reset() hands it."""

    def step(self, *args):
        pos, vel = super().step(*args)
        return pos + np.random.default_rng().normal(0, 1e-3, pos.shape), vel


class Exploding(Walker):
    """Speeds without bound."""

    def step(self, pos, vel, radius, v_pref, v_max, other_pos, other_vel, other_radius, dt):
        return pos + dt * 50 * v_pref, 50 * v_pref


class Gravity(Walker):
    """Attracted by the robot at any distance (1/r^2 without a range)."""

    def step(self, pos, vel, radius, v_pref, v_max, other_pos, other_vel, other_radius, dt):
        pos, vel = super().step(pos, vel, radius, v_pref, v_max, other_pos, other_vel,
                                other_radius, dt)  # fmt: skip
        for p in other_pos:
            d = p - pos
            pos = pos + dt * d / np.maximum((d**2).sum(axis=1, keepdims=True), 1.0)
        return pos, vel


class InPlace(Walker):
    """Moves the pedestrians by writing into the input arrays."""

    def step(self, pos, vel, radius, v_pref, v_max, other_pos, other_vel, other_radius, dt):
        pos += dt * v_pref
        return pos, vel


def test_a_right_model_and_the_shipped_one_pass():
    for model in (Walker(), SocialForceModel()):
        for check in check_crowd_model:
            check(model)


@pytest.mark.parametrize(
    ("model", "check", "words"),
    [
        (Jittery(), check_crowd_model_deterministic, "same seed"),
        (Exploding(), check_crowd_model_finite, "left the scene"),
        (Gravity(), check_crowd_model_far_robot, "changed the pedestrians"),
        (InPlace(), check_crowd_model_no_mutation, "modified its input"),
    ],
)
def test_each_check_fails_a_model_that_breaks_it(model, check, words):
    with pytest.raises(ContractError, match=words):
        check(model)
