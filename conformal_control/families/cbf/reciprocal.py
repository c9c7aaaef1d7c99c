"""Reciprocal robot-robot constraints: each robot of a pair takes a share of the pair's barrier.

Two robots i and j that both run a CBF safety filter can share one pairwise constraint
instead of each assuming the other will keep going (or dodge) as predicted. For the pair's
barrier ``h = h(x_i, x_j)`` (the run's barrier, symmetric in the two positions) and
velocities ``v_i``, ``v_j``, safety of the pair needs

    dh/dx_i . v_i + dh/dx_j . v_j + a h >= 0.                                  (pair)

With the rule of safety barrier certificates for multi-robot systems (Wang, Ames &
Egerstedt 2017: each robot of a pair enforces its own part of the pairwise constraint,
halves for identical robots), robot i enforces its **row** about j

    dh/dx_i . v_i + dh/dx_j . v~_j + s_ij a h >= 0,                            (row)
    v~_j = s_ij r_j + (1 - s_ij) r_i,

where ``s_ij`` is robot i's **share** of the pair (``s_ij + s_ji = 1``; from the fleet's
agreed weights ``s_ij = w_i / (w_i + w_j)``, one half by default) and ``r_i``, ``r_j``
are the two robots' **reference velocities**, which depend on what robots know of each
other (:data:`INFORMATION`):

* ``"position"``: positions only, ``r = 0``. The row is ``dh/dx_i . v_i + s_ij a h >= 0``:
  robot i may let h fall at rate ``s_ij a h`` at most (the decentralised certificate);
* ``"velocity"``: positions and the current velocities (measured by the sensor), ``r``
  the two velocities now. The row asks robot i to change the pair's rate, relative to
  the current velocities, by its share of what the pair lacks: ``dh/dx_i . (v_i - r_i)
  >= -s_ij c`` with ``c = dh/dx_i . r_i + dh/dx_j . r_j + a h`` (the split of reciprocal
  velocity obstacles, written for the barrier);
* ``"plan"``: positions and the plans the robots broadcast (for this family, the velocity
  each decided at the previous control instant), ``r`` those plans.

Adding robot i's row and robot j's row gives (pair) exactly, whatever the information
(the ``r`` terms cancel because both robots use the same two references): **when both
comply, the pair is as safe as one robot avoiding a static obstacle** (the barrier's
forward invariance, up to the discretisation of the control step). When one does *not*
comply (it ignores the other, or is not a robot of the fleet), the other's row alone gives
no such guarantee; with ``"velocity"`` (or ``"plan"``) information its row is relative to
the partner's actual motion, so at every control instant it takes its share of what is
still missing and, over a few instants, all of it (within its speed bound); with
``"position"`` it only ever takes its share.

**lambda** (the conformal slack) applies to the rows chosen by the scope
(:data:`LAMBDA_SCOPES`): ``"pedestrians"`` (default: the rows of predicted pedestrians
get ``+ lambda``; the robot rows are hard), ``"robots"`` (only the robot rows) or
``"both"``. The loss the controller learns lambda from scores the same agents (see
:class:`~conformal_control.families.cbf.loss.CBFGapLoss`): for a robot row the "prediction" is
the partner's assumed part ``dh/dx_j . v~_j + s_ij a h`` and the truth its actual part
``dh/dx_j . v_j + a h``, so a positive gap says that the partner did not take its share.
When the rows are infeasible at lambda and the filter's fallback is ``lambda_search``, the
search raises a slack level ``lambda' >= lambda`` on the rows lambda is the slack of
(:func:`lexicographic_search`), and the hard rows by ``hard_rows``:

* ``"level"``: they get ``max(0, lambda')``: with a cautious (negative) lambda the margin
  on the other rows goes first, the hard rows get slack once the level passes 0, and then
  the same as the others;
* ``"last"``: they keep none unless they cannot be met on their own (then every row is
  relaxed together, as ``lambda_search`` does).

Rows with a zero gradient (an agent already overlapped: no velocity changes them) are
left out of that search, where they would set the level for every other row. Steps that
relaxed hard rows are counted (``n_hard_rows_relaxed``). Other fallbacks see the rows as
one problem.

**Side-stepping.** Two robots exactly head-on (or any symmetric jam) can stop face to
face: each row cancels the component of the nominal velocity towards the other, and
nothing turns them. A reciprocal robot that is held back (moving slower than
:data:`SIDESTEP_SLOW` times its nominal speed) while its nominal velocity points at
another robot (within :data:`SIDESTEP_CONE` of it) that it would reach within
:data:`SIDESTEP_HORIZON` seconds at that velocity turns its nominal velocity away from
the nearest such robot by ``sidestep`` radians before filtering: clockwise when that
robot is on its left or dead ahead, counter-clockwise when it is on its right. Two robots
in a symmetric encounter turn the same way round and pass; a robot facing one that does
not comply turns away from its path. It changes only what the filter starts from: the
rows, hence the safety argument, are untouched.

This module holds the rule (:class:`Reciprocity`, the controller's setting), what a
robot knows of its peers at a control instant (:class:`PeerView`, handed to it by the
world) and the rows (:func:`peer_rows`).
"""

from __future__ import annotations

import copy
import functools
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ...core.base import Plugin
from ...core.spec import FLOOR_CORE_DEFAULT, FLOOR_MARGIN_M, PEER_HORIZON_S, ROBOT_CHOICES
from .constraint import ConformalConstraint
from .speed import speed_polygon

__all__ = [
    "COORDINATION",
    "FLOOR_CORE",
    "FLOOR_CORES",
    "FLOOR_LOOKAHEAD_S",
    "FLOOR_ROW",
    "HARD_ROWS",
    "INFORMATION",
    "LAMBDA_SCOPES",
    "PEDESTRIAN_ROW",
    "PRIORITIES",
    "RECIPROCITY",
    "ROBOT_ROW",
    "SIDESTEP_CONE",
    "SIDESTEP_HORIZON",
    "TIE_DISTANCE",
    "YIELD_HOLD_S",
    "PeerView",
    "Reciprocity",
    "calm_ahead_pairs",
    "calm_pairs",
    "check_peer_view",
    "floor_rows",
    "grown_constraint",
    "lexicographic_search",
    "pair_directions",
    "pair_shares",
    "parked_shares",
    "peer_rows",
    "priority_relax",
    "reference_velocities",
    "relaxed_approach",
    "robot_escape",
    "sidestep",
    "tie_direction",
]

#: How a robot treats the robots its sensor identifies: ``"reciprocal"`` (a shared
#: constraint, its share of each pair), ``"none"`` (predicted like pedestrians, each robot
#: taking the whole constraint for its prediction of the other: the behaviour without
#: reciprocity) or ``"ignore"`` (no constraint at all: a robot that does not comply).
RECIPROCITY = (*ROBOT_CHOICES["reciprocity"], "ignore")

#: What robots know of each other at a control instant (see the module docstring).
INFORMATION = ROBOT_CHOICES["information"]

#: The rows the conformal lambda is the slack of.
LAMBDA_SCOPES = ROBOT_CHOICES["lambda_scope"]

#: How the lambda search treats the rows without slack (:class:`Reciprocity`).
HARD_ROWS = ROBOT_CHOICES["hard_rows"]

#: The rows kept longest when not every row can be met (:class:`Reciprocity`).
PRIORITIES = ROBOT_CHOICES["priority"]

#: Which floor rows keep their cores before the pedestrians' rows give way
#: (:class:`Reciprocity` ``floor_core``).
FLOOR_CORES = ROBOT_CHOICES["floor_core"]

#: How robots coordinate beyond their shares (:class:`Reciprocity`): ``"yield"``, a robot
#: whose robot rows gave way broadcasts it and its partners take the whole pair.
COORDINATION = ROBOT_CHOICES["coordination"]

#: A robot keeps broadcasting that it yields for this long (s) after its robot rows last
#: gave way (so that its partners' shares do not flip at every control instant).
YIELD_HOLD_S = 0.5

#: Two robots closer than this (m) *coincide*: the direction between them is taken from
#: their ids (:func:`pair_directions`), not from their positions. Far below any distance a
#: robot can tell (a nanometre), yet far above the rounding of the positions' difference
#: (positions of a scene are below 1e5 m, whose float64 spacing is 1.5e-11 m), so that the
#: positions' direction is used wherever it is more than rounding noise.
TIE_DISTANCE = 1e-9

#: The fraction of the floor margin (:attr:`Reciprocity.floor_margin`) the floor rows'
#: *cores* keep (:func:`priority_relax`): the floor rows aim at ``d_c + floor_margin`` and
#: give way, before the pedestrians' rows do, down to ``d_c + FLOOR_CORE * floor_margin``
#: at most. Not all the way to ``d_c``: a robot tracks its command with a lag, so a pair
#: held exactly at ``d_c`` overshoots into contact (measured in docs/multi-robot.md).
FLOOR_CORE = 0.5

#: The look-ahead (s) of ``floor_core="ahead"`` (:func:`calm_ahead_pairs`): a pair's
#: cores give way when a pedestrian is predicted inside its collision distance of either
#: robot of the pair within this many seconds (measured in docs/multi-robot.md).
FLOOR_LOOKAHEAD_S = 1.0

#: Bisection steps of :func:`lexicographic_search` at most.
MAX_BISECTIONS = 60

#: Side-stepping: a robot turns when another robot is within this many seconds of its
#: nominal velocity ...
SIDESTEP_HORIZON = 1.0
#: ... and within this angle (rad) of its direction ...
SIDESTEP_CONE = math.pi / 4
#: ... while it moves slower than this fraction of its nominal speed.
SIDESTEP_SLOW = 0.5


class Reciprocity(Plugin):
    """How a CBF controller treats the robots its sensor reports (see the module docstring).

    Parameters
    ----------
    mode : {"reciprocal", "none", "ignore"}
        Reciprocal rows, prediction (as a pedestrian), or no constraint.
    lambda_scope : {"pedestrians", "robots", "both"}
        Rows that get ``+ lambda`` (and agents the loss scores).
    robot_margin : float
        Added to the barrier's collision distance for a robot (m): the run's barrier is
        built for robot + pedestrian radii, a robot-robot pair needs two robot radii, so
        ``robot_radius - agent_radius`` (the barrier needs a ``d_c`` parameter when this
        is not 0). Applies to the reciprocal rows.
    sidestep : float
        Angle (rad, in [0, pi/2]) a reciprocal robot turns its nominal velocity by, away
        from another robot ahead (see the module docstring); 0 never turns.
    hard_rows : {"level", "last"}
        How the ``lambda_search`` fallback treats the rows without slack (see the module
        docstring).
    peer_horizon : float, optional
        Planners that look ahead (the MPC family, :mod:`~conformal_control.families.mpc.peers`):
        how far ahead (s, > 0) the peers' lines bind their plans (default
        :data:`~conformal_control.core.spec.PEER_HORIZON_S`); None: the whole plan.
    coordination : {"none", "yield"}
        ``"yield"``: when the robot's rows about the other robots give way, it broadcasts
        that it yields (for :data:`YIELD_HOLD_S` seconds), and the world hands both robots
        of each of its pairs the yielding shares
        (:class:`~conformal_control.world.multi.MultiRobotWorld`); needs broadcast plans.
    priority : {"pedestrians", "robots"}
        The rows kept longest when not every row can be met: ``"pedestrians"`` (default:
        the robot rows give way first, :func:`priority_relax`) or ``"robots"`` (the
        pedestrians' lambda is raised first and the robot rows kept as ``hard_rows`` says,
        :func:`lexicographic_search`).
    floor_margin : float
        With ``priority="pedestrians"``: how far (m, finite, >= 0) beyond the robots'
        collision distance the floor rows aim (:func:`floor_rows`; default
        :data:`~conformal_control.core.spec.FLOOR_MARGIN_M`). The floor rows of the plain
        barrier ``d - d_c`` let a pair close to ``d_c`` in continuous time and, in steps,
        a little below it; aiming at ``d_c + floor_margin`` keeps the pair out of contact
        (measured in docs/multi-robot.md). Before the pedestrians' rows give way, the floor
        rows give way down to their cores at ``d_c + FLOOR_CORE * floor_margin``
        (:func:`priority_relax`). 0: the floor rows at ``d_c``, and no band. Not used by the
        MPC family (its lines are at ``d_c + robot_margin``) or with ``priority="robots"``
        (no floor rows).
    floor_core : {"always", "inside", "calm", "ahead", "none"}
        With ``priority="pedestrians"``: which floor rows keep their cores before the
        pedestrians' rows give way (:func:`priority_relax`'s ``cored``): ``"always"``
        every pair's; ``"inside"`` only the pairs already closer than the robots'
        collision distance (the others' floor rows give way entirely first); ``"calm"``
        only the pairs with no pedestrian inside its collision distance of either robot
        of the pair (from the predicted agents' positions of the step, as the edge rule
        reads them: when one is, the pair's floor rows give way as with ``"none"``, so
        the pedestrians' rows come first; :func:`calm_pairs`); ``"ahead"`` the pairs
        with no pedestrian inside, nor predicted inside within :data:`FLOOR_LOOKAHEAD_S`
        seconds (:func:`calm_ahead_pairs`), and every pair already within the floor
        distance ``d_c + floor_margin`` (released there, the pedestrians' rows would
        squeeze it into contact); ``"none"`` no pair's.
        Default :data:`~conformal_control.core.spec.FLOOR_CORE_DEFAULT` (the trade-off
        measured in docs/multi-robot.md).
    """

    def __init__(
        self,
        mode: str = "reciprocal",
        lambda_scope: str = "pedestrians",
        robot_margin: float = 0.0,
        sidestep: float = 0.3,
        hard_rows: str = "last",
        peer_horizon: float | None = PEER_HORIZON_S,
        coordination: str = "none",
        priority: str = "pedestrians",
        floor_margin: float = FLOOR_MARGIN_M,
        floor_core: str = FLOOR_CORE_DEFAULT,
    ) -> None:
        self.mode = mode
        self.lambda_scope = lambda_scope
        self.robot_margin = robot_margin
        self.sidestep = sidestep
        self.hard_rows = hard_rows
        self.peer_horizon = peer_horizon
        self.coordination = coordination
        self.priority = priority
        self.floor_margin = floor_margin
        self.floor_core = floor_core

    def validate(self) -> None:
        """Raise ``ValueError`` (one line) for an unknown choice or a setting out of range."""
        if self.mode not in RECIPROCITY:
            raise ValueError(
                f"reciprocity must be one of {', '.join(RECIPROCITY)}, got {self.mode!r}"
            )
        if self.lambda_scope not in LAMBDA_SCOPES:
            raise ValueError(
                f"lambda_scope must be one of {', '.join(LAMBDA_SCOPES)}, got {self.lambda_scope!r}"
            )
        k = self.sidestep
        if not (isinstance(k, (int, float)) and 0.0 <= k <= math.pi / 2):
            raise ValueError(f"sidestep must be an angle in [0, pi/2] (rad), got {k!r}")
        if self.hard_rows not in HARD_ROWS:
            raise ValueError(
                f"hard_rows must be one of {', '.join(HARD_ROWS)}, got {self.hard_rows!r}"
            )
        p = self.peer_horizon
        if p is not None and not (
            isinstance(p, (int, float)) and not isinstance(p, bool) and math.isfinite(p) and p > 0
        ):
            raise ValueError(f"peer_horizon must be a duration > 0 (s) or None, got {p!r}")
        if self.coordination not in COORDINATION:
            raise ValueError(
                f"coordination must be one of {', '.join(COORDINATION)}, got {self.coordination!r}"
            )
        if self.priority not in PRIORITIES:
            raise ValueError(
                f"priority must be one of {', '.join(PRIORITIES)}, got {self.priority!r}"
            )
        f = self.floor_margin
        if not (
            isinstance(f, (int, float)) and not isinstance(f, bool) and math.isfinite(f) and f >= 0
        ):
            raise ValueError(f"floor_margin must be a finite distance >= 0 (m), got {f!r}")
        if self.floor_core not in FLOOR_CORES:
            raise ValueError(
                f"floor_core must be one of {', '.join(FLOOR_CORES)}, got {self.floor_core!r}"
            )

    def turn(self) -> np.ndarray:
        """The compiled step's options: ``(cos, sin)`` of :attr:`sidestep`, the horizon (s),
        the cosine of the cone, the slow fraction (zeros: never turn), 1 when the hard
        rows are relaxed last (:attr:`hard_rows`) and 1 when the robot rows give way first
        (:attr:`priority` ``"pedestrians"``)."""
        keep = float(self.hard_rows == "last")
        first = float(self.priority == "pedestrians")
        if not self.sidestep:
            return np.array([0.0, 0.0, 0.0, 0.0, 0.0, keep, first])
        k = float(self.sidestep)
        return np.array(
            [
                math.cos(k),
                math.sin(k),
                SIDESTEP_HORIZON,
                math.cos(SIDESTEP_CONE),
                SIDESTEP_SLOW,
                keep,
                first,
            ]
        )

    def robot_constraint(self, constraint: ConformalConstraint) -> ConformalConstraint:
        """The constraint of the robot rows: ``constraint`` with the barrier's collision
        distance ``d_c`` grown by :attr:`robot_margin` (``constraint`` itself for 0)."""
        return grown_constraint(constraint, self.robot_margin)

    @property
    def lambda_on_pedestrians(self) -> bool:
        """Whether the pedestrians' rows get ``+ lambda``."""
        return self.lambda_scope != "robots"

    @property
    def lambda_on_robots(self) -> bool:
        """Whether the robots' rows get ``+ lambda``."""
        return self.lambda_scope != "pedestrians"


@dataclass(slots=True)
class PeerView:
    """What a robot knows of the robots it sensed at the last sampling time, now.

    The world builds it for each robot at each control instant from what the chosen
    information option allows; a controller reads nothing else about another robot. The
    arrays are the robot's own (copies, or read-only for the ids and shares): writing into
    them changes nothing in the world.

    Attributes
    ----------
    ids : ndarray of shape (K,)
        The robots' ids (as in the sensor's query).
    positions : ndarray of shape (K, 2)
        Their positions now (m).
    shares : ndarray of shape (K,)
        This robot's share ``s_ij`` of each pair.
    information : {"position", "velocity", "plan"}
    reference : ndarray of shape (K, 2) or None
        The peers' reference velocities ``r_j`` (m/s): their velocities now
        (``"velocity"``) or their broadcast plans (``"plan"``); None with ``"position"``.
    own_reference : ndarray of shape (2,) or None
        This robot's own ``r_i`` of the same kind (its velocity now, or the plan it
        broadcast); None with ``"position"``.
    plans : tuple of (ndarray, ndarray) or None
        With ``"plan"``, each peer's broadcast path when it has one: ``(times, positions)``
        with times in seconds since the start (H,) and positions (H, 2); None entries for
        peers that broadcast a velocity only. Planners that look ahead (the MPC family)
        read it.
    own_plan : tuple of (ndarray, ndarray) or None
        With ``"plan"``, the path this robot broadcast itself (what its peers read of it),
        so that both robots of a pair reason from the same two paths; None when it has
        broadcast none.
    own_id : int or None
        This robot's own id (as its peers sense it): with a peer's id it fixes the pair's
        tie-break direction (:func:`pair_directions`) when the two coincide; None (a view
        built without it): such a peer gets a zero row, as before.
    parked : ndarray of bool, shape (K,), or None
        Which peers have reached their last goal and stopped deciding (the world holds
        them still): they take no share of a pair any more, so a CBF robot takes the
        whole of each pair with them (:func:`parked_shares`). None: none known.
    """

    ids: np.ndarray
    positions: np.ndarray
    shares: np.ndarray
    information: str = "position"
    reference: np.ndarray | None = None
    own_reference: np.ndarray | None = None
    plans: tuple[tuple[np.ndarray, np.ndarray] | None, ...] | None = None
    own_plan: tuple[np.ndarray, np.ndarray] | None = None
    own_id: int | None = None
    parked: np.ndarray | None = None

    @property
    def n_peers(self) -> int:
        return int(self.positions.shape[0])


def parked_shares(view: PeerView) -> PeerView:
    """``view`` with this robot's share of each pair with a parked peer
    (:attr:`PeerView.parked`) set to 1: a robot at its goal no longer decides, so it never
    takes its share, and its partner takes the whole pair constraint (the barrier row
    with the partner's reference at its broadcast standstill, and the floor row closing
    in at most at ``a (d - d_c - margin)``). ``view`` itself when no peer is parked.

    Parameters
    ----------
    view : PeerView
        What the robot knows of its peers.
    """
    if view.parked is None or not view.parked.any():
        return view
    shares = np.where(view.parked, 1.0, np.asarray(view.shares, dtype=float))
    return replace(view, shares=shares)


def pair_shares(weights: np.ndarray) -> np.ndarray:
    """``s_ij = w_i / (w_i + w_j)`` for every ordered pair, shape (R, R) (diagonal 1/2).

    Parameters
    ----------
    weights : ndarray of shape (R,)
        Positive weights agreed by the fleet (equal weights: every share is one half).
    """
    w = np.asarray(weights, dtype=float).reshape(-1)
    if w.size == 0 or not np.isfinite(w).all() or (w <= 0).any():
        raise ValueError(f"share weights must be finite numbers > 0, got {w.tolist()}")
    out: np.ndarray = w[:, None] / (w[:, None] + w[None, :])
    return out


def reference_velocities(view: PeerView) -> np.ndarray:
    """``v~_j = s_ij r_j + (1 - s_ij) r_i`` for every peer, shape (K, 2) (0 for position)."""
    k = view.n_peers
    if view.reference is None or view.own_reference is None:
        return np.zeros((k, 2))
    s = view.shares[:, None]
    out: np.ndarray = s * view.reference + (1.0 - s) * np.asarray(view.own_reference)[None, :]
    return out


def peer_rows(
    constraint: ConformalConstraint, x_ego: np.ndarray, view: PeerView
) -> tuple[np.ndarray, np.ndarray]:
    """The robot rows ``A v + b >= 0`` of :func:`reference_velocities`'s rule (lambda apart).

    Parameters
    ----------
    constraint : ConformalConstraint
        Barrier and slope (the run's: the same as the pedestrians').
    x_ego : ndarray of shape (2,)
    view : PeerView

    Returns
    -------
    A : ndarray of shape (K, 2)
        ``dh/dx_i`` for each peer.
    b : ndarray of shape (K,)
        ``dh/dx_j . v~_j + s_ij a h``.
    """
    if view.n_peers == 0:
        return np.zeros((0, 2)), np.zeros(0)
    h, dh_dego, dh_dpeer = constraint.barrier.evaluate(x_ego, view.positions)
    vt = reference_velocities(view)
    b: np.ndarray = np.einsum("ij,ij->i", dh_dpeer, vt) + view.shares * float(constraint.a) * h
    return dh_dego, b


def check_peer_view(view: Any, ids: np.ndarray) -> PeerView:
    """``view`` as a :class:`PeerView` about exactly the robots ``ids`` (a clear error else)."""
    if not isinstance(view, PeerView):
        raise TypeError(f"state.peers must be a PeerView, got {type(view).__name__}")
    if view.ids.shape != ids.shape or not np.array_equal(view.ids, ids):
        raise ValueError(
            f"the world's peer view lists robots {view.ids.tolist()} but the robots sensed at "
            f"the sampling time are {ids.tolist()}"
        )
    if view.positions.shape != (ids.size, 2) or view.shares.shape != (ids.size,):
        raise ValueError("a peer view needs positions (K, 2) and shares (K,)")
    if view.information not in INFORMATION:
        raise ValueError(
            f"information must be one of {', '.join(INFORMATION)}, got {view.information!r}"
        )
    return view


def grown_constraint(constraint: ConformalConstraint, margin: float) -> ConformalConstraint:
    """``constraint`` with its barrier's collision distance ``d_c`` grown by ``margin`` (m)
    (``constraint`` itself for 0; a clear error for a barrier without ``d_c``)."""
    m = float(margin)
    if not math.isfinite(m):
        raise ValueError(f"robot_margin must be a finite distance, got {margin!r}")
    if m == 0.0:
        return constraint
    params = constraint.barrier.get_params()
    if "d_c" not in params:
        raise ValueError(
            f"robots larger than pedestrians need a barrier with a collision distance d_c; "
            f"{type(constraint.barrier).__name__} has none (give barrier_margin instead)"
        )
    d_c = float(params["d_c"]) + m
    if d_c < 0:
        raise ValueError(f"the robots' collision distance would be negative ({d_c} m)")
    barrier = copy.deepcopy(constraint.barrier)
    barrier.set_params(d_c=d_c)
    return ConformalConstraint(barrier, constraint.a)


def sidestep(
    nominal: np.ndarray, x_ego: np.ndarray, view: PeerView, turn: np.ndarray, d_c: float
) -> np.ndarray:
    """The nominal velocity turned away from the nearest peer ahead when the robot is held
    back; as given otherwise.

    The robot is held back when its speed is below the slow fraction of the nominal
    speed; a peer is ahead when it is closer than ``d_c`` plus the nominal speed times
    the horizon and inside the cone around the nominal direction. The turn is away from
    that peer's side.

    Parameters
    ----------
    nominal : ndarray of shape (2,)
        The nominal velocity (m/s).
    x_ego : ndarray of shape (4,)
        The robot's state (x, y, vx, vy): m, m/s.
    view : PeerView
        The peers' positions now (m).
    turn : ndarray
        :meth:`Reciprocity.turn`'s options: cosine and sine of the turn angle (both 0:
        never turn), horizon (s), cosine of the cone's half-angle, slow fraction.
    d_c : float
        The robots' collision distance, centre to centre (m).
    """
    c, s, horizon, cone, slow = (float(v) for v in turn[:5])
    n0, n1 = float(nominal[0]), float(nominal[1])
    sp = math.hypot(n0, n1)
    if s == 0.0 or sp == 0.0 or view.n_peers == 0:
        return np.asarray(nominal, dtype=float)
    if math.hypot(float(x_ego[2]), float(x_ego[3])) >= slow * sp:
        return np.asarray(nominal, dtype=float)
    rel = np.asarray(view.positions, dtype=float) - np.asarray(x_ego, dtype=float)[:2]
    d = np.hypot(rel[:, 0], rel[:, 1])
    ahead = (d < d_c + sp * horizon) & (rel @ np.array([n0, n1]) > cone * sp * d)
    if not ahead.any():
        return np.asarray(nominal, dtype=float)
    j = int(np.flatnonzero(ahead)[np.argmin(d[ahead])])
    if n0 * rel[j, 1] - n1 * rel[j, 0] < 0.0:  # on the right: turn counter-clockwise
        s = -s
    return np.array([c * n0 + s * n1, -s * n0 + c * n1])


def lexicographic_search(
    solver: Any,
    nominal: np.ndarray,
    A: np.ndarray,
    b: np.ndarray,
    hard: np.ndarray,
    lam: float,
    keep: bool = False,
) -> tuple[np.ndarray, float, bool]:
    """The ``lambda_search`` fallback with rows without slack (``hard``; their ``b``
    already holds ``- lam``): ``(v, lambda_applied, hard rows relaxed)``.

    The generic path's twin of
    :func:`~conformal_control.families.cbf.kernels_peers.lexicographic_search`, on the filter's
    primitives (``project``, ``min_lambda``, ``search_margin``): the smallest level
    ``lambda' >= lam`` at which the rows with slack at ``lambda'`` and the hard rows at 0
    (``keep``) or ``max(0, lambda')`` are feasible, by bisection; rows with a zero
    gradient (an agent already overlapped: no velocity changes them) are left out.

    Parameters
    ----------
    solver : SafetyFilter
        The filter whose primitives are used (``project``, ``min_lambda``,
        ``search_margin``, ``v_max`` and, when it has one, ``speed_sides``).
    nominal : ndarray of shape (2,)
        The nominal velocity (m/s).
    A : ndarray of shape (R, 2)
        The rows' velocity coefficients.
    b : ndarray of shape (R,)
        Their right-hand sides at lambda = 0 (the hard rows' already minus ``lam``).
    hard : ndarray of bool, shape (R,)
        Which rows have no slack (the robot rows).
    lam : float
        The lambda of the step (1/s); the search starts there.
    keep : bool
        Keep the hard rows at 0 (True: relaxed only when nothing else works) or relax
        them with the others beyond 0 (False).

    Returns
    -------
    v : ndarray of shape (2,)
        The decision (m/s).
    lambda_applied : float
        The level reached (1/s).
    relaxed : bool
        Whether the hard rows were relaxed.
    """
    live = np.hypot(A[:, 0], A[:, 1]) > 0.0  # rows no velocity changes are left out
    if not live.all():
        A, b, hard = A[live], b[live], np.asarray(hard, dtype=bool)[live]
    hard = np.asarray(hard, dtype=bool)
    soft = ~hard

    def at(level: float) -> np.ndarray | None:
        rhs = b + np.where(hard, lam if keep else lam + max(0.0, level), level)
        out: np.ndarray | None = solver.project(nominal, A, rhs)
        return out

    sides = getattr(solver, "speed_sides", None)
    if isinstance(sides, int):  # the disc around the filter's speed polygon
        reach = speed_polygon(sides, float(solver.v_max))[3]
    else:
        reach = 2.0 * float(solver.v_max)  # |v| <= 2 v_max on any polygon of 3+ sides
    top = -b + np.hypot(A[:, 0], A[:, 1]) * reach - np.where(hard, lam, 0.0)
    hi = max([lam, *(top[soft] if keep else top)])
    lo = lam
    if soft.any():
        star, _ = solver.min_lambda(A[soft], b[soft])
        lo = max(lo, float(star))
    margin = float(solver.search_margin(max(abs(lo), abs(hi)), A, b))
    v = at(hi + margin)
    if v is None:  # the hard rows cannot be met (keep), or round-off: all together
        star, v_star = solver.min_lambda(A, b)
        floor = max(lam, float(star))
        used = floor + float(solver.search_margin(floor, A, b))
        w = solver.project(nominal, A, b + used)
        return (np.asarray(v_star, float), floor, True) if w is None else (w, used, True)
    hi += margin
    w = at(lo + margin)
    if w is not None:
        return w, lo + margin, not keep and lo + margin > 0.0
    for _ in range(MAX_BISECTIONS):
        if hi - lo <= margin:
            break
        mid = 0.5 * (lo + hi)
        w = at(mid)
        if w is not None:
            hi, v = mid, w
        else:
            lo = mid
    return v, hi, not keep and hi > 0.0


@functools.lru_cache(maxsize=64)
def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(n, k=1)``, read-only, computed once per ``n`` (a fleet's steps
    handed to the priority stages ask for the same few sizes thousands of times)."""
    i, j = np.triu_indices(n, k=1)
    i.setflags(write=False)
    j.setflags(write=False)
    return i, j


def _vertices(G: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Every pairwise intersection of the lines ``G_i . v = g_i`` (parallel pairs left
    out), shape (P, 2)."""
    i, j = _pairs(G.shape[0])
    det = G[i, 0] * G[j, 1] - G[i, 1] * G[j, 0]
    ok = np.abs(det) > 1e-12
    i, j, det = i[ok], j[ok], det[ok]
    x = (g[i] * G[j, 1] - G[i, 1] * g[j]) / det
    y = (G[i, 0] * g[j] - g[i] * G[j, 0]) / det
    out: np.ndarray = np.stack([x, y], axis=1)
    return out


def _robot_slacks(
    A: np.ndarray,
    base: np.ndarray,
    nrm: np.ndarray,
    fixed: np.ndarray,
    fixed_rhs: np.ndarray,
    rows: np.ndarray,
    S: np.ndarray,
    s_poly: np.ndarray,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The least summed slack of the robot rows ``rows`` (normalised to unit gradient:
    speeds) with the rows ``fixed`` held at ``fixed_rhs`` and the speed set ``S v <=
    s_poly``: ``(v, slack per row of A)``, or None when the held rows cannot be met.

    The summed slack is a convex piecewise-linear function of the velocity, so its
    minimum over the polygon the held rows and the speed set cut out is at a vertex of
    the arrangement of their lines and the robot rows' lines: every pairwise intersection
    is tried (a few hundred points in the plane; exact, and much faster than a
    general LP solver here). Among minima the one keeping most rows without slack wins,
    so rows that need none get none."""
    # held rows met everywhere in the speed set (|v| <= 2 max s_poly there: a polygon of
    # 3+ sides around its disc) are left out, and the tolerance of the held rows is not
    # the robot rows': a row with a tiny gradient (a far agent's, or one at overlap) has a
    # huge normalised right-hand side, which would swamp it
    reach = 2.0 * float(np.abs(s_poly).max(initial=0.0))
    fx = np.flatnonzero(fixed)
    fx = fx[fixed_rhs[fx] < nrm[fx] * reach]
    An, rn = A[rows] / nrm[rows, None], base[rows] / nrm[rows]
    Fn, fn = A[fx] / nrm[fx, None], fixed_rhs[fx] / nrm[fx]
    G = np.concatenate([-An, -Fn, S])
    g = np.concatenate([rn, fn, s_poly])
    pts = _vertices(G, g)
    if not pts.size:
        return None
    held_tol = 1e-9 * (1.0 + float(np.abs(np.r_[fn, s_poly]).max(initial=0.0)))
    tol = 1e-9 * (1.0 + float(np.abs(g).max(initial=0.0)))
    ok = (pts @ S.T <= s_poly + held_tol).all(axis=1)
    if fx.size:
        ok &= (pts @ Fn.T + fn >= -held_tol).all(axis=1)
    pts = pts[ok]
    if not pts.size:
        return None
    short = np.maximum(0.0, -(pts @ An.T + rn))  # (P, k) per row
    total = short.sum(axis=1)
    best = total <= total.min() + tol
    pick = np.flatnonzero(best)[np.argmin((short[best] > tol).sum(axis=1))]
    v = pts[pick]
    slack = np.zeros(A.shape[0])
    slack[rows] = np.where(short[pick] > tol, short[pick], 0.0) * nrm[rows]
    return np.asarray(v, dtype=float), slack


def _level(
    solver: Any,
    A: np.ndarray,
    base: np.ndarray,
    nrm: np.ndarray,
    raised: np.ndarray,
    held: np.ndarray,
    S: np.ndarray,
    s_poly: np.ndarray,
    radius: float,
) -> float | None:
    """The smallest level ``delta`` added to the rows ``raised`` at which they can be met
    with the rows ``held`` (at ``base``) in the speed set; None when the held rows cannot
    be met at all. By bisection on the solver's exact projection (feasibility is
    monotone in ``delta``), to its search margin."""
    keep = raised | held
    Ak, bk, up = A[keep], base[keep], raised[keep]
    nominal = np.zeros(2)
    if _robot_slacks(Ak, bk, nrm[keep], ~up, bk, np.zeros(0, dtype=np.int64), S, s_poly) is None:
        return None
    lo = float((-(bk + nrm[keep] * radius))[up].max(initial=0.0))  # below: infeasible
    hi = float((-bk + nrm[keep] * radius)[up].max(initial=0.0))  # above: each row anywhere
    margin = float(solver.search_margin(max(abs(lo), abs(hi)), Ak, bk))
    if solver.project(nominal, Ak, bk + np.where(up, lo, 0.0)) is not None:
        return lo
    for _ in range(MAX_BISECTIONS):
        if hi - lo <= margin:
            break
        mid = 0.5 * (lo + hi)
        if solver.project(nominal, Ak, bk + np.where(up, mid, 0.0)) is not None:
            hi = mid
        else:
            lo = mid
    return hi


#: Kinds of the rows handed to :func:`priority_relax`: a pedestrian's (predicted agent's)
#: row, a robot's barrier row, a robot's floor row (:func:`floor_rows`).
PEDESTRIAN_ROW, ROBOT_ROW, FLOOR_ROW = 0, 1, 2


def pair_directions(x_ego: np.ndarray, view: PeerView) -> tuple[np.ndarray, np.ndarray]:
    """The unit vectors from the robot toward each peer and the distances: ``(u, d)``,
    shapes (K, 2) and (K,).

    ``u = rel / d`` from the positions, except for a peer that *coincides* with the robot
    (``d <`` :data:`TIE_DISTANCE`), where the positions give no direction: there ``u`` is
    the pair's tie-break direction (:func:`tie_direction`), a function of the two ids
    alone that both robots compute the same way and oppositely. With ``lo < hi`` the
    pair's ids, the direction ``e`` is the unit vector at angle ``2 pi frac(lo phi + hi
    phi^2)`` (``phi`` the golden ratio: neighbouring pairs get well-spread angles), and the
    robot with id ``lo`` has ``u = e`` (it parts along ``-e``), the robot with id ``hi``
    ``u = -e``: the pair parts whatever order the robots are stepped in. Without an own id
    (:attr:`PeerView.own_id` None) such a peer keeps ``u = 0`` (no direction, as before).
    Pairs apart are computed exactly as ``rel / d`` (bit for bit).

    Parameters
    ----------
    x_ego : ndarray of shape (2,) or more
        The robot's position (m) first.
    view : PeerView
        Its peers (ids, positions) and its own id.
    """
    rel = np.asarray(view.positions, dtype=float) - np.asarray(x_ego, dtype=float)[:2]
    d = np.hypot(rel[:, 0], rel[:, 1])
    ok = d >= TIE_DISTANCE
    u = np.zeros_like(rel)
    u[ok] = rel[ok] / d[ok, None]
    if not ok.all() and view.own_id is not None:
        for k in np.flatnonzero(~ok):
            u[k] = tie_direction(int(view.own_id), int(view.ids[k]))
    return u, d


def robot_escape(
    x_ego: np.ndarray,
    view: PeerView,
    d_c: float,
    gain: float,
    margin: float,
    within: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The edge rule's terms for the peers already within the robots' collision distance
    ``d_c`` (or within ``within``): ``(peers, U, c, push)``, the peers' indices in
    ``view`` and, for each, the unit vector from it to the robot, ``c = 0`` and the speed
    to move out at.

    A reciprocal robot is held to the edge rule about a robot inside ``d_c`` as about a
    pedestrian inside its collision distance: no command of its own closes in on it
    (``U v + c >= 0`` with ``c = 0``: only its own velocity counts, the partner keeps the
    same rule about it), and it moves out at its share of ``gain (d_c + margin - d)``
    where the speed set allows (:class:`~conformal_control.families.cbf.roles.EscapeRows`).
    A coinciding peer gets the pair's tie-break direction (:func:`pair_directions`).

    Parameters
    ----------
    x_ego : ndarray of shape (2,)
        The robot's position (m).
    view : PeerView
        Its peers (positions, shares, ids).
    d_c : float
        The robots' collision distance, centre to centre (m).
    gain : float
        The edge rule's gain (1/s).
    margin : float
        Beyond ``d_c`` (m) the push aims at.
    within : float, optional
        The peers closer than this (m) join (default ``d_c``). The controller passes
        ``d_c + FLOOR_CORE * margin`` (the floor cores) when a pedestrian is inside its
        collision distance too: there the edge rule may decide alone, without the floor
        rows, so a peer inside the cores joins it before contact (with
        :func:`relaxed_approach` when no command meets every agent's rule).
    """
    u, d = pair_directions(x_ego, view)
    reach = float(d_c) if within is None else float(within)
    peers = np.flatnonzero((d < reach) & (u != 0.0).any(axis=1))
    share = np.asarray(view.shares, dtype=float)[peers]
    push = share * float(gain) * (float(d_c) + float(margin) - d[peers])
    return peers.astype(np.int64), -u[peers], np.zeros(peers.size), push


def relaxed_approach(solver: Any, U: np.ndarray, c: np.ndarray, robots: np.ndarray) -> np.ndarray:
    """The pedestrians' edge-rule terms ``c`` relaxed so that the robot need not close in
    on the robots ``robots`` either: ``c'``, shape (k,).

    The edge rule asks ``U_j v + c_j >= 0`` of a pedestrian j inside its collision
    distance (``c_j = -U_j . v_j``: the robot moves away at least as fast as the
    pedestrian comes at it) and ``U_r v >= 0`` of a robot r inside the robots' (the robot
    commands nothing toward it). Hemmed in -- a pedestrian walking at the robot from
    behind, a robot ahead -- no command meets both, and a pedestrians' rule alone drives
    the robot into the robot ahead (measured in docs/multi-robot.md). Here the
    pedestrians that come at the robot (``c_j < 0``) get ``c'_j = min(c_j + sigma, 0)``
    with ``sigma`` the smallest level (>= 0) at which every row can be met, so the robot
    still never commands toward a pedestrian inside (``U_j v >= 0`` at worst: ``sigma``
    stops there, where ``v = 0`` meets every row) nor toward a robot inside, and moves
    away from the pedestrians as fast as that leaves room for. The others keep their
    ``c_j``. ``c`` itself when every row can be met already.

    Parameters
    ----------
    solver : SafetyFilter
        The filter whose primitives are used (``project``, ``search_margin``,
        ``speed_set``).
    U : ndarray of shape (k, 2)
        Unit vectors from each pedestrian inside to the robot.
    c : ndarray of shape (k,)
        Their edge-rule terms ``-U_j . v_j`` (m/s).
    robots : ndarray of shape (m, 2)
        Unit vectors from each robot inside to the robot (its rows ``U_r v >= 0``).
    """
    U = np.asarray(U, dtype=float).reshape(-1, 2)
    c = np.asarray(c, dtype=float).reshape(-1)
    robots = np.asarray(robots, dtype=float).reshape(-1, 2)
    coming = c < 0.0
    if not coming.any() or not robots.size:
        return c
    A = np.concatenate([U[coming], U, robots])
    base = np.concatenate([c[coming], np.where(coming, 0.0, c), np.zeros(robots.shape[0])])
    raised = np.zeros(A.shape[0], dtype=bool)
    raised[: int(coming.sum())] = True
    nrm = np.hypot(A[:, 0], A[:, 1])
    S, s_poly, radius = solver.speed_set()
    level = _level(solver, A, base, nrm, raised, ~raised, S, s_poly, radius)
    if level is None or level <= 0.0:  # the held rows cannot be met (no 0 in the speed set)
        return c
    level += float(solver.search_margin(level, A, base))
    out: np.ndarray = np.where(coming, np.minimum(c + level, 0.0), c)
    return out


def calm_pairs(
    x_ego: np.ndarray, peers: np.ndarray, pedestrians: np.ndarray, distance: float
) -> np.ndarray:
    """Which of a robot's pairs are calm (``floor_core="calm"``): no pedestrian inside
    ``distance`` of the robot nor of the pair's other robot, shape (K,).

    Both robots of a pair compute it from the same two positions, so they agree whenever
    they read the same pedestrians there (each reads its own predicted agents: a
    pedestrian one robot does not sense is not counted by it).

    Parameters
    ----------
    x_ego : ndarray of shape (2,)
        The robot's position (m).
    peers : ndarray of shape (K, 2)
        The other robots' positions (m).
    pedestrians : ndarray of shape (N, 2)
        The pedestrians' positions (m; NaN rows: absent, never inside).
    distance : float
        The pedestrians' collision distance (m).
    """
    peers = np.asarray(peers, dtype=float).reshape(-1, 2)
    peds = np.asarray(pedestrians, dtype=float).reshape(-1, 2)
    if not peds.size:
        return np.ones(peers.shape[0], dtype=bool)
    d_ego = np.hypot(peds[:, 0] - x_ego[0], peds[:, 1] - x_ego[1])
    if bool((d_ego < distance).any()):
        return np.zeros(peers.shape[0], dtype=bool)
    d = np.hypot(peds[None, :, 0] - peers[:, None, 0], peds[None, :, 1] - peers[:, None, 1])
    out: np.ndarray = ~(d < distance).any(axis=1)
    return out


def calm_ahead_pairs(
    x_ego: np.ndarray,
    peers: np.ndarray,
    pedestrians: np.ndarray,
    velocities: np.ndarray,
    distance: float,
    horizon: float,
    own_velocity: np.ndarray | None = None,
    peer_velocities: np.ndarray | None = None,
) -> np.ndarray:
    """Which of a robot's pairs stay calm for ``horizon`` seconds (``floor_core="ahead"``):
    no pedestrian inside ``distance`` of the robot nor of the pair's other robot now, nor
    predicted to come inside within ``horizon``, shape (K,).

    Each pedestrian moves on at its (predicted) velocity and each robot at its reference
    velocity (:attr:`PeerView.own_reference`, :attr:`PeerView.reference`: the velocities
    or broadcast plans both robots of a pair read alike; standing still without them); the
    time to contact is :func:`~conformal_control.families.cbf.constraint.time_to_contact`'s.
    The pedestrians' rows give way *before* a pedestrian is inside (measured in
    docs/multi-robot.md), so a rule that waits for contact (:func:`calm_pairs`) releases
    the cores too late; this one releases them while the pedestrian is still coming.

    Parameters
    ----------
    x_ego : ndarray of shape (2,)
        The robot's position (m).
    peers : ndarray of shape (K, 2)
        The other robots' positions (m).
    pedestrians, velocities : ndarrays of shape (N, 2)
        The pedestrians' positions (m) and velocities (m/s); NaN rows: absent, never
        inside.
    distance : float
        The pedestrians' collision distance (m).
    horizon : float
        The look-ahead (s, >= 0; 0: :func:`calm_pairs`' rule, contact now).
    own_velocity : ndarray of shape (2,), optional
        The robot's reference velocity (m/s).
    peer_velocities : ndarray of shape (K, 2), optional
        The peers' reference velocities (m/s).
    """
    from .constraint import time_to_contact

    peers = np.asarray(peers, dtype=float).reshape(-1, 2)
    peds = np.asarray(pedestrians, dtype=float).reshape(-1, 2)
    vel = np.asarray(velocities, dtype=float).reshape(-1, 2)
    k = peers.shape[0]
    if not peds.size:
        return np.ones(k, dtype=bool)
    live = np.isfinite(peds).all(axis=1) & np.isfinite(vel).all(axis=1)
    peds, vel = peds[live], vel[live]
    if not peds.size:
        return np.ones(k, dtype=bool)
    h = float(horizon)
    x = np.asarray(x_ego, dtype=float)[:2]
    if bool((time_to_contact(x, peds, vel, distance, own_velocity) <= h).any()):
        return np.zeros(k, dtype=bool)
    pv = np.zeros((k, 2)) if peer_velocities is None else np.asarray(peer_velocities, float)
    out = np.ones(k, dtype=bool)
    for j in range(k):
        out[j] = not bool((time_to_contact(peers[j], peds, vel, distance, pv[j]) <= h).any())
    return out


def tie_direction(own_id: int, peer_id: int) -> np.ndarray:
    """The unit vector robot ``own_id`` takes as "toward" robot ``peer_id`` when the two
    coincide (:func:`pair_directions`): ``e`` for the lower id, ``-e`` for the higher, with
    ``e`` at angle ``2 pi frac(lo phi + hi phi^2)``; so ``tie_direction(i, j) ==
    -tie_direction(j, i)`` exactly.

    Parameters
    ----------
    own_id, peer_id : int
        The two robots' ids (different).
    """
    me, other = int(own_id), int(peer_id)
    if me == other:
        raise ValueError(f"a robot has no tie-break direction with itself (id {me})")
    lo, hi = min(me, other), max(me, other)
    phi = (1.0 + math.sqrt(5.0)) / 2.0
    angle = 2.0 * math.pi * ((lo * phi + hi * phi * phi) % 1.0)
    e = np.array([math.cos(angle), math.sin(angle)])
    return e if me == lo else -e


def floor_rows(
    x_ego: np.ndarray, view: PeerView, d_c: float, a: float, margin: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """The robots' *floor* rows: for each peer, ``-u . v + s_ij a (d - d_c - margin) >= 0``
    with ``u`` the unit vector toward it, ``d`` the distance and ``s_ij`` the robot's share.

    The reciprocal rows of the plain distance barrier ``d - d_c - margin`` (no partner's
    velocity, no comfort margin): robot i may close in on j at its share of
    ``a (d - d_c - margin)``; when both robots of a pair keep theirs, ``d`` never falls
    below ``d_c + margin`` in continuous time (and a pair already closer parts). In steps
    of ``dt`` with ``a dt > 1`` a pair may overshoot that distance by a fraction of a
    step's closing; the ``margin`` (:attr:`Reciprocity.floor_margin`) keeps that
    overshoot out of contact. Far apart they allow much; near contact they forbid closing
    in. :func:`priority_relax` keeps them after the robots' barrier rows have given way.

    Parameters
    ----------
    x_ego : ndarray of shape (2,)
        The robot's position (m).
    view : PeerView
        Its peers (positions, shares).
    d_c : float
        The robots' collision distance, centre to centre (m).
    a : float
        The slope (1/s).
    margin : float
        The distance beyond ``d_c`` the rows aim at (m, >= 0; 0: ``d_c`` itself, the
        rows bit for bit as without it).

    Returns
    -------
    A : ndarray of shape (K, 2)
    b : ndarray of shape (K,)
        A peer that coincides with the robot (closer than :data:`TIE_DISTANCE`) gets the
        pair's tie-break direction (:func:`pair_directions`), so the pair parts; a zero
        row only when the view has no own id.
    """
    u, d = pair_directions(x_ego, view)
    A = -u
    live = (u != 0.0).any(axis=1)
    target = d_c + margin  # d_c itself for 0 (x + 0.0 == x)
    b = np.where(live, np.asarray(view.shares, dtype=float) * a * (d - target), 0.0)
    return A, b


def priority_relax(
    solver: Any,
    nominal: np.ndarray,
    A: np.ndarray,
    b: np.ndarray,
    kind: np.ndarray,
    lam: float,
    band: np.ndarray | None = None,
    cored: np.ndarray | None = None,
) -> tuple[np.ndarray, float, str]:
    """The fallback with the pedestrians' rows given way after the robots' rows
    (``priority="pedestrians"``): ``(v, lambda_applied, gave_way)``.

    ``kind`` says what each row is (:data:`PEDESTRIAN_ROW`, :data:`ROBOT_ROW`,
    :data:`FLOOR_ROW`). Every row's base is ``A v + b + lam >= 0`` (rows without slack
    already hold ``- lam`` in ``b``). A floor row's **core** is its base raised by its
    ``band`` (the floor rows aim at ``d_c + floor_margin``; their core at
    ``d_c + FLOOR_CORE * floor_margin``: ``band = s_ij a (1 - FLOOR_CORE) floor_margin``).
    Only the floor rows in ``cored`` keep their cores before the pedestrians' rows give
    way (:attr:`Reciprocity.floor_core`); the others give way entirely in stage 2. The
    rows give way in this order, each stage only when the one before cannot make them
    feasible:

    1. ``"robots"``: the robots' barrier rows, each with its own slack (the least summed
       slack, rows normalised to unit gradient so that slacks are speeds; exact, at a
       vertex of the rows' arrangement that leaves the rows that need none without), the
       pedestrians' rows at ``lam`` and the floor rows held;
    2. ``"robot_floors"``: the floor rows' margin band (the whole row for a floor row not
       in ``cored``), with the pedestrians' rows at ``lam`` and the cores held (the least
       summed slack of the floor rows; the barrier rows left out from here on);
    3. ``"pedestrians"``: the pedestrians' rows at the smallest level ``lam + delta`` at
       which they can be met with the cores held (bisection on the exact projection),
       the floor rows given way as in stage 2 there;
    4. ``"robot_cores"``: when the cores cannot be met at any level of the pedestrians'
       rows (robots hemmed in, or already closer than ``d_c``), the least-violation
       command: it never closes in on a robot already inside its collision distance (a
       floor row whose core is negative: the row ``A v >= 0``; the pedestrians inside
       theirs are kept out by the speed set, the edge rule's escape polygon), the
       pedestrians' rows at the smallest level at which they can be met with that, and
       the cores given way by their least summed slack. When even not closing in on
       those robots is impossible in the speed set, the command that closes in on them
       the slowest (the brake: the min-lambda LP on their rows).

    Each robot of a pair computes its floor row from the same distance and its own share
    (the shares of a pair add to 1), so the cores are reciprocal: a pair whose robots
    both keep theirs never closes below ``d_c`` (continuous time), whatever the
    pedestrians do to the bands. The decision is the velocity closest to the nominal at
    that relaxation (plus the solver's margin on the relaxed rows), or the LP's own
    velocity should that projection fail. Rows with a zero gradient are left out.

    Parameters
    ----------
    solver : SafetyFilter
        The filter whose primitives are used (``project``, ``min_lambda``,
        ``search_margin`` and ``speed_set``: the LPs work in the speed set the
        filter works in, the escape polygon under the edge rule).
    nominal : ndarray of shape (2,)
        The nominal velocity (m/s).
    A : ndarray of shape (R,)
        The rows' velocity coefficients, shape (R, 2).
    b : ndarray of shape (R,)
        Their right-hand sides at lambda = 0 (the rows without slack already minus ``lam``).
    kind : ndarray of int, shape (R,)
        Each row's kind.
    lam : float
        The lambda of the step (1/s).
    band : ndarray of shape (R,), optional
        How far each floor row may give way before its core (finite, >= 0, in the row's
        units: m/s; read for floor rows only). None: 0, the floor rows are their cores.
    cored : ndarray of bool, shape (R,), optional
        The floor rows whose cores are held before the pedestrians' rows give way (read
        for floor rows only). None: every floor row (``floor_core="always"``).

    Returns
    -------
    v : ndarray of shape (2,)
        The decision (m/s).
    lambda_applied : float
        ``lam`` plus the pedestrians' level (1/s).
    gave_way : str
        The last stage that gave way: ``""`` (none: round-off), ``"robots"``,
        ``"robot_floors"``, ``"pedestrians"`` or ``"robot_cores"``.
    """
    kind = np.asarray(kind)
    if band is None:
        band = np.zeros(A.shape[0])
    band = np.asarray(band, dtype=float)
    if band.shape != (A.shape[0],) or not np.isfinite(band).all() or (band < 0).any():
        raise ValueError(
            f"priority_relax: band must be {A.shape[0]} finite numbers >= 0 (one per row), "
            f"got shape {band.shape}"
        )
    cored = np.ones(A.shape[0], dtype=bool) if cored is None else np.asarray(cored)
    if cored.shape != (A.shape[0],) or cored.dtype != bool:
        raise ValueError(
            f"priority_relax: cored must be {A.shape[0]} booleans (one per row), "
            f"got {cored.dtype} of shape {cored.shape}"
        )
    nrm = np.hypot(A[:, 0], A[:, 1])
    live = nrm > 0.0
    if not live.all():
        A, b, kind, nrm = A[live], b[live], kind[live], nrm[live]
        band, cored = band[live], cored[live]
    base = b + lam
    ped, rob, flo = kind == PEDESTRIAN_ROW, kind == ROBOT_ROW, kind == FLOOR_ROW
    core = base + np.where(flo, band, 0.0)  # the floor rows' cores; the others' bases
    S, s_poly, radius = solver.speed_set()  # the escape polygon under the edge rule
    could_bind = base < nrm * radius  # else met anywhere in the speed disc
    held, fixed_rhs, delta = ped | flo, base, 0.0
    gave_way, rows, slack_of = "robots", np.flatnonzero(rob & could_bind), base
    found = _robot_slacks(A, base, nrm, held, base, rows, S, s_poly)
    extra = np.zeros(0, dtype=np.int64)  # rows held at A v >= 0 too (stage 4)
    kept = flo & cored  # the floor rows whose cores hold before the pedestrians give way
    if found is None:  # 2. the floors' margin bands, the pedestrians at lam
        gave_way, rows, fixed_rhs = "robot_floors", np.flatnonzero(flo & could_bind), core
        held = ped | kept
        found = _robot_slacks(A, base, nrm, held, core, rows, S, s_poly)
    if found is None and ped.any():  # 3. the pedestrians' level with the cores held
        level = _level(solver, A, core, nrm, ped, kept, S, s_poly, radius)
        if level is not None:
            gave_way, delta = "pedestrians", max(level, 0.0)
            delta += float(solver.search_margin(abs(delta), A, core))
            fixed_rhs = core + np.where(ped, delta, 0.0)
            found = _robot_slacks(A, base, nrm, held, fixed_rhs, rows, S, s_poly)
    if found is None:  # 4. the cores give way: never closing in on a robot inside d_c
        gave_way, slack_of = "robot_cores", core
        inside = flo & (core < 0.0)
        extra = np.flatnonzero(inside)
        held, fixed_rhs = ped | inside, np.where(inside, 0.0, core)
        rows = np.flatnonzero(flo & (core < nrm * radius))
        level = (
            _level(solver, A, fixed_rhs, nrm, ped, inside, S, s_poly, radius)
            if ped.any()
            else (0.0 if _meets(A, fixed_rhs, nrm, inside, S, s_poly) else None)
        )
        if level is None:  # the brake: the slowest closing on the robots inside d_c
            star, v_star = solver.min_lambda(A[inside] / nrm[inside, None], np.zeros(extra.size))
            return np.asarray(v_star, dtype=float), lam, gave_way
        delta = max(level, 0.0)
        delta += float(solver.search_margin(abs(delta), A, fixed_rhs))
        fixed_rhs = fixed_rhs + np.where(ped, delta, 0.0)
        found = _robot_slacks(A, core, nrm, held, fixed_rhs, rows, S, s_poly)
    v_lp, slack = found if found is not None else (None, np.zeros(A.shape[0]))
    relaxed = slack > 0.0
    if relaxed.any():
        slack = np.where(relaxed, slack + float(solver.search_margin(slack.max(), A, base)), 0.0)
    if gave_way == "robots":
        rhs = base + np.where(ped, delta, slack)  # the barrier rows' slacks; floors at 0
    else:  # the barrier rows left out, the floors with their slacks
        rhs = np.where(rob, np.inf, slack_of + np.where(ped, delta, slack))
    Ax, rx = A, rhs
    if extra.size:  # and not closing in on the robots inside d_c
        Ax, rx = np.concatenate([A, A[extra]]), np.concatenate([rhs, np.zeros(extra.size)])
    v = solver.project(nominal, Ax, rx)
    if v is None:
        if v_lp is None:  # round-off: every row relaxed together
            star, v_star = solver.min_lambda(A, base)
            return np.asarray(v_star, dtype=float), lam + max(0.0, float(star)), "robot_cores"
        v = v_lp
    if gave_way == "robots" and not relaxed.any():
        gave_way = ""
    return np.asarray(v, dtype=float), lam + delta, gave_way


def _meets(
    A: np.ndarray,
    rhs: np.ndarray,
    nrm: np.ndarray,
    rows: np.ndarray,
    S: np.ndarray,
    s_poly: np.ndarray,
) -> bool:
    """Whether some velocity of the speed set ``S v <= s_poly`` meets the rows ``rows``
    (a mask) at ``rhs``."""
    found = _robot_slacks(A, rhs, nrm, rows, rhs, np.zeros(0, dtype=np.int64), S, s_poly)
    return found is not None
