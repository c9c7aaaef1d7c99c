"""Contract checks for :class:`~conformal_control.families.cbf.roles.ReferenceController`
plugins."""

from __future__ import annotations

import numpy as np

from ..families.cbf.roles import ReferenceController
from ._core import CheckList, ContractError, assert_unchanged, clone, expect, plugin_label, snapshot
from .common import (
    check_capabilities,
    check_docstring_parameters,
    check_get_params_round_trip,
    check_no_mutable_defaults,
    check_pickle_round_trip,
    check_repr,
    sample_behaviour,
)

__all__ = [
    "check_reference_controller",
    "check_reference_deterministic",
    "check_reference_no_mutation",
    "check_reference_output",
]

STATES = [
    np.array([0.0, 0.0, 0.0, 0.0]),
    np.array([3.0, -1.0, 0.5, 0.2]),
    np.array([9.5, 2.0, -1.0, 0.0]),
]
GOAL = np.array([10.0, 2.0])


def _call(ref: ReferenceController, state: np.ndarray, t: float, goal: np.ndarray) -> np.ndarray:
    try:
        out = ref(state, t, goal)
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(ref)}: expected ref(state, t, goal) to work (the environment "
            f"passes its current goal), got {type(exc).__name__}: {exc}"
        ) from exc
    return np.asarray(out)


def check_reference_output(reference: ReferenceController) -> None:
    """``ref(state, t, goal)`` returns a finite float velocity of shape (2,), goal included."""
    ref = clone(reference)
    ref.reset()
    for i, state in enumerate([*STATES, np.array([*GOAL, 0.0, 0.0])]):
        out = _call(ref, state, 0.1 * i, GOAL)
        expect(
            out.shape == (2,) and np.issubdtype(out.dtype, np.floating),
            ref,
            f"expected a float velocity of shape (2,), got shape {out.shape} dtype {out.dtype}",
        )
        expect(np.isfinite(out).all(), ref, f"expected a finite velocity, got {out.tolist()}")


def check_reference_no_mutation(reference: ReferenceController) -> None:
    """The state and goal arrays handed in are left unchanged."""
    ref = clone(reference)
    ref.reset()
    state, goal = STATES[1].copy(), GOAL.copy()
    before = snapshot((state, goal))
    _call(ref, state, 0.0, goal)
    assert_unchanged(before, (state, goal), ref, "(state, goal)", "ref(state, t, goal)")


def check_reference_deterministic(reference: ReferenceController) -> None:
    """Two fresh copies, reset, give the same velocities on the same inputs."""
    outs = []
    for _ in range(2):
        ref = clone(reference)
        ref.reset()
        outs.append([_call(ref, s, 0.0, GOAL) for s in STATES])
    same = all(np.array_equal(a, b) for a, b in zip(*outs, strict=True))
    expect(same, reference, "expected the same velocities from two fresh copies after reset()")


@sample_behaviour.register(ReferenceController)
def _behaviour(reference: ReferenceController) -> list[np.ndarray]:
    """Velocities at the sample states after ``reset()`` (for the pickling check)."""
    reference.reset()
    return [np.asarray(reference(s, 0.1 * i, GOAL)) for i, s in enumerate(STATES)]


check_reference_controller = CheckList(
    "reference",
    [
        check_get_params_round_trip,
        check_repr,
        check_capabilities,
        check_reference_output,
        check_reference_no_mutation,
        check_reference_deterministic,
        check_pickle_round_trip,
        check_docstring_parameters,
        check_no_mutable_defaults,
    ],
)
