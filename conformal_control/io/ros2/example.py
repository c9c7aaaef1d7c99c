"""A robot's bag made from a built-in scene: the documentation's example, and the tests'.

:func:`scene_bag` writes what a robot driven straight to its goal through a scene's crowd
would have recorded, as a ROS 2 bag (no data from elsewhere):

* ``/people`` (``people_msgs/msg/People``, frame ``map``): the scene's pedestrians at the
  scene's rate, named ``person_<id>``, stamps with a small seeded jitter (a tracker's);
* ``/tracked_people`` (``visualization_msgs/msg/MarkerArray``, frame ``map``): the same
  people as cylinder markers (namespace ``people``, marker id = the pedestrian's id), the
  alternative a tracker may publish;
* ``/odom`` (``nav_msgs/msg/Odometry``, ``odom`` -> ``base_link``, 50 Hz): the robot,
  starting at the origin of ``odom`` facing the goal and driving straight to it at
  ``speed`` (then standing), ignoring everyone -- the motion shadow mode is asked about;
* ``/tf_static`` (``tf2_msgs/msg/TFMessage``): ``map`` -> ``odom``, the robot's start
  pose in the scene.

Stamps start at ``t0_ns`` (a wall-clock-like epoch, as a real robot's).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .types import MARKER_ARRAY, ODOMETRY, PEOPLE, TF_MESSAGE
from .writer import CYLINDER, DELETEALL, Recording, header, marker, marker_array, point, pose, twist

__all__ = ["ODOM_RATE", "scene_bag"]

#: Rate of the odometry topic (Hz).
ODOM_RATE = 50.0


def scene_bag(
    path: str | Path,
    scene: str = "crossing",
    *,
    storage: str = "mcap",
    seconds: float = 30.0,
    speed: float = 1.0,
    seed: int = 0,
    t0_ns: int = 1_700_000_000_000_000_000,
) -> Path:
    """Write a robot's bag made from a built-in scene (see the module docstring).

    Parameters
    ----------
    path : path
        The bag folder to create (it must not exist).
    scene : str
        A scene that needs no data (``crossing``).
    storage : {"mcap", "sqlite3"}
        The bag's storage.
    seconds : float
        Length of the recording (s) from the scene's start frame.
    speed : float
        The robot's speed (m/s) on its straight line to the goal.
    seed : int
        Seed of the stamps' jitter.
    t0_ns : int
        The first stamp (ns).

    Returns
    -------
    Path
        The bag folder; the goal in ``odom`` is the scene's goal minus its start.
    """
    from ...data.scenes import load_scene

    sc = load_scene(scene)
    rng = np.random.default_rng(seed)
    dt = 1.0 / float(sc.fps)
    frames = min(round(seconds / dt), sc.positions.shape[0] - sc.start_index)
    pos = sc.positions[sc.start_index : sc.start_index + frames]
    start = np.asarray(sc.start, dtype=float)
    goal = np.asarray(sc.goals[0], dtype=float) - start
    heading = math.atan2(goal[1], goal[0])
    rec = Recording()
    tf = _static_tf(t0_ns, start, 0.0)
    rec.add("/tf_static", TF_MESSAGE, t0_ns, tf)
    # people: the scene's rate, stamps jittered by up to 5 ms (never out of order)
    jitter = rng.uniform(-0.005, 0.005, size=frames)
    for f in range(frames):
        ns = t0_ns + round((f * dt + jitter[f]) * 1e9)
        present = np.flatnonzero(np.isfinite(pos[f, :, 0]))
        hdr = header(ns, "map")
        persons = [_person(f"person_{int(sc.agent_ids[m])}", pos[f, m]) for m in present]
        rec.add("/people", PEOPLE, ns, _people(hdr, persons))
        markers = [marker(hdr, "people", 0, CYLINDER, action=DELETEALL)]
        markers += [
            marker(
                hdr,
                "people",
                int(sc.agent_ids[m]),
                CYLINDER,
                at=pose(pos[f, m, 0], pos[f, m, 1], z=0.85),
                scale=(0.6, 0.6, 1.7),
                rgba=(0.35, 0.55, 0.8, 0.9),
            )
            for m in present
        ]
        rec.add("/tracked_people", MARKER_ARRAY, ns, marker_array(markers))
    # odometry: straight to the goal at `speed`, then standing
    distance = float(np.hypot(*goal))
    n_odom = round(frames * dt * ODOM_RATE)
    for i in range(n_odom):
        t = i / ODOM_RATE
        s = min(speed * t, distance)
        moving = speed * t < distance
        xy = goal / distance * s
        ns = t0_ns + round(t * 1e9)
        rec.add("/odom", ODOMETRY, ns, _odometry(ns, xy, heading, speed if moving else 0.0))
    return rec.write_bag(path, storage=storage)


def _person(name: str, xy: np.ndarray) -> object:
    from .types import typestore

    t = typestore().types
    return t["people_msgs/msg/Person"](
        name=name,
        position=point(xy[0], xy[1]),
        velocity=point(0.0, 0.0),
        reliability=1.0,
        tagnames=[],
        tags=[],
    )


def _people(hdr: object, persons: list[object]) -> object:
    from .types import typestore

    return typestore().types[PEOPLE](header=hdr, people=persons)


def _odometry(ns: int, xy: np.ndarray, yaw: float, v: float) -> object:
    from .types import typestore

    t = typestore().types
    cov = np.zeros(36, dtype=np.float64)
    return t[ODOMETRY](
        header=header(ns, "odom"),
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=pose(xy[0], xy[1], yaw), covariance=cov
        ),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=twist(v, 0.0), covariance=cov.copy()
        ),
    )


def _static_tf(ns: int, xy: np.ndarray, yaw: float) -> object:
    from .types import typestore

    t = typestore().types
    p = pose(xy[0], xy[1], yaw)
    tr = t["geometry_msgs/msg/Transform"](
        translation=t["geometry_msgs/msg/Vector3"](x=float(xy[0]), y=float(xy[1]), z=0.0),
        rotation=p.orientation,
    )
    stamped = t["geometry_msgs/msg/TransformStamped"](
        header=header(ns, "map"), child_frame_id="odom", transform=tr
    )
    return t[TF_MESSAGE](transforms=[stamped])
