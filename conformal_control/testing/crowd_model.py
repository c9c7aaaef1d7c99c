"""Contract checks for :class:`~conformal_control.world.crowds.base.CrowdModel` plugins.

A crowd model moves simulated pedestrians one time step at a time among agents it only
sees (the robot first). The checks drive it on a small crowd of its own for a few seconds:

* ``check_crowd_model_deterministic`` -- the same seed gives the same pedestrians, bit for
  bit (a model's noise comes from the generator ``reset`` hands it, nothing else);
* ``check_crowd_model_finite`` -- positions and velocities keep their shape, stay finite
  (no NaN, no inf) and in the scene, speeds within each pedestrian's bound;
* ``check_crowd_model_far_robot`` -- a robot far beyond every interaction range changes
  nothing: the pedestrians move exactly as with no robot at all;
* ``check_crowd_model_no_mutation`` -- ``step`` returns new arrays and leaves its inputs
  as they were.
"""

from __future__ import annotations

import numpy as np

from ..world.crowds.base import CrowdModel
from ._core import CheckList, ContractError, clone, plugin_label
from .common import (
    check_capabilities,
    check_docstring_parameters,
    check_get_params_round_trip,
    check_no_mutable_defaults,
    check_pickle_round_trip,
    check_repr,
)

__all__ = [
    "check_crowd_model",
    "check_crowd_model_deterministic",
    "check_crowd_model_far_robot",
    "check_crowd_model_finite",
    "check_crowd_model_no_mutation",
]

#: Time step (s) and steps of a check's episode (3 s).
DT, STEPS = 0.1, 30
#: Where the far robot stands (m): beyond any pedestrian model's interaction range.
FAR = 1.0e6


def _crowd(seed: int = 0) -> tuple[np.ndarray, ...]:
    """Six pedestrians crossing a 10 m square: pos, vel, radius, v_pref, v_max."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(0.0, 10.0, (6, 2))
    v_pref = rng.normal(0.0, 1.0, (6, 2))
    return pos, 0.5 * v_pref, np.full(6, 0.3), v_pref, np.full(6, 1.8)


def _robot(at: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if at is None:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0)
    return np.array([at], dtype=float), np.array([[0.5, 0.0]]), np.array([0.3])


def _run(
    model: CrowdModel, seed: int, robot: tuple[float, float] | None = (5.0, 5.0)
) -> tuple[np.ndarray, np.ndarray]:
    """The pedestrians' positions and velocities after :data:`STEPS` steps."""
    m = clone(model)
    m.reset(np.random.default_rng(seed))
    pos, vel, radius, v_pref, v_max = _crowd()
    other = _robot(robot)
    for k in range(STEPS):
        try:
            pos, vel = m.step(pos, vel, radius, v_pref, v_max, *other, DT)
        except Exception as exc:
            raise ContractError(
                f"{plugin_label(model)}: expected step() to work on a crowd of 6 "
                f"pedestrians (step {k}), got {type(exc).__name__}: {exc}"
            ) from exc
        pos, vel = np.asarray(pos), np.asarray(vel)
    return pos, vel


def check_crowd_model_deterministic(model: CrowdModel) -> None:
    """The same seed gives the same pedestrians, bit for bit."""
    a, b = _run(model, 7), _run(model, 7)
    if not (np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])):
        raise ContractError(
            f"{plugin_label(model)}: expected two runs reset with the same seed to move the "
            "pedestrians identically (draw noise only from the generator reset() gets)"
        )


def check_crowd_model_finite(model: CrowdModel) -> None:
    """Shapes kept; positions and velocities finite and in the scene; speeds bounded."""
    pos, vel = _run(model, 0)
    label = plugin_label(model)
    if pos.shape != (6, 2) or vel.shape != (6, 2):
        raise ContractError(
            f"{label}: expected step() to return positions and velocities of shape (6, 2), "
            f"got {pos.shape} and {vel.shape}"
        )
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
        raise ContractError(f"{label}: expected finite positions and velocities, got NaN/inf")
    if np.abs(pos).max() > 10.0 + 2.0 * STEPS * DT * 1.8 + 1.0:
        raise ContractError(
            f"{label}: a pedestrian left the scene (|position| {np.abs(pos).max():.3g} m after "
            f"{STEPS * DT:g} s at speeds of at most 1.8 m/s)"
        )
    speed = np.hypot(vel[:, 0], vel[:, 1])
    if np.any(speed > 1.8 * (1.0 + 1e-9)):
        raise ContractError(
            f"{label}: expected speeds within the bound v_max = 1.8 m/s, got {speed.max():.4g}"
        )


def check_crowd_model_far_robot(model: CrowdModel) -> None:
    """A robot far beyond every interaction range changes nothing."""
    alone = _run(model, 0, robot=None)
    far = _run(model, 0, robot=(FAR, FAR))
    if not (
        np.allclose(alone[0], far[0], rtol=0, atol=1e-12)
        and np.allclose(alone[1], far[1], rtol=0, atol=1e-12)
    ):
        raise ContractError(
            f"{plugin_label(model)}: a robot {FAR:g} m away changed the pedestrians' motion "
            "(an interaction without a range, or one that does not decay)"
        )


def check_crowd_model_no_mutation(model: CrowdModel) -> None:
    """``step`` returns new arrays and leaves its inputs unchanged."""
    m = clone(model)
    m.reset(np.random.default_rng(0))
    inputs = [*_crowd(), *_robot((5.0, 5.0))]
    before = [x.copy() for x in inputs]
    pos, vel = m.step(*inputs, DT)
    if any(not np.array_equal(x, y) for x, y in zip(inputs, before, strict=True)):
        raise ContractError(f"{plugin_label(model)}: step() modified its input arrays")
    if any(np.shares_memory(out, x) for out in (pos, vel) for x in inputs):
        raise ContractError(f"{plugin_label(model)}: step() returned a view of an input array")


check_crowd_model = CheckList(
    "crowd",
    [
        check_get_params_round_trip,
        check_repr,
        check_capabilities,
        check_pickle_round_trip,
        check_docstring_parameters,
        check_no_mutable_defaults,
        check_crowd_model_deterministic,
        check_crowd_model_finite,
        check_crowd_model_far_robot,
        check_crowd_model_no_mutation,
    ],
)
