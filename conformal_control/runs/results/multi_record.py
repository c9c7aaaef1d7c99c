"""The animation record of a multi-robot run (``animation.npz`` with ``kind = "multi"``).

Keys (``F`` frames from the start to the end of the run, ``M`` robots, ``P`` pedestrians
present during the run, ``K`` intervals, ``G`` most goals of a robot):

==================  ================  ===============================================
key                 shape             content
==================  ================  ===============================================
``kind``            ()                ``"multi"``
``frame``, ``t``    (F,)              video frame numbers, time since the start (s)
``robots``          (F, M, 2)         robot positions (m), finished robots included
``active``          (F, M)            the robot is still under way
``contact_ped``     (F, M)            closer than d_c to a pedestrian
``contact_robot``   (F, M)            closer than two robot radii to another robot
``peds``            (F, P, 2)         pedestrian positions (m), NaN when absent
``starts``          (M, 2)            start of each robot
``goals``           (M, G, 2)         goals of each robot (NaN padded)
``k_start``         (K,)              index into ``frame`` where interval k starts
``lam``             (K, M)            lambda_k of each robot (scene units, NaN once done)
==================  ================  ===============================================

plus scalars and strings: ``epsilon``, ``sensing_radius``, ``robot_radius``,
``agent_radius``, ``fps``, ``extent``, ``image``, ``scene``, ``lambda_unit``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from ...world.multi import MultiRobotWorld
    from .episode import RobotResult

__all__ = ["multi_record"]


def multi_record(
    world: MultiRobotWorld,
    results: list[RobotResult],
    track: dict[str, np.ndarray],
    *,
    epsilon: float,
) -> dict[str, Any]:
    """Assemble the record of a finished multi-robot run.

    Parameters
    ----------
    world : MultiRobotWorld
        The finished world (its pedestrians and robots).
    results : list of RobotResult
        Each robot's measured result.
    track : dict of arrays
        The robots' common per-frame track (``frame``, ``robots``, ``active``).
    epsilon : float
        The run's target loss (drawn as a reference line).

    Returns
    -------
    dict
        The compact record ``conformal-control animate`` renders.
    """
    sc = world.scene
    frames = np.asarray(track["frame"]) - sc.first_frame
    robots = np.asarray(track["robots"], dtype=float)
    win = world.pedestrians()[frames]
    cols = np.flatnonzero(np.isfinite(win[..., 0]).any(axis=0))
    peds = win[:, cols]
    n = robots.shape[1]
    with np.errstate(invalid="ignore"):
        if cols.size:
            d = np.hypot(
                peds[:, None, :, 0] - robots[:, :, None, 0],
                peds[:, None, :, 1] - robots[:, :, None, 1],
            )
            contact_ped = np.nanmin(np.where(np.isfinite(d), d, np.inf), axis=2) < (
                sc.collision_distance
            )
        else:
            contact_ped = np.zeros(robots.shape[:2], dtype=bool)
        dr = np.hypot(
            robots[:, :, None, 0] - robots[:, None, :, 0],
            robots[:, :, None, 1] - robots[:, None, :, 1],
        )
        dr[:, np.arange(n), np.arange(n)] = np.inf
        contact_robot = (
            dr.min(axis=2) < 2.0 * sc.robot_radius if n > 1 else np.zeros_like(contact_ped)
        )
    g = max(r.goals.shape[0] for r in results)
    goals = np.full((n, g, 2), np.nan)
    for r in results:
        goals[r.index, : r.goals.shape[0]] = r.goals
    k = max(len(r.intervals) for r in results)
    lam = np.full((k, n), np.nan)
    for r in results:
        for j, iv in enumerate(r.intervals):
            lam[j, r.index] = iv["lambda"]
    tau = world.tau_frames
    k_start = np.minimum(np.arange(k) * tau, max(frames.size - 1, 0))
    return {
        "kind": "multi",
        "frame": np.asarray(track["frame"]),
        "t": np.asarray(track["t"], dtype=float),
        "robots": robots.astype(np.float32),
        "active": np.asarray(track["active"], dtype=bool),
        "contact_ped": contact_ped,
        "contact_robot": contact_robot,
        "peds": peds.astype(np.float32),
        "starts": np.array([r.start for r in results], dtype=float),
        "goals": goals,
        "k_start": k_start,
        "lam": lam,
        "epsilon": float(epsilon),
        "sensing_radius": float(world.sensing_radius),
        "robot_radius": float(sc.robot_radius),
        "agent_radius": float(sc.agent_radius),
        "fps": float(sc.fps),
        "extent": np.asarray(sc.extent if sc.extent is not None else (np.nan, np.nan)),
        "image": str(sc.image) if sc.image is not None else "",
        "scene": sc.name,
        "lambda_unit": results[0].metrics.unit("lambda_final"),
    }
