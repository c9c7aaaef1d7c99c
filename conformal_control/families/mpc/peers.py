"""Robot peers for the sampling MPC: each robot of a pair plans on its side of a shared line.

The CBF family splits a pair's barrier rate (:mod:`conformal_control.families.cbf.reciprocal`); a
planner that looks ``H`` steps ahead splits the *space* instead, as buffered Voronoi cells
do: at every plan time ``t_h`` the two robots' reference positions ``y_i(t_h)``,
``y_j(t_h)`` define a line between them, at the fraction ``s_ij`` (robot i's share) of the
way from ``y_i`` to ``y_j``; robot i keeps its planned position ``p_h`` at least
``buffer`` on its own side::

    n_h . (p_h - m_h) <= -buffer,  n_h = (y_j - y_i) / |y_j - y_i|,  m_h = y_i + s_ij (y_j - y_i).

Robot j keeps ``-n_h . (p_h - m_h) <= -buffer`` about the same ``m_h`` (its share is
``1 - s_ij``): when both plans comply their positions at every plan time are on the two
sides of one line, ``2 buffer`` apart at least. The reference positions depend on what
robots know of each other (the ``information`` of the world's
:class:`~conformal_control.families.cbf.reciprocal.PeerView`):

* ``"position"``: the positions now, held over the horizon (the buffered Voronoi cell);
* ``"velocity"``: the positions now moved on at the velocities now;
* ``"plan"``: the paths the robots broadcast at the previous control instant
  (:meth:`~conformal_control.world.multi.MultiRobotWorld.broadcast`), interpolated at the
  plan times (the last point held); the velocity rule for a robot without one. A robot
  reads its **own** broadcast path too (:attr:`PeerView.own_plan
  <conformal_control.families.cbf.reciprocal.PeerView.own_plan>`), not an extrapolation of its
  position: its peer reads that same path of it.

Both robots of a pair compute the same two reference positions from the same shared
information, hence the same line (a test checks it for every information option).
``buffer`` is half the robots' collision distance, plus half the family's margin, minus
half of lambda where the conformal scope puts lambda on the robots.

**Near horizon.** The lines bind only the plan steps within the reciprocity's
``peer_horizon`` seconds of now (:class:`~conformal_control.families.cbf.reciprocal.Reciprocity`):
a broadcast plan is redone at every replanning, so its far end says little about where
the peer will be, and lines drawn there only forbid plans that the next replanning
would not hold the peer to.

**Priority.** :func:`peer_terms` keeps the lines apart from the pedestrians' safe
distances so that the family can give way in order (:meth:`SamplingMPC.plan_end
<conformal_control.families.mpc.controller.SamplingMPC.plan_end>`; the reciprocity's
``priority="pedestrians"``): a plan meeting both; else, the lines give way first --
among the plans that keep the pedestrians' safe distances, the one intruding least over
the lines (then the cheapest), with ``status="peer_yield"``; only when no plan keeps the
pedestrians' safe distances does the family's fallback decide, and ``least_violation``
then ranks the plans by their intrusion into the pedestrians' safe distances first, over
the lines second. With ``priority="robots"`` the lines and the safe
distances are one problem (a plan meeting both, else the fallback on their summed
intrusion).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...predictors.base import PredictionQuery
from ..cbf.reciprocal import TIE_DISTANCE, PeerView, Reciprocity, tie_direction

__all__ = [
    "RobotSplit",
    "between_steps",
    "has_peer_terms",
    "near_steps",
    "peer_clearance",
    "peer_lines",
    "peer_terms",
    "reference_paths",
    "split_robots",
    "with_robot_columns",
]


def reference_paths(
    view: PeerView, x_ego: np.ndarray, times: np.ndarray, t_now: float
) -> tuple[np.ndarray, np.ndarray]:
    """The robot's own and its peers' reference positions at ``times`` (s since the start).

    Parameters
    ----------
    view : PeerView
        What the robot knows of its K peers (positions, and by its ``information``
        velocities or broadcast plans).
    x_ego : ndarray
        The robot's state (its first two numbers are its position, m).
    times : ndarray of shape (H,)
        The plan times (s since the start).
    t_now : float
        The time now (s since the start).

    Returns
    -------
    own : ndarray of shape (H, 2)
    peers : ndarray of shape (K, H, 2)
    """
    dt = np.asarray(times, dtype=float) - float(t_now)
    x = np.asarray(x_ego, dtype=float)[:2]
    pos = np.asarray(view.positions, dtype=float)
    if view.information == "position" or view.reference is None or view.own_reference is None:
        own = np.broadcast_to(x, (dt.size, 2)).copy()
        peers = np.broadcast_to(pos[:, None, :], (pos.shape[0], dt.size, 2)).copy()
        return own, peers
    own_v = np.asarray(view.own_reference, dtype=float)
    ref = np.asarray(view.reference, dtype=float)
    own = x[None, :] + dt[:, None] * own_v[None, :]
    peers = pos[:, None, :] + dt[None, :, None] * ref[:, None, :]
    if view.information == "plan":
        if view.own_plan is not None:  # what the peers read of this robot
            own = _along(view.own_plan, times, x)
        for k, path in enumerate(view.plans or ()):
            if path is not None:
                peers[k] = _along(path, times, pos[k])
    return own, peers


def _along(path: tuple[np.ndarray, np.ndarray], times: np.ndarray, now: np.ndarray) -> np.ndarray:
    """A broadcast path at ``times``: linear between its points, its last point held, its
    first one reached from the position ``now`` (whose time is the path's start)."""
    t, p = (np.asarray(a, dtype=float) for a in path)
    out = np.empty((np.size(times), 2))
    for d in range(2):
        out[:, d] = np.interp(times, t, p[:, d], left=np.nan, right=p[-1, d])
    early = np.isnan(out[:, 0])
    if early.any():  # before the path's first point: from where the robot is now
        out[early] = now
    return out


def peer_lines(
    view: PeerView, own: np.ndarray, peers: np.ndarray, buffer: float
) -> tuple[np.ndarray, np.ndarray]:
    """The shared lines: unit normals ``(K, H, 2)`` pointing at each peer and offsets
    ``(K, H)`` such that robot i's plan must keep ``normal . p <= offset``.

    Parameters
    ----------
    view : PeerView
        The peers; its ``shares`` (K,) place each line at that fraction of the way from
        the robot's reference position to the peer's.
    own : ndarray of shape (H, 2)
        The robot's reference positions at the plan times (m).
    peers : ndarray of shape (K, H, 2)
        The peers' reference positions at the plan times (m).
    buffer : float
        Distance (m) the plan keeps on its side of each line.
    """
    d = peers - own[None, :, :]
    dist = np.hypot(d[..., 0], d[..., 1])
    normal = d / np.maximum(dist, 1e-12)[..., None]
    # coincident references: the pair's tie-break direction (opposite for the two robots,
    # so that their lines part them), or (1, 0) for a view without the robot's own id
    tied = dist < TIE_DISTANCE
    if tied.any():
        for k, h in zip(*np.nonzero(tied), strict=True):
            normal[k, h] = (
                (1.0, 0.0)
                if view.own_id is None
                else tie_direction(int(view.own_id), int(view.ids[k]))
            )
    share = np.asarray(view.shares, dtype=float)[:, None]
    mid = own[None, :, :] + share[..., None] * d
    offset: np.ndarray = (normal * mid).sum(-1) - float(buffer)
    return normal, offset


def peer_clearance(
    positions: np.ndarray, normal: np.ndarray, offset: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per candidate plan, its smallest margin to the lines (m; < 0 crosses one) and its
    summed intrusion.

    Parameters
    ----------
    positions : ndarray of shape (N, H, 2)
        Planned positions at plan steps 1..H.
    normal, offset
        :func:`peer_lines`.
    """
    if normal.shape[0] == 0:
        n = positions.shape[0]
        return np.full(n, np.inf), np.zeros(n)
    # margin[n, k, h] = offset[k, h] - normal[k, h] . p[n, h]
    proj = np.einsum("nhd,khd->nkh", positions, normal)
    margin = offset[None] - proj
    clear: np.ndarray = margin.min(axis=(1, 2))
    viol: np.ndarray = np.maximum(-margin, 0.0).sum(axis=(1, 2))
    return clear, viol


# ---------------------------------------------------------------------------- the family
@dataclass(frozen=True)
class RobotSplit:
    """How one interval's sensed agents were split: predicted pedestrians, robot peers.

    Attributes
    ----------
    ids : ndarray of shape (N,)
        Every sensed agent, in the query's order (the record's columns).
    robot : ndarray of shape (N,)
        The sensor's agent types.
    peer_ids : ndarray of shape (K,)
        The robots handled reciprocally (empty when they are ignored).
    scored : ndarray of shape (N,)
        The agents the loss scores (pedestrians, and robots where lambda applies to them).
    """

    ids: np.ndarray
    robot: np.ndarray
    peer_ids: np.ndarray
    scored: np.ndarray


def split_robots(
    reciprocity: Reciprocity | None, observation: PredictionQuery
) -> tuple[PredictionQuery, RobotSplit | None]:
    """The query the predictor gets (the pedestrians, when robots are handled apart) and
    the split (None: every agent is predicted, as without reciprocity)."""
    if reciprocity is None or reciprocity.mode == "none":
        return observation, None
    reciprocity.validate()
    robot = observation.is_robot
    ids = np.asarray(observation.ids)
    peer = robot if reciprocity.mode == "reciprocal" else np.zeros_like(robot)
    scored = np.where(robot, reciprocity.lambda_on_robots & peer, reciprocity.lambda_on_pedestrians)
    split = RobotSplit(ids=ids, robot=robot, peer_ids=ids[peer], scored=scored.astype(bool))
    return observation.select(~robot), split


def with_robot_columns(record: Any, split: RobotSplit | None) -> Any:
    """The family's record with a (NaN) column for every robot, in the query's order, and
    the split's scoring (losses read the robots' true positions from the truth)."""
    if split is None:
        return record
    n, s = split.ids.size, record.n_steps
    xp = np.full((s, n, 2), np.nan)
    vp = np.full((s, n, 2), np.nan)
    xp[:, ~split.robot] = record.x_pred
    vp[:, ~split.robot] = record.v_pred
    return dataclasses.replace(record, ids=split.ids, x_pred=xp, v_pred=vp, scored=split.scored)


def near_steps(dt_plan: float, horizon: int, peer_horizon: float | None) -> int:
    """How many plan steps (from the first) the peers' lines bind: those at most
    ``peer_horizon`` seconds ahead (at least one; every step for None).

    Parameters
    ----------
    dt_plan : float
        The plan step (s).
    horizon : int
        Plan steps.
    peer_horizon : float, optional
        The near horizon (s).
    """
    if peer_horizon is None or not np.isfinite(peer_horizon):
        return int(horizon)
    return int(min(max(np.floor(float(peer_horizon) / float(dt_plan) + 1e-9), 1), horizon))


def between_steps(positions: np.ndarray, now: np.ndarray) -> np.ndarray:
    """The candidate plans at their steps and halfway between them (from the position
    now): shape (N, 2 H, 2), the halfway point before each step first.

    The lines bind there too: two robots whose plans are on their sides of the lines at
    every plan step may still cross each other's path between two steps (plans ``dt_plan``
    apart, 0.8 m at 2 m/s), and did -- issue 36's gates 4 random pair came within 0.68 m
    with both plans meeting every line (docs/multi-robot.md).

    Parameters
    ----------
    positions : ndarray of shape (N, H, 2)
        The plans' positions at plan steps 1..H (m).
    now : ndarray of shape (2,)
        The robot's position now (m): the plans' step 0.
    """
    n, h = positions.shape[0], positions.shape[1]
    prev = np.concatenate([np.broadcast_to(now, (n, 1, 2)), positions[:, :-1]], axis=1)
    out = np.empty((n, 2 * h, 2))
    out[:, 0::2] = 0.5 * (prev + positions)
    out[:, 1::2] = positions
    return out


def has_peer_terms(family: Any, state: Any) -> bool:
    """Whether :func:`peer_terms` has lines for this plan: a reciprocal family and a
    control instant that sees at least one peer.

    Parameters
    ----------
    family : SamplingMPC
        The planning family (its ``reciprocity``).
    state : ControlState
        The control instant (its ``peers`` view).
    """
    rec = getattr(family, "reciprocity", None)
    view = getattr(state, "peers", None)
    return not (rec is None or rec.mode != "reciprocal" or view is None or view.n_peers == 0)


def peer_terms(
    family: Any, state: Any, lam: float, positions: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """The candidate plans' clearance to the peers' lines and their intrusion over them
    (None without peers): the buffer is half the robots' collision distance (the family's
    ``d_c`` plus the reciprocity's robot margin) plus half the family's margin, minus half
    of lambda when lambda applies to the robots; only the steps within the reciprocity's
    ``peer_horizon`` count (:func:`near_steps`), each with the halfway point before it
    (:func:`between_steps`).

    Parameters
    ----------
    family : SamplingMPC
        The planning family (its ``reciprocity``, ``d_c``, ``margin`` and plan step).
    state : ControlState
        The control instant (its ``peers`` view, time and robot state).
    lam : float
        The lambda the plan is made with (m).
    positions : ndarray of shape (N, H, 2)
        The candidate plans' positions at plan steps 1..H (m).

    Returns
    -------
    clear, viol : ndarrays of shape (N,), or None
        Per candidate, its smallest margin to the lines (m; < 0 crosses one) and its
        summed intrusion over them (m).
    """
    if not has_peer_terms(family, state):
        return None
    rec = family.reciprocity
    view = state.peers
    lam_r = float(lam) if rec.lambda_on_robots else 0.0
    d_r = float(family.d_c) + float(rec.robot_margin)
    buffer = max(0.5 * d_r + 0.5 * (float(family.margin) - lam_r), 0.0)
    dt_plan = float(family.sampling.dt_plan)
    h = near_steps(dt_plan, positions.shape[1], rec.peer_horizon)
    near = between_steps(positions[:, :h], np.asarray(state.x, dtype=float)[:2])
    times = float(state.t) + 0.5 * dt_plan * np.arange(1, 2 * h + 1)
    own, peers = reference_paths(view, state.x, times, float(state.t))
    normal, offset = peer_lines(view, own, peers, buffer)
    return peer_clearance(near, normal, offset)
