"""A fleet's control instant in two compiled calls: every robot's decision, then the world.

The lockstep engine of fleets (:mod:`conformal_control.runs.engines.batch.fleet`) calls
:func:`fleet_decide` and :func:`fleet_apply` once per control instant instead of the
per-fleet loop's chain of Python calls per robot
(:func:`conformal_control.runs.fleet.drive`: the world's ``state``, the stepper's and the
controller's ``decide``, the filter's compiled step, ``broadcast``, then the world's
``apply``).

:func:`fleet_decide` is, for each robot under way, what
:meth:`MultiRobotWorld.state <conformal_control.world.multi.MultiRobotWorld.state>` and
:meth:`ConformalCBFController.decide
<conformal_control.families.cbf.controller.ConformalCBFController.decide>` compute on the
compiled path with robot rows: the attractive field's nominal velocity (Python's hypot,
as :meth:`AttractiveField.velocity
<conformal_control.families.cbf.reference.AttractiveField.velocity>`), the peer view (the
sensed robots' positions now, the robot's shares -- 1 with a parked peer -- and the
references the information option gives) and
:func:`~conformal_control.families.cbf.kernels_peers.apf_control_peers` on the
controller's own arrays; a step that kernel decides (unconstrained or optimal) is recorded
and broadcast here; any other step is handed back (nothing counted, the last decision kept)
and the caller decides it with the robot's own objects. :func:`fleet_apply` is
:meth:`MultiRobotWorld.apply <conformal_control.world.multi.MultiRobotWorld.apply>` up to
its frame clock: the velocity-tracking plants (the operations of the plant's ``step`` in
Python floats, in the same order), the goal check (Python's hypot), the per-instant record
and the plan broadcast.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.jit import kernel
from ...families.cbf.kernels2d import HEADER, OPTIMAL, RECORD_FIELDS, UNCONSTRAINED
from ...families.cbf.kernels_peers import apf_control_peers
from ...families.cbf.pyhypot import py_hypot

__all__ = ["fleet_apply", "fleet_decide", "fleet_instants"]

jit = kernel(cache=True, nogil=True)

#: Where the filter's buffer holds its last decision (two entries).
LAST = HEADER - 2


@jit
def fleet_decide(
    start: int,
    robots: np.ndarray,
    on: np.ndarray,
    x: np.ndarray,
    done: np.ndarray,
    step: np.ndarray,
    goal: np.ndarray,
    goals: np.ndarray,
    lam: np.ndarray,
    att: np.ndarray,
    npred: np.ndarray,
    nrec: np.ndarray,
    pvs: tuple[np.ndarray, ...],
    cols: tuple[np.ndarray, ...],
    bufs: tuple[np.ndarray, ...],
    recs: tuple[np.ndarray, ...],
    turns: np.ndarray,
    floors: np.ndarray,
    sensed: np.ndarray,
    n_sensed: np.ndarray,
    shares: np.ndarray,
    info: int,
    plan_v: np.ndarray,
    next_v: np.ndarray,
    next_yield: np.ndarray,
    broadcast: bool,
    cmds: np.ndarray,
    made: np.ndarray,
    solves: np.ndarray,
    t_dec: np.ndarray,
    t: float,
    scratch: np.ndarray,
    tally: np.ndarray,
) -> int:
    """Decide the control instant of robots ``robots[start:]`` (those not ``done``); returns
    -1, or the position in ``robots`` of the first robot whose step the caller decides
    (robots after it are not run: call again from the next one).

    Per robot ``i`` (arrays indexed by robot): ``on[i]``, whether its interval's decisions
    go through the compiled step (else every step is handed back); its state ``x[i]``,
    control instant ``step[i]``, waypoint ``goals[i, goal[i]]``, lambda ``lam[i]``, the
    attractive field's ``(K_att, v_max)`` ``att[i]``; its controller's arrays
    (:class:`~conformal_control.families.cbf.controller.PeerStepForm`): ``pvs[i]``,
    ``cols[i]``, ``bufs[i]``, ``recs[i]`` (tuples over every robot of the fleet),
    ``turns[i]``, ``floors[i]``, ``npred[i]`` and the record's next row ``nrec[i]``; the
    robots it sensed ``sensed[i, :n_sensed[i]]`` (its peers, in order) and the fleet's
    ``shares``. ``info``: the world's information option (-1 none, 0 position, 1
    velocity, 2 plan; ``plan_v`` the broadcast velocities). A decided step writes
    ``cmds[i]``, counts ``made[i]`` (and ``solves[i]``: optimal ones) and advances
    ``nrec[i]`` and sets ``t_dec[i] = t`` (the time now); with ``broadcast`` it is
    broadcast (``next_v[i]``, not yielding). ``scratch`` (R, 5): the peers' positions and
    references; ``tally[0]`` counts the decisions made.
    """
    for p in range(start, robots.shape[0]):
        i = robots[p]
        if done[i]:
            continue
        if not on[i]:
            return p
        rec = recs[i]
        rows = rec.shape[0] // RECORD_FIELDS
        r = nrec[i]
        if r == rows:  # the record is full: the controller grows it
            return p
        x0 = x[i, 0]
        x1 = x[i, 1]
        # AttractiveField.velocity: -K_att (X - goal), saturated at v_max (Python's hypot)
        g = goal[i]
        kneg = -att[i, 0]
        n0 = kneg * (x0 - goals[i, g, 0])
        n1 = kneg * (x1 - goals[i, g, 1])
        speed = py_hypot(n0, n1)
        if speed > att[i, 1]:
            f = att[i, 1] / speed
            n0 *= f
            n1 *= f
        # the peer view: positions now, shares (1 with a parked peer), references
        k = n_sensed[i]
        col = cols[i]
        m = npred[i]
        o0 = 0.0
        o1 = 0.0
        any_done = False
        for j in range(done.shape[0]):
            if done[j]:
                any_done = True
                break
        for q in range(k):
            j = sensed[i, q]
            scratch[q, 0] = x[j, 0]
            scratch[q, 1] = x[j, 1]
            sh = shares[i, j]
            if any_done and done[j]:
                sh = 1.0
            col[0, m + q] = sh
            if info == 2:
                scratch[q, 2] = plan_v[j, 0]
                scratch[q, 3] = plan_v[j, 1]
            elif info == 1:
                scratch[q, 2] = x[j, 2]
                scratch[q, 3] = x[j, 3]
            else:
                scratch[q, 2] = 0.0
                scratch[q, 3] = 0.0
        if k:
            if info == 2:
                o0 = plan_v[i, 0]
                o1 = plan_v[i, 1]
            elif info == 1:
                o0 = x[i, 2]
                o1 = x[i, 3]
        buf = bufs[i]
        last0 = buf[LAST]
        last1 = buf[LAST + 1]
        code = apf_control_peers(
            x0, x1, n0, n1, lam[i], step[i], r, pvs[i], buf, rec, col, m,
            scratch[:k, 0:2], scratch[:k, 2:4], o0, o1, turns[i], x[i, 2], x[i, 3], floors[i],
        )  # fmt: skip
        if code != UNCONSTRAINED and code != OPTIMAL:
            buf[LAST] = last0  # as before the call: the caller decides the step
            buf[LAST + 1] = last1
            return p
        v0 = rec[2 * rows + 2 * r]
        v1 = rec[2 * rows + 2 * r + 1]
        if broadcast and not (math.isfinite(v0) and math.isfinite(v1)):
            return p  # the caller's decide, and the world's broadcast error
        cmds[i, 0] = v0
        cmds[i, 1] = v1
        nrec[i] = r + 1
        made[i] += 1
        solves[i] += code
        t_dec[i] = t
        tally[0] += 1
        if broadcast:
            next_v[i, 0] = v0
            next_v[i, 1] = v1
            next_yield[i] = False
    return -1


@jit
def fleet_apply(
    x: np.ndarray,
    done: np.ndarray,
    parked: np.ndarray,
    step: np.ndarray,
    goal: np.ndarray,
    goals: np.ndarray,
    n_goals: np.ndarray,
    radius: float,
    t: float,
    dt: float,
    plant: np.ndarray,
    parked_speed: float,
    cmds: np.ndarray,
    st_t: np.ndarray,
    st_x: np.ndarray,
    st_cmd: np.ndarray,
    n_st: np.ndarray,
    t_goal: np.ndarray,
    plan: bool,
    plan_v: np.ndarray,
    next_v: np.ndarray,
    yielding: np.ndarray,
    next_yield: np.ndarray,
) -> int:
    """:meth:`MultiRobotWorld.apply <conformal_control.world.multi.MultiRobotWorld.apply>`'s
    robots for one control instant ending at ``t``: each robot under way applies
    ``cmds[i]`` through its plant (``plant[i]`` = ``K``, ``exp(-K dt)``, ``-expm1(-K dt)``),
    its instant is recorded (``st_t[i, n_st[i]]``, ``st_x``, ``st_cmd``) and its goal
    checked (the last one reached: ``t_goal[i] = t``, ``done[i]``); a robot at its goal
    brakes (commanded to stop) until slower than ``parked_speed`` (``parked[i]``). With
    ``plan`` the broadcast velocities and flags of this instant become visible (a robot
    at its goal broadcasts standing still). Returns how many robots reached their last
    goal."""
    r = x.shape[0]
    reached = 0
    for i in range(r):
        k = plant[i, 0]
        dec = plant[i, 1]
        g = plant[i, 2]
        if done[i]:
            if not parked[i]:
                d0 = x[i, 2] - 0.0
                d1 = x[i, 3] - 0.0
                a0 = x[i, 0] + 0.0 * dt + d0 * g / k
                a1 = x[i, 1] + 0.0 * dt + d1 * g / k
                a2 = 0.0 + d0 * dec
                a3 = 0.0 + d1 * dec
                if py_hypot(a2, a3) < parked_speed:
                    a2 = 0.0
                    a3 = 0.0
                    parked[i] = True
                x[i, 0] = a0
                x[i, 1] = a1
                x[i, 2] = a2
                x[i, 3] = a3
            continue
        c0 = cmds[i, 0]
        c1 = cmds[i, 1]
        d0 = x[i, 2] - c0
        d1 = x[i, 3] - c1
        x0 = x[i, 0] + c0 * dt + d0 * g / k
        x1 = x[i, 1] + c1 * dt + d1 * g / k
        x[i, 0] = x0
        x[i, 1] = x1
        x[i, 2] = c0 + d0 * dec
        x[i, 3] = c1 + d1 * dec
        step[i] += 1
        j = n_st[i]
        st_t[i, j] = t
        for c in range(4):
            st_x[i, j, c] = x[i, c]
        st_cmd[i, j, 0] = c0
        st_cmd[i, j, 1] = c1
        n_st[i] = j + 1
        q = goal[i]
        while q < n_goals[i] and py_hypot(x0 - goals[i, q, 0], x1 - goals[i, q, 1]) <= radius:
            q += 1
        if q >= n_goals[i]:
            q = n_goals[i] - 1
            t_goal[i] = t
            done[i] = True
            reached += 1
        goal[i] = q
    if plan:
        for i in range(r):
            if done[i]:
                next_v[i, 0] = 0.0
                next_v[i, 1] = 0.0
            plan_v[i, 0] = next_v[i, 0]
            plan_v[i, 1] = next_v[i, 1]
            yielding[i] = next_yield[i] and not done[i]
    return reached


@jit
def fleet_instants(
    start: int,
    n_left: int,
    instants: int,
    substeps: int,
    clock: np.ndarray,
    ran: np.ndarray,
    robots: np.ndarray,
    on: np.ndarray,
    x: np.ndarray,
    done: np.ndarray,
    parked: np.ndarray,
    step: np.ndarray,
    goal: np.ndarray,
    goals: np.ndarray,
    n_goals: np.ndarray,
    radius: float,
    dt: float,
    plant: np.ndarray,
    parked_speed: float,
    lam: np.ndarray,
    att: np.ndarray,
    npred: np.ndarray,
    nrec: np.ndarray,
    pvs: tuple[np.ndarray, ...],
    cols: tuple[np.ndarray, ...],
    bufs: tuple[np.ndarray, ...],
    recs: tuple[np.ndarray, ...],
    turns: np.ndarray,
    floors: np.ndarray,
    sensed: np.ndarray,
    n_sensed: np.ndarray,
    shares: np.ndarray,
    info: int,
    plan_v: np.ndarray,
    next_v: np.ndarray,
    yielding: np.ndarray,
    next_yield: np.ndarray,
    broadcast: bool,
    cmds: np.ndarray,
    made: np.ndarray,
    solves: np.ndarray,
    t_dec: np.ndarray,
    scratch: np.ndarray,
    tally: np.ndarray,
    st_t: np.ndarray,
    st_x: np.ndarray,
    st_cmd: np.ndarray,
    n_st: np.ndarray,
    t_goal: np.ndarray,
) -> int:
    """Control instants back to back: :func:`fleet_decide` (from robot position ``start``
    in the first one), then :func:`fleet_apply`, each instant's end time ``clock[0] + dt``
    written to ``clock[0]`` and counted in ``ran[0]`` -- until a frame closes (the world's
    control instants since the start, ``instants + ran[0]``, a multiple of
    ``substeps``), every robot is at its goal, or ``n_left`` instants have run: returns
    -1 (the world's clock then ticks). A step handed back returns its position in
    ``robots`` mid-instant (every instant before it was one at which the world's clock
    does nothing): the caller decides it and calls again from the next robot. The
    arguments are :func:`fleet_decide`'s and :func:`fleet_apply`'s (``plan``: ``info ==
    2``)."""
    while True:
        p = fleet_decide(
            start, robots, on, x, done, step, goal, goals, lam, att, npred, nrec, pvs, cols,
            bufs, recs, turns, floors, sensed, n_sensed, shares, info, plan_v, next_v,
            next_yield, broadcast, cmds, made, solves, t_dec, clock[0], scratch, tally,
        )  # fmt: skip
        if p >= 0:
            return p
        start = 0
        t = clock[0] + dt
        fleet_apply(
            x, done, parked, step, goal, goals, n_goals, radius, t, dt, plant, parked_speed,
            cmds, st_t, st_x, st_cmd, n_st, t_goal, info == 2, plan_v, next_v, yielding,
            next_yield,
        )  # fmt: skip
        clock[0] = t
        ran[0] += 1
        every = True
        for i in range(done.shape[0]):
            if not done[i]:
                every = False
                break
        if every or (instants + ran[0]) % substeps == 0 or ran[0] >= n_left:
            return -1
