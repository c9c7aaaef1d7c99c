"""Sampling-MPC episodes in lockstep: every episode's candidate plans in one compiled call.

A batch of episodes of the ``mpc`` family (``mpc``, ``cc_mpc``) or of its subclasses
(``acp_mpc``, ``ecp_mpc``) that all reach a control instant together plans in three steps
(:func:`plan_all`): each episode's family samples and rolls out its candidates and states
its evaluation (:meth:`~conformal_control.families.mpc.controller.SamplingMPC.plan_begin`: its own
random stream, plant, predictions, safe distances, so its own numbers); ONE compiled call
evaluates the cost, clearance and violation of every candidate of every episode
(:func:`~conformal_control.families.mpc.kernels.evaluate_many`, the same compiled body per plan as a
single episode's call, so the same bits); each family then chooses its plan
(:meth:`~conformal_control.families.mpc.controller.SamplingMPC.plan_end`) and applies it at its next
``decide`` (:meth:`~conformal_control.families.mpc.controller.SamplingMPC.use_plan`). What an
episode
computes is what it computes alone; what the batch saves is the per-call overhead of the
evaluation (argument conversion, the dispatch into compiled code), once per control instant
for all episodes instead of once per episode.

**Measured: it does not pay at the planar protocol's size.** The 13 scenarios of ``cc_mpc``
(1,203 candidates of 12 steps per decision) take 3.7 ms of CPU per decided step in lockstep
(:func:`~conformal_control.experiments.bench.planar.run_scenarios`) against 3.1 ms one at a time
(``benchmarks/bench_mpc.py``, the better of two passes each, on a machine shared with other
jobs): the evaluation's call overhead is tens of microseconds, while the joint call copies
every episode's candidates (three arrays of 1,203 x 12 x 2) into one and works through 13
episodes' arrays instead of one episode's, hot in cache. Per decided step (a profile of the
lockstep run of zara1): the compiled evaluation about a quarter, sampling the candidates,
rolling them out (the half-angle cosines and sines in numpy, the compiled loop), the
predictions' interpolation, the stepper, the loss and the rule the rest -- each episode's
own Python, which a batch does not remove. The planar suite (``run_planar``) therefore runs
its scenarios one at a time; this path is the hook for a batch engine whose episodes'
sampling and rollouts are vectorised too.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from .controller import SamplingMPC
from .kernels import evaluate_many

__all__ = ["plan_all"]


def plan_all(requests: Sequence[tuple[Any, Any, float]]) -> int:
    """Plan, together, for every ``(family, state, lam)`` whose family is a sampling MPC
    about to plan (:meth:`~conformal_control.families.mpc.controller.SamplingMPC.will_plan`); the
    plan is applied by the family's next ``decide(state, lam)``, which must follow with
    the same state and lambda. Other requests are left alone (their ``decide`` plans as
    usual).

    Parameters
    ----------
    requests : sequence of (family, state, lam)
        The episodes' families, control states and lambdas at this control instant.

    Returns
    -------
    int
        How many plans were made.
    """
    todo = [
        (fam, fam.plan_begin(state, lam))
        for fam, state, lam in requests
        if isinstance(fam, SamplingMPC) and fam.will_plan()
    ]
    by_horizon: dict[int, list[int]] = {}
    for i, (_, inputs) in enumerate(todo):
        by_horizon.setdefault(int(inputs.positions.shape[1]), []).append(i)
    for group in by_horizon.values():
        results = evaluate_many([todo[i][1].problem for i in group])
        for i, (cost, clear, viol) in zip(group, results, strict=True):
            fam, inputs = todo[i]
            fam.use_plan(fam.plan_end(inputs, cost, clear, viol))
    return len(todo)
