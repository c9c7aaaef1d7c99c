"""The per-fleet loop with the robots' control instants stepped together, compiled.

:func:`~conformal_control.runs.fleet.drive` runs a fleet's robots one Python call chain at
a time (world ``state``, stepper and controller ``decide``, the filter's compiled step,
``broadcast``; then the world's ``apply``). :func:`drive_lockstep` runs the same loop with
the control instants of a frame in one call of
:func:`~conformal_control.runs.engines.fleet_kernels.fleet_instants`: at each instant
:func:`~conformal_control.runs.engines.fleet_kernels.fleet_decide` decides every robot whose
step the compiled step with robot rows decides alone (unconstrained or optimal), on the
controllers' own arrays (:meth:`ConformalCBFController.peer_step_form
<conformal_control.families.cbf.controller.ConformalCBFController.peer_step_form>`), and
:func:`~conformal_control.runs.engines.fleet_kernels.fleet_apply` moves the robots (plants,
goals, plan broadcast). A step it hands back (the priority stages of the people-first
order, the edge rule near an agent, a record to grow, a robot whose interval does not take
the compiled step) stops the call mid-instant: the world's clock is brought up to date and
the robot's own stepper decides it, as the loop decides it, counted
(:attr:`FleetRun.python_steps`); the call then goes on from the next robot. At a frame's
end (or once every robot is at its goal) the world's frame clock and log run
(:meth:`~conformal_control.world.multi.MultiRobotWorld.close_instants`). The sampling times
(sensing, predicting, learning) are the robots' own objects', as in the loop.

The results are the loop's, number for number (``tests/runs/test_fleet_lockstep.py``
compares every field but the timings): the same operations in the same order, each
decision recorded into the controller's own record and counted by its own counters.
:func:`lockstep_reason` says why a fleet is not run this way (then the loop runs it).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ....core.loop import ConformalStepper
from ....families.cbf.controller import ConformalCBFController, PeerStepForm
from ....world.multi import PARKED_SPEED, LockstepArrays, MultiRobotWorld
from ..fleet_kernels import fleet_instants

__all__ = ["FleetRun", "drive_lockstep", "lockstep_reason"]


def lockstep_reason(world: MultiRobotWorld, steppers: Sequence[ConformalStepper]) -> str | None:
    """Why :func:`drive_lockstep` does not run this fleet (None: it does), as one line.

    Parameters
    ----------
    world : MultiRobotWorld
        The fleet's world (reset or not).
    steppers : sequence of ConformalStepper
        One per robot.
    """
    for i, st in enumerate(steppers):
        if type(st) is not ConformalStepper:
            return f"robot {i}: a stepper of type {type(st).__name__}"
        fam = st.family
        if type(fam) is not ConformalCBFController:
            return f"robot {i}: the decision family {type(fam).__name__} (the CBF controller only)"
        rec = fam.reciprocity
        if rec is not None and rec.coordination != "none":
            return f"robot {i}: coordination={rec.coordination!r} (robots that say they yield)"
        if st.lambda_per != "run":
            return f"robot {i}: lambda run per {st.lambda_per}"
    return world.lockstep_reason()


@dataclass
class FleetRun:
    """What :func:`drive_lockstep` counted.

    Attributes
    ----------
    own : list of float
        Per robot, the time (s) spent in its own sensing, deciding and learning (a
        compiled call's time shared among the robots it decided).
    compiled_steps : int
        Decisions made by the compiled call.
    python_steps : int
        Decisions handed to the robots' own ``decide``.
    """

    own: list[float]
    compiled_steps: int = 0
    python_steps: int = 0


class _Robots:
    """The open interval's per-robot arrays for :func:`fleet_decide` (the controllers'
    forms, the kernel's lists of their arrays)."""

    def __init__(self, world: MultiRobotWorld, steppers: Sequence[ConformalStepper]) -> None:
        n = len(steppers)
        self.world = world
        self.steppers = steppers
        self.on = np.zeros(n, dtype=bool)
        self.lam = np.zeros(n)
        self.att = np.zeros((n, 2))
        self.npred = np.zeros(n, dtype=np.int64)
        self.nrec = np.zeros(n, dtype=np.int64)
        self.turns = np.zeros((n, 7))
        self.floors = np.zeros((n, 2))
        self.sensed = np.zeros((n, max(n, 1)), dtype=np.int64)
        self.n_sensed = np.zeros(n, dtype=np.int64)
        self.made = np.zeros(n, dtype=np.int64)
        self.t_dec = np.zeros(n)
        self.solves = np.zeros(n, dtype=np.int64)
        self.forms: list[PeerStepForm | None] = [None] * n
        self.order = np.zeros(0, dtype=np.int64)
        self.lists: tuple[Any, Any, Any, Any] = ([], [], [], [])

    def begin(self, active: list[int]) -> None:
        """Read every robot's form after its ``begin_interval``."""
        self.order = np.array(active, dtype=np.int64)
        self.on[:] = False
        for i in active:
            self._load(i)
        self._lists()

    def _load(self, i: int) -> None:
        st = self.steppers[i]
        fam = st.family
        assert isinstance(fam, ConformalCBFController)
        form = fam.peer_step_form()
        self.forms[i] = form
        if form is None or st.lams is not None:
            self.on[i] = False
            return
        robots = self.world.sensed_robots(i)
        ids = self.world.robot_ids[robots]
        if not np.array_equal(ids, form.peer_ids) or form.turn.shape != (7,):
            self.on[i] = False  # the robot's own decide says what is wrong
            return
        self.on[i] = True
        self.lam[i] = st.lam_
        self.att[i] = (form.k_att, form.v_max)
        self.npred[i] = form.npred
        self.nrec[i] = form.n
        self.turns[i] = form.turn
        self.floors[i] = form.floor
        self.n_sensed[i] = robots.size
        self.sensed[i, : robots.size] = robots

    def _lists(self) -> None:
        """The kernel's tuples of the active robots' arrays (a placeholder for a robot
        whose steps its own ``decide`` takes)."""
        z1, z2, z4 = np.zeros(1), np.zeros((3, 1)), np.zeros((2, 1, 1, 2))
        pv, col, buf, rec = [], [], [], []
        for i, f in enumerate(self.forms):  # all robots: one tuple length per fleet size
            f = f if self.on[i] else None
            pv.append(z4 if f is None else f.pv)
            col.append(z2 if f is None else f.col)
            buf.append(z1 if f is None else f.buf)
            rec.append(z1 if f is None else f.rec)
        self.lists = (tuple(pv), tuple(col), tuple(buf), tuple(rec))

    def flush(self, i: int) -> None:
        """Hand robot ``i``'s compiled decisions since the last flush to its objects."""
        made = int(self.made[i])
        if made:
            st = self.steppers[i]
            st.add_decisions(made)
            fam = st.family
            assert isinstance(fam, ConformalCBFController)
            fam.add_compiled_steps(made, int(self.solves[i]), float(self.t_dec[i]))
            self.made[i] = 0
            self.solves[i] = 0

    def reload(self, i: int) -> None:
        """Robot ``i``'s form again after a decision of its own (its record may have grown)."""
        old = self.forms[i]
        self._load(i)
        new = self.forms[i]
        if old is None or new is None or new.rec is not old.rec or new.buf is not old.buf:
            self._lists()


def drive_lockstep(
    world: MultiRobotWorld,
    steppers: Sequence[ConformalStepper],
    *,
    broadcast: bool = False,
    clock: Callable[[], float] = time.perf_counter,
) -> FleetRun:
    """:func:`~conformal_control.runs.fleet.drive` with each control instant's robots stepped
    together (see the module docstring); the same results. Call :func:`lockstep_reason`
    first (None).

    Parameters
    ----------
    world : MultiRobotWorld
        The crowd and the robots.
    steppers : sequence of ConformalStepper
        One per robot, in the world's order.
    broadcast : bool
        Each robot broadcasts its decided velocity to the others.
    clock : callable
        Gives the time (s) the robots' own work is measured with.
    """
    n = len(steppers)
    run = FleetRun([0.0] * n)
    own = run.own
    world.reset()
    for st in steppers:
        st.start()
    arr: LockstepArrays = world.lockstep()
    cmds = np.zeros((n, 2))
    yields = [getattr(st.family, "yielding", None) for st in steppers]
    cap = max(world.control_budget(), 1)
    st_t = np.zeros((n, cap))
    st_x = np.zeros((n, cap, 4))
    st_cmd = np.zeros((n, cap, 2))
    n_st = np.zeros(n, dtype=np.int64)
    t_goal = np.full(n, np.nan)
    scratch = np.zeros((n, 5))
    tally = np.zeros(1, dtype=np.int64)  # decisions of the compiled call
    clk = np.zeros(1)  # the time the compiled call's instants end at
    ran = np.zeros(1, dtype=np.int64)  # instants it ran
    rb = _Robots(world, steppers)
    while not world.done:
        active = [int(i) for i in world.active()]
        for i in active:
            t0 = clock()
            steppers[i].begin_interval(world.sense(i))
            own[i] += clock() - t0
        rb.begin(active)
        order = rb.order
        left = world.control_instants()
        start = 0
        while left > 0:
            t0 = clock()
            clk[0] = world.t
            ran[0] = 0
            pv, col, buf, rec = rb.lists
            p = fleet_instants(
                start, left, world.instants, world.substeps, clk, ran, order, rb.on, arr.x,
                arr.done, arr.parked, arr.step, arr.goal, arr.goals, arr.n_goals,
                arr.goal_radius, arr.dt, arr.plant, PARKED_SPEED, rb.lam, rb.att, rb.npred,
                rb.nrec, pv, col, buf, rec, rb.turns, rb.floors, rb.sensed, rb.n_sensed,
                arr.shares, arr.information, arr.plan_v, arr.next_v, arr.yielding,
                arr.next_yielding, broadcast, cmds, rb.made, rb.solves, rb.t_dec, scratch,
                tally, st_t, st_x, st_cmd, n_st, t_goal,
            )  # fmt: skip
            k = int(ran[0])
            left -= k
            reached = bool(np.isfinite(t_goal).any())
            world.close_instants(k, float(clk[0]), t_goal if reached else None, tick=p < 0)
            if reached:
                t_goal[:] = np.nan
            share = (clock() - t0) / max(len(active), 1)
            for i in active:
                own[i] += share
            if p >= 0:  # a step handed back, mid-instant: the robot's own decide
                i = int(order[p])
                t1 = clock()
                rb.flush(i)
                cmds[i] = steppers[i].decide(world.state(i))
                if broadcast:
                    yielding = yields[i]
                    world.broadcast(
                        i, cmds[i], None, yielding=False if yielding is None else bool(yielding())
                    )
                rb.reload(i)
                run.python_steps += 1
                own[i] += clock() - t1
                start = p + 1
                continue
            start = 0
            if world.done:
                break
        for i in active:
            rb.flush(i)
        for i in active:
            t0 = clock()
            steppers[i].end_interval(world.reveal(i))
            own[i] += clock() - t0
    run.compiled_steps = int(tally[0])
    for i in range(n):
        k = int(n_st[i])
        world.add_steps(i, st_t[i, :k], st_x[i, :k], st_cmd[i, :k])
    return run
