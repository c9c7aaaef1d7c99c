"""Contract checks for :class:`~conformal_control.families.cbf.roles.Barrier` plugins."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..families.cbf.roles import Barrier
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
    "check_barrier",
    "check_barrier_broadcasting",
    "check_barrier_deterministic",
    "check_barrier_gradient",
    "check_barrier_nan_propagates",
    "check_barrier_no_mutation",
    "check_barrier_output_shape",
    "check_barrier_safe_far_unsafe_at_contact",
    "check_barrier_upper_bound",
    "check_barrier_value_matches_evaluate",
    "sample_pairs",
]


def sample_pairs(n: int = 64, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Ego and agent positions (n, 2) in metres at 0.05-12 m from each other."""
    rng = np.random.default_rng(seed)
    ego = rng.uniform(-10.0, 10.0, size=(n, 2))
    dist = rng.uniform(0.05, 12.0, size=n)
    ang = rng.uniform(0.0, 2.0 * np.pi, size=n)
    agent = ego + dist[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    return ego, agent


def _evaluate(b: Barrier, x_ego: Any, x_agent: Any, what: str) -> tuple[np.ndarray, ...]:
    try:
        out = b.evaluate(x_ego, x_agent)
    except Exception as exc:
        raise ContractError(
            f"{plugin_label(b)}: expected evaluate() to handle {what}, got "
            f"{type(exc).__name__}: {exc}"
        ) from exc
    expect(
        isinstance(out, tuple) and len(out) == 3,
        b,
        f"expected evaluate() to return a tuple (h, dh_dego, dh_dagent), got {type(out).__name__}"
        + (f" of length {len(out)}" if isinstance(out, tuple) else ""),
    )
    return tuple(np.asarray(o) for o in out)


def _check_shapes(
    b: Barrier, out: tuple[np.ndarray, ...], lead: tuple[int, ...], what: str
) -> None:
    h, ge, ga = out
    for name, arr, shape in (
        ("h", h, lead),
        ("dh_dego", ge, (*lead, 2)),
        ("dh_dagent", ga, (*lead, 2)),
    ):
        expect(
            arr.shape == shape,
            b,
            f"expected {name} of shape {shape} for {what}, got {arr.shape}",
        )
        expect(
            np.issubdtype(arr.dtype, np.floating),
            b,
            f"expected {name} to be floating point, got dtype {arr.dtype}",
        )


# ---------------------------------------------------------------------------- checks
def check_barrier_output_shape(barrier: Barrier) -> None:
    """h has the broadcast leading shape, both gradients that shape + (2,), all floats."""
    b = clone(barrier)
    ego, agent = sample_pairs(8)
    _check_shapes(b, _evaluate(b, ego, agent, "(8, 2) inputs"), (8,), "(8, 2) inputs")
    _check_shapes(b, _evaluate(b, ego[0], agent[0], "single (2,) points"), (), "(2,) inputs")


def check_barrier_broadcasting(barrier: Barrier) -> None:
    """One ego against N agents, and (S, 1, 2) against (S, N, 2), as the controller and loss
    call it; results equal the element-wise ones."""
    b = clone(barrier)
    ego, agent = sample_pairs(12)
    agents = agent.reshape(3, 4, 2)
    egos = ego[:3]
    ref = _evaluate(b, np.repeat(egos[:, None, :], 4, axis=1), agents, "(3, 4, 2) inputs")
    _check_shapes(b, ref, (3, 4), "(3, 4, 2) inputs")
    got = _evaluate(b, egos[:, None, :], agents, "(3, 1, 2) against (3, 4, 2)")
    _check_shapes(b, got, (3, 4), "(3, 1, 2) against (3, 4, 2) inputs")
    one = _evaluate(b, egos[0], agents[0], "(2,) against (4, 2)")
    _check_shapes(b, one, (4,), "(2,) against (4, 2) inputs")
    for name, r, g, o in zip(("h", "dh_dego", "dh_dagent"), ref, got, one, strict=True):
        expect(
            close(r, g, rtol=1e-12, atol=1e-12) and close(r[0], o, rtol=1e-12, atol=1e-12),
            b,
            f"expected broadcast evaluation to equal element-wise evaluation for {name}",
        )


def check_barrier_value_matches_evaluate(barrier: Barrier) -> None:
    """``value()`` equals ``evaluate()[0]``."""
    b = clone(barrier)
    ego, agent = sample_pairs(16)
    h = _evaluate(b, ego, agent, "(16, 2) inputs")[0]
    v = np.asarray(b.value(ego, agent))
    expect(close(h, v, rtol=1e-12, atol=1e-12), b, "expected value() == evaluate()[0]")


def check_barrier_gradient(barrier: Barrier) -> None:
    """Both gradients match central finite differences of h at random smooth points."""
    b = clone(barrier)
    ego, agent = sample_pairs(64, seed=1)
    h, ge, ga = _evaluate(b, ego, agent, "(64, 2) inputs")
    for wrt, grad, base in (("ego", ge, ego), ("agent", ga, agent)):
        fd = np.zeros_like(grad, dtype=float)
        scale = np.maximum(1.0, np.abs(base))
        for k in range(2):
            step = np.zeros_like(base)
            step[:, k] = 1e-6 * scale[:, k]
            if wrt == "ego":
                hp, hm = b.value(base + step, agent), b.value(base - step, agent)
            else:
                hp, hm = b.value(ego, base + step), b.value(ego, base - step)
            fd[:, k] = (np.asarray(hp) - np.asarray(hm)) / (2.0 * step[:, k])
        err = np.abs(grad - fd)
        tol = 1e-5 * np.maximum(1.0, np.abs(fd)) + 1e-6
        # a random point may land on a kink: allow at most 1 of 64 mismatches
        bad = (err > tol).any(axis=-1)
        if bad.sum() > 1:
            i = int(np.argmax(bad))
            raise ContractError(
                f"{plugin_label(b)}: expected dh_d{wrt} to match central finite differences; at "
                f"ego={ego[i].tolist()}, agent={agent[i].tolist()} (h={float(h[i]):.6g}) "
                f"expected {fd[i].tolist()}, got {np.asarray(grad[i]).tolist()} "
                f"({int(bad.sum())} of {bad.size} points differ)"
            )


def check_barrier_no_mutation(barrier: Barrier) -> None:
    """evaluate() leaves its input arrays untouched."""
    b = clone(barrier)
    ego, agent = sample_pairs(8)
    agent[2] = np.nan
    before = snapshot((ego, agent))
    with np.errstate(invalid="ignore"):
        b.evaluate(ego, agent)
    assert_unchanged(before[0], ego, b, "x_ego", "evaluate()")
    assert_unchanged(before[1], agent, b, "x_agent", "evaluate()")


def check_barrier_deterministic(barrier: Barrier) -> None:
    """Same inputs, same outputs (also across fresh copies)."""
    ego, agent = sample_pairs(16)
    a = _evaluate(clone(barrier), ego, agent, "(16, 2) inputs")
    b = clone(barrier)
    _evaluate(b, ego[::-1].copy(), agent, "(16, 2) inputs")  # any internal state must not leak
    c = _evaluate(b, ego, agent, "(16, 2) inputs")
    for name, x, y in zip(("h", "dh_dego", "dh_dagent"), a, c, strict=True):
        expect(
            close(x, y, rtol=0, atol=0), b, f"expected repeated evaluate() to give the same {name}"
        )


def check_barrier_nan_propagates(barrier: Barrier) -> None:
    """A NaN position (missing truth) gives NaN h in that entry only; no exception.

    The loss evaluates the barrier on the true trajectories and masks missing samples by
    their NaN barrier values, so a barrier must neither raise nor return a finite value there.
    """
    b = clone(barrier)
    ego, agent = sample_pairs(6)
    ref = _evaluate(b, ego, agent, "(6, 2) inputs")[0]
    agent[2] = np.nan
    agent[4, 0] = np.nan
    with np.errstate(invalid="ignore"):
        h = _evaluate(b, ego, agent, "NaN agent positions (missing truth)")[0]
    expect(
        np.isnan(h[[2, 4]]).all(),
        b,
        f"expected h = NaN where the agent position is NaN, got {h[[2, 4]].tolist()}",
    )
    keep = [0, 1, 3, 5]
    expect(
        close(h[keep], ref[keep], rtol=0, atol=0),
        b,
        "expected entries without NaN to be unaffected by NaN entries elsewhere in the batch",
    )


def check_barrier_upper_bound(barrier: Barrier) -> None:
    """``upper_bound`` (if not None) is finite and bounds h everywhere, far away included."""
    b = clone(barrier)
    ub = b.upper_bound
    if ub is None:
        return
    expect(np.isfinite(ub), b, f"expected upper_bound to be finite or None, got {ub!r}")
    ego, agent = sample_pairs(64)
    far = ego + 1e4 * (agent - ego)
    for what, a in (("sampled", agent), ("far", far)):
        h = _evaluate(b, ego, a, f"{what} points")[0]
        expect(
            (h <= ub + 1e-9 * max(1.0, abs(ub))).all(),
            b,
            f"expected h <= upper_bound = {ub:g} at {what} points, got max h = {h.max():g}",
        )


def check_barrier_safe_far_unsafe_at_contact(barrier: Barrier) -> None:
    """A collision barrier: h < 0 when the two positions coincide, h > 0 100 m apart."""
    b = clone(barrier)
    x = np.array([1.0, 2.0])
    h0 = float(_evaluate(b, x, x.copy(), "coincident positions")[0])
    expect(h0 < 0, b, f"expected h < 0 (unsafe) for coincident positions, got h = {h0:g}")
    hf = float(_evaluate(b, x, x + np.array([100.0, 0.0]), "positions 100 m apart")[0])
    expect(hf > 0, b, f"expected h > 0 (safe) for positions 100 m apart, got h = {hf:g}")


@sample_behaviour.register(Barrier)
def _behaviour(barrier: Barrier) -> tuple[np.ndarray, ...]:
    """``evaluate`` at 16 sample pairs (for the pickling check)."""
    ego, agent = sample_pairs(16, seed=7)
    return tuple(np.asarray(o) for o in barrier.evaluate(ego, agent))


#: Every barrier check, in order.
check_barrier = CheckList(
    "barrier",
    [
        check_get_params_round_trip,
        check_repr,
        check_capabilities,
        check_barrier_output_shape,
        check_barrier_broadcasting,
        check_barrier_value_matches_evaluate,
        check_barrier_gradient,
        check_barrier_no_mutation,
        check_barrier_deterministic,
        check_barrier_nan_propagates,
        check_barrier_upper_bound,
        check_barrier_safe_far_unsafe_at_contact,
        check_pickle_round_trip,
        check_docstring_parameters,
        check_no_mutable_defaults,
    ],
)
