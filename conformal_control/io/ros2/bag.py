"""Read a robot's ROS 2 bag: the people it tracked and its odometry, in one frame.

:func:`read_bag` opens a ROS 2 bag -- a folder with ``metadata.yaml`` as ``ros2 bag
record`` writes it, or a bare ``.mcap`` or ``.db3`` file, either storage -- with
``rosbags`` (no ROS installation) and returns a :class:`RecordedBag`:

* the **people** topic: ``people_msgs/msg/People`` (a person's id is their ``name``;
  ``position`` is used, ``velocity`` ignored: the predictor works from the positions'
  history), or ``visualization_msgs/msg/MarkerArray`` (each marker with action ADD is one
  person, identified by its ``(ns, id)``, at its ``pose.position``; DELETE and DELETEALL
  markers are ignored). Names and marker keys become whole-number ids 0, 1, ... in order
  of first appearance (:attr:`PeopleTrack.names` maps them back);
* the **odometry** topic: ``nav_msgs/msg/Odometry``, the pose in ``header.frame_id`` and
  the twist, as ROS defines it, in ``child_frame_id`` (the robot's body): rotated here
  into the pose's frame with the pose's heading;
* **frames**: everything is expressed in the odometry's frame. People in another frame are
  moved into it with the static transforms of ``/tf_static`` (``tf2_msgs/msg/TFMessage``;
  any chain of them, in either direction, rotations about z only); frames that differ
  with no such chain are an error (dynamic ``/tf`` transforms are not used).

Times are the messages' header stamps (integer nanoseconds); a ``MarkerArray`` without
markers has no header and takes the bag's receive time. Every problem of the bag is one
line (:class:`~conformal_control.core.exceptions.DataFormatError`, or
:class:`~conformal_control.core.exceptions.InputError` for a topic option that does not fit):
a missing file, an unreadable bag, no messages, a missing topic or one of another type,
stamps out of order or repeated, non-finite poses, frames without a transform.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...core.exceptions import DataFormatError, InputError
from .types import MARKER_ARRAY, ODOMETRY, PEOPLE, TF_MESSAGE, require_rosbags, typestore

__all__ = ["OdometryTrack", "PeopleTrack", "RecordedBag", "read_bag"]

#: The people topic's accepted types.
PEOPLE_TYPES = (PEOPLE, MARKER_ARRAY)
#: visualization_msgs/Marker's ADD action (MODIFY has the same value in ROS 2).
_ADD = 0
#: Largest |qx|, |qy| of a transform's rotation that still counts as a rotation about z.
_TILT_TOL = 1e-6


@dataclass
class PeopleTrack:
    """The people topic, one entry per message (in the odometry's frame after
    :func:`read_bag`).

    Attributes
    ----------
    topic : str
        The topic's name.
    msgtype : str
        ``people_msgs/msg/People`` or ``visualization_msgs/msg/MarkerArray``.
    frame : str
        The frame the positions were recorded in (``header.frame_id``).
    stamps : ndarray of int64
        (N,) the messages' stamps (ns), increasing.
    ids : list of ndarray
        Per message, the whole-number ids of the people in it.
    positions : list of ndarray
        Per message, their (x, y) positions (m), one row per id.
    names : list of str
        ``names[i]`` is the name (or ``ns/id`` marker key) of id ``i``.
    """

    topic: str
    msgtype: str
    frame: str
    stamps: np.ndarray
    ids: list[np.ndarray]
    positions: list[np.ndarray]
    names: list[str]


@dataclass
class OdometryTrack:
    """The odometry topic (``nav_msgs/msg/Odometry``).

    Attributes
    ----------
    topic : str
        The topic's name.
    frame : str
        ``header.frame_id``: the frame of the poses (and of everything after
        :func:`read_bag`).
    child_frame : str
        ``child_frame_id``: the robot's body frame, the twist's frame.
    stamps : ndarray of int64
        (N,) the stamps (ns), strictly increasing.
    xy : ndarray
        (N, 2) positions (m).
    yaw : ndarray
        (N,) headings (rad, unwrapped: continuous across +-pi).
    velocity : ndarray
        (N, 2) velocities in ``frame`` (m/s): the twist's linear part rotated by ``yaw``.
    """

    topic: str
    frame: str
    child_frame: str
    stamps: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray
    velocity: np.ndarray


@dataclass
class RecordedBag:
    """What :func:`read_bag` read.

    Attributes
    ----------
    path : Path
        The bag (folder or file).
    people : PeopleTrack
        The people, in the odometry's frame.
    odometry : OdometryTrack
        The robot's recorded motion.
    transform : tuple of float
        The static transform applied to the people, (x (m), y (m), yaw (rad)) of their
        frame in the odometry's; ``(0, 0, 0)`` when the frames are the same.
    topics : dict of str to str
        Every topic of the bag and its type.
    """

    path: Path
    people: PeopleTrack
    odometry: OdometryTrack
    transform: tuple[float, float, float] = (0.0, 0.0, 0.0)
    topics: dict[str, str] = field(default_factory=dict)


# ---------------------------------------------------------------------------- helpers
def _stamp(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _yaw(q: Any, where: str) -> float:
    """Heading (rad) of quaternion ``q``; a non-finite or zero quaternion is an error."""
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    if not all(math.isfinite(v) for v in (x, y, z, w)):
        raise DataFormatError(f"{where}: the orientation is not finite ({x}, {y}, {z}, {w})")
    if x * x + y * y + z * z + w * w == 0.0:
        raise DataFormatError(f"{where}: the orientation is the zero quaternion")
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _finite(where: str, what: str, *values: float) -> None:
    if not all(math.isfinite(v) for v in values):
        raise DataFormatError(f"{where}: {what} is not finite {tuple(values)}")


def _check_order(topic: str, stamps: list[int], index: int) -> None:
    """Stamps of one topic strictly increase: an earlier or repeated one is an error."""
    if index and stamps[index] <= stamps[index - 1]:
        what = "repeats" if stamps[index] == stamps[index - 1] else "comes before"
        raise DataFormatError(
            f"topic {topic}: message {index} stamped {stamps[index] / 1e9:.9f} s {what} "
            f"message {index - 1} ({stamps[index - 1] / 1e9:.9f} s): stamps out of order"
        )


def _topic_list(topics: dict[str, str]) -> str:
    return ", ".join(f"{t} ({m})" for t, m in sorted(topics.items())) or "none"


def _find_topic(
    path: Path, topics: dict[str, str], topic: str, option: str, want: tuple[str, ...]
) -> str:
    if topic not in topics:
        raise InputError(
            f"{path}: no topic {topic!r} (give {option}; the bag's topics: {_topic_list(topics)})"
        )
    if topics[topic] not in want:
        raise InputError(
            f"{path}: topic {topic} is {topics[topic]}, {option} needs {' or '.join(want)}"
        )
    return topics[topic]


# ---------------------------------------------------------------------------- frames
Pose2 = tuple[float, float, float]


def _compose(a: Pose2, b: Pose2) -> Pose2:
    """a∘b: the pose b (given in a's child frame) expressed in a's parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2])


def _inverse(a: Pose2) -> Pose2:
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-(c * a[0] + s * a[1]), s * a[0] - c * a[1], -a[2])


def static_transform(edges: dict[tuple[str, str], Pose2], target: str, source: str) -> Pose2 | None:
    """The pose of frame ``source`` in frame ``target`` from a chain of static transforms
    (``edges[(parent, child)]`` = the child's pose in the parent), or None without one.

    Parameters
    ----------
    edges : dict
        ``(parent, child) -> (x, y, yaw)``.
    target, source : str
        The frame to express in, the frame of the data.
    """
    if source == target:
        return (0.0, 0.0, 0.0)
    graph: dict[str, list[tuple[str, Pose2]]] = {}
    for (parent, child), pose in edges.items():
        graph.setdefault(parent, []).append((child, pose))
        graph.setdefault(child, []).append((parent, _inverse(pose)))
    seen = {target: (0.0, 0.0, 0.0)}
    todo = deque([target])
    while todo:
        frame = todo.popleft()
        for nxt, pose in graph.get(frame, []):
            if nxt not in seen:
                seen[nxt] = _compose(seen[frame], pose)
                todo.append(nxt)
    return seen.get(source)


def _static_edges(reader: Any, path: Path, topics: dict[str, str]) -> dict[tuple[str, str], Pose2]:
    edges: dict[tuple[str, str], Pose2] = {}
    if topics.get("/tf_static") != TF_MESSAGE:
        return edges
    conns = [c for c in reader.connections if c.topic == "/tf_static"]
    for n, (conn, _, raw) in enumerate(reader.messages(connections=conns)):
        msg = _decode(reader, raw, conn, path, n)
        for tf in msg.transforms:
            where = f"{path}: /tf_static message {n}, {tf.header.frame_id} -> {tf.child_frame_id}"
            t, q = tf.transform.translation, tf.transform.rotation
            _finite(where, "the translation", float(t.x), float(t.y), float(t.z))
            yaw = _yaw(q, where)
            norm = math.sqrt(float(q.x) ** 2 + float(q.y) ** 2 + float(q.z) ** 2 + float(q.w) ** 2)
            if max(abs(float(q.x)), abs(float(q.y))) / norm > _TILT_TOL:
                raise DataFormatError(
                    f"{where}: the rotation is not about z (the people's plane is tilted); "
                    "only planar static transforms are supported"
                )
            edges[(str(tf.header.frame_id), str(tf.child_frame_id))] = (
                float(t.x),
                float(t.y),
                yaw,
            )
    return edges


# ---------------------------------------------------------------------------- reading
def _decode(reader: Any, raw: bytes, conn: Any, path: Path, index: int) -> Any:
    try:
        return reader.deserialize(raw, conn.msgtype)
    except Exception as exc:  # rosbags' AnyReaderError (not a ValueError)
        raise DataFormatError(
            f"{path}: topic {conn.topic}, message {index} cannot be decoded as "
            f"{conn.msgtype} ({exc})"
        ) from None


def _read_people(reader: Any, path: Path, topic: str, msgtype: str) -> PeopleTrack:
    conns = [c for c in reader.connections if c.topic == topic]
    key_to_id: dict[str, int] = {}
    stamps: list[int] = []
    ids: list[np.ndarray] = []
    positions: list[np.ndarray] = []
    frames: set[str] = set()
    for n, (conn, log_time, raw) in enumerate(reader.messages(connections=conns)):
        msg = _decode(reader, raw, conn, path, n)
        where = f"{path}: topic {topic}, message {n}"
        keys: list[str] = []
        xy: list[tuple[float, float]] = []
        if msgtype == PEOPLE:
            stamps.append(_stamp(msg.header))
            frames.add(str(msg.header.frame_id))
            for person in msg.people:
                p = person.position
                _finite(f"{where}, person {person.name!r}", "the position", p.x, p.y)
                keys.append(str(person.name))
                xy.append((float(p.x), float(p.y)))
        else:
            markers = [m for m in msg.markers if int(m.action) == _ADD]
            stamps.append(_stamp(markers[0].header) if markers else int(log_time))
            for m in markers:
                frames.add(str(m.header.frame_id))
                p = m.pose.position
                key = f"{m.ns}/{m.id}"
                _finite(f"{where}, marker {key}", "the position", p.x, p.y)
                keys.append(key)
                xy.append((float(p.x), float(p.y)))
        where = f"{where} (t = {stamps[-1] / 1e9:.9f} s)"
        if len(set(keys)) != len(keys):
            dup = next(k for k in keys if keys.count(k) > 1)
            raise DataFormatError(f"{where}: person {dup!r} appears twice in one message")
        if len(frames) > 1:
            raise DataFormatError(
                f"{where}: people in several frames ({', '.join(sorted(frames))}); one frame "
                "per topic"
            )
        _check_order(topic, stamps, n)
        for k in keys:
            key_to_id.setdefault(k, len(key_to_id))
        ids.append(np.array([key_to_id[k] for k in keys], dtype=np.int64))
        positions.append(np.array(xy, dtype=float).reshape(-1, 2))
    if not stamps:
        raise DataFormatError(f"{path}: topic {topic} has no messages")
    if not frames:
        raise DataFormatError(f"{path}: topic {topic}: no message has a person (no frame)")
    return PeopleTrack(
        topic=topic,
        msgtype=msgtype,
        frame=frames.pop(),
        stamps=np.array(stamps, dtype=np.int64),
        ids=ids,
        positions=positions,
        names=list(key_to_id),
    )


def _read_odometry(reader: Any, path: Path, topic: str) -> OdometryTrack:
    conns = [c for c in reader.connections if c.topic == topic]
    stamps: list[int] = []
    rows: list[tuple[float, float, float, float, float]] = []
    frames: set[tuple[str, str]] = set()
    for n, (conn, _, raw) in enumerate(reader.messages(connections=conns)):
        msg = _decode(reader, raw, conn, path, n)
        stamps.append(_stamp(msg.header))
        where = f"{path}: topic {topic}, message {n} (t = {stamps[-1] / 1e9:.9f} s)"
        frames.add((str(msg.header.frame_id), str(msg.child_frame_id)))
        if len(frames) > 1:
            pairs = " and ".join(" -> ".join(f) for f in sorted(frames))
            raise DataFormatError(f"{where}: the frames changed ({pairs})")
        _check_order(topic, stamps, n)
        p, v = msg.pose.pose.position, msg.twist.twist.linear
        _finite(where, "the position", p.x, p.y)
        _finite(where, "the linear velocity", v.x, v.y)
        yaw = _yaw(msg.pose.pose.orientation, where)
        rows.append((float(p.x), float(p.y), yaw, float(v.x), float(v.y)))
    if not stamps:
        raise DataFormatError(f"{path}: topic {topic} has no messages")
    arr = np.array(rows, dtype=float)
    heading: np.ndarray = np.unwrap(arr[:, 2])
    c, s = np.cos(heading), np.sin(heading)
    velocity = np.stack([c * arr[:, 3] - s * arr[:, 4], s * arr[:, 3] + c * arr[:, 4]], axis=1)
    frame, child = frames.pop()
    return OdometryTrack(
        topic=topic,
        frame=frame,
        child_frame=child,
        stamps=np.array(stamps, dtype=np.int64),
        xy=arr[:, :2].copy(),
        yaw=heading,
        velocity=velocity,
    )


def read_bag(
    path: str | Path, *, people_topic: str = "/people", odom_topic: str = "/odom"
) -> RecordedBag:
    """Read the people and the odometry of a ROS 2 bag (see the module docstring).

    Parameters
    ----------
    path : path
        A bag folder (with ``metadata.yaml``), or a ``.mcap`` or ``.db3`` file.
    people_topic : str
        ``people_msgs/msg/People`` or ``visualization_msgs/msg/MarkerArray``.
    odom_topic : str
        ``nav_msgs/msg/Odometry``.

    Returns
    -------
    RecordedBag
        People moved into the odometry's frame.

    Raises
    ------
    InputError
        The bag does not exist, or a topic is missing or of another type.
    DataFormatError
        The bag cannot be read or its content is not usable (one line saying where).
    """
    require_rosbags()
    from rosbags.highlevel import AnyReader

    bag = Path(path)
    if not bag.exists():
        raise InputError(
            f"{bag}: no such bag (a ROS 2 bag folder with metadata.yaml, or a .mcap or .db3 file)"
        )
    try:
        reader = AnyReader([bag], default_typestore=typestore())
        reader.open()
    except Exception as exc:  # rosbags' reader errors are not ValueErrors
        message = " ".join(str(exc).split()) or type(exc).__name__
        raise DataFormatError(f"{bag}: not a readable ROS 2 bag ({message})") from None
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        if reader.message_count == 0:
            raise DataFormatError(f"{bag}: the bag holds no messages")
        people_type = _find_topic(bag, topics, people_topic, "--people-topic", PEOPLE_TYPES)
        _find_topic(bag, topics, odom_topic, "--odom-topic", (ODOMETRY,))
        people = _read_people(reader, bag, people_topic, people_type)
        odom = _read_odometry(reader, bag, odom_topic)
        edges = _static_edges(reader, bag, topics)
    finally:
        reader.close()
    pose = static_transform(edges, odom.frame, people.frame)
    if pose is None:
        raise DataFormatError(
            f"{bag}: the people are in frame {people.frame!r}, the odometry in "
            f"{odom.frame!r}, and no static transform (/tf_static) links them; record one, "
            "or publish both in the same frame"
        )
    if pose != (0.0, 0.0, 0.0):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        rot = np.array([[c, -s], [s, c]])
        people.positions = [p @ rot.T + np.array(pose[:2]) for p in people.positions]
    return RecordedBag(path=bag, people=people, odometry=odom, transform=pose, topics=topics)
