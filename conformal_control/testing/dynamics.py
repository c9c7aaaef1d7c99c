"""Contract checks for :class:`~conformal_control.families.cbf.roles.Dynamics` plugins."""

from __future__ import annotations

import math

import numpy as np

from ..families.cbf.roles import Dynamics
from ._core import (
    CheckList,
    ContractError,
    assert_unchanged,
    clone,
    close,
    expect,
    plugin_label,
    snapshot,
)
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
    "check_dynamics",
    "check_dynamics_bad_dt",
    "check_dynamics_deterministic",
    "check_dynamics_no_mutation",
    "check_dynamics_output",
    "check_dynamics_rollout",
    "check_dynamics_zero_dt",
]

COMMAND = np.array([0.4, -0.3])


def _state(d: Dynamics) -> np.ndarray:
    n = int(getattr(d, "state_dim", 4))
    return np.linspace(0.5, 2.0, n)


def _step(d: Dynamics, state: np.ndarray, command: np.ndarray, dt: float) -> np.ndarray:
    try:
        out = d.step(state, command, dt)
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(d)}: expected step(state, command, dt={dt:g}) to work, got "
            f"{type(exc).__name__}: {exc}"
        ) from exc
    return np.asarray(out)


def check_dynamics_output(dynamics: Dynamics) -> None:
    """``step`` returns a new finite float array of shape ``(state_dim,)``."""
    d = clone(dynamics)
    s = _state(d)
    out = _step(d, s, COMMAND, 0.1)
    expect(
        out.shape == s.shape and np.issubdtype(out.dtype, np.floating),
        d,
        f"expected a float state of shape {s.shape}, got shape {out.shape} dtype {out.dtype}",
    )
    expect(np.isfinite(out).all(), d, f"expected a finite next state, got {out.tolist()}")
    expect(out is not s, d, "expected step() to return a new array, got the input state")
    pos, vel = np.asarray(d.position(out)), np.asarray(d.velocity(out))
    expect(
        pos.shape == (2,) and vel.shape == (2,),
        d,
        f"expected position()/velocity() of shape (2,), got {pos.shape}/{vel.shape}",
    )


def check_dynamics_zero_dt(dynamics: Dynamics) -> None:
    """Holding a command for zero seconds leaves the state unchanged."""
    d = clone(dynamics)
    s = _state(d)
    out = _step(d, s, COMMAND, 0.0)
    expect(
        close(out, s, rtol=0, atol=1e-12), d, f"expected step(dt=0) == state, got {out.tolist()}"
    )


def check_dynamics_no_mutation(dynamics: Dynamics) -> None:
    """``step`` leaves state and command untouched."""
    d = clone(dynamics)
    s, c = _state(d), COMMAND.copy()
    before = snapshot((s, c))
    _step(d, s, c, 0.1)
    assert_unchanged(before[0], s, d, "state", "step()")
    assert_unchanged(before[1], c, d, "command", "step()")


def check_dynamics_deterministic(dynamics: Dynamics) -> None:
    """Same state, command and dt give the same next state."""
    a = _step(clone(dynamics), _state(dynamics), COMMAND, 0.1)
    b = _step(clone(dynamics), _state(dynamics), COMMAND, 0.1)
    expect(close(a, b, rtol=0, atol=0), dynamics, "expected step() to be deterministic")


def check_dynamics_bad_dt(dynamics: Dynamics) -> None:
    """A NaN or negative dt gives a clear ValueError."""
    d = clone(dynamics)
    for dt in (math.nan, -0.1):
        try:
            out = d.step(_state(d), COMMAND, dt)
        except ValueError:
            continue
        except Exception as exc:
            raise ContractError(
                f"{plugin_label(d)}: expected a ValueError for dt={dt}, got "
                f"{type(exc).__name__}: {exc}"
            ) from exc
        raise ContractError(
            f"{plugin_label(d)}: expected a ValueError for dt={dt}, got state "
            f"{np.asarray(out).tolist()}"
        )


def check_dynamics_rollout(dynamics: Dynamics) -> None:
    """``rollout`` of several command sequences equals :meth:`step` applied in a loop
    (to 1e-9 relative), returns shape ``(N, H, state_dim)`` and leaves its inputs
    unchanged."""
    d = clone(dynamics)
    s = _state(d)
    rng = np.random.default_rng(0)
    cmds = rng.uniform(-1.0, 1.0, (4, 3, 2))
    before = snapshot((s, cmds))
    try:
        out = np.asarray(d.rollout(s, cmds, 0.1))
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(d)}: expected rollout(state, commands (4, 3, 2), 0.1) to work, "
            f"got {type(exc).__name__}: {exc}"
        ) from exc
    assert_unchanged(before[0], s, d, "state", "rollout()")
    assert_unchanged(before[1], cmds, d, "commands", "rollout()")
    expect(
        out.shape == (4, 3, s.size),
        d,
        f"expected rollout() of shape (4, 3, {s.size}), got {out.shape}",
    )
    for i in range(4):
        x = s
        for j in range(3):
            x = _step(d, x, cmds[i, j], 0.1)
            expect(
                close(out[i, j], x, rtol=1e-9, atol=1e-12),
                d,
                f"expected rollout()[{i}, {j}] to equal step() in a loop, got "
                f"{out[i, j].tolist()} against {x.tolist()}",
            )


@sample_behaviour.register(Dynamics)
def _behaviour(dynamics: Dynamics) -> list[np.ndarray]:
    """Three steps from the sample state (for the pickling check)."""
    x, out = _state(dynamics), []
    for _ in range(3):
        x = np.asarray(dynamics.step(x, COMMAND, 0.1))
        out.append(x)
    return out


#: Every dynamics check, in order.
check_dynamics = CheckList(
    "dynamics",
    [
        check_get_params_round_trip,
        check_repr,
        check_capabilities,
        check_dynamics_output,
        check_dynamics_zero_dt,
        check_dynamics_no_mutation,
        check_dynamics_deterministic,
        check_dynamics_bad_dt,
        check_dynamics_rollout,
        check_pickle_round_trip,
        check_docstring_parameters,
        check_no_mutable_defaults,
    ],
)
