"""Small ROS 2 bags written with rosbags for the tests: people, odometry, transforms."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from conformal_control.io.ros2.types import MARKER_ARRAY, ODOMETRY, PEOPLE, TF_MESSAGE, typestore
from conformal_control.io.ros2.writer import (
    CYLINDER,
    DELETEALL,
    Recording,
    header,
    marker,
    marker_array,
    point,
    pose,
    twist,
)

T0 = 1_000_000_000_000  # 1000 s: the bags' first stamp (ns)


def person(name: str, x: float, y: float) -> Any:
    t = typestore().types
    return t["people_msgs/msg/Person"](
        name=name,
        position=point(x, y),
        velocity=point(0.0, 0.0),
        reliability=1.0,
        tagnames=[],
        tags=[],
    )


def people_msg(ns: int, frame: str, crowd: Sequence[tuple[str, float, float]]) -> Any:
    return typestore().types[PEOPLE](
        header=header(ns, frame), people=[person(n, x, y) for n, x, y in crowd]
    )


def markers_msg(ns: int, frame: str, crowd: Sequence[tuple[str, float, float]]) -> Any:
    hdr = header(ns, frame)
    ms = [marker(hdr, "people", 0, CYLINDER, action=DELETEALL)]
    ms += [
        marker(hdr, "people", int(n.split("_")[-1]), CYLINDER, at=pose(x, y)) for n, x, y in crowd
    ]
    return marker_array(ms)


def odom_msg(
    ns: int, x: float, y: float, yaw: float, v: tuple[float, float], frame: str = "odom"
) -> Any:
    t = typestore().types
    cov = np.zeros(36)
    return t[ODOMETRY](
        header=header(ns, frame),
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose(x, y, yaw), covariance=cov),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist(*v), covariance=cov.copy()),
    )


def tf_msg(ns: int, parent: str, child: str, x: float, y: float, yaw: float) -> Any:
    t = typestore().types
    p = pose(x, y, yaw)
    tr = t["geometry_msgs/msg/Transform"](
        translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.0), rotation=p.orientation
    )
    return t[TF_MESSAGE](
        transforms=[
            t["geometry_msgs/msg/TransformStamped"](
                header=header(ns, parent), child_frame_id=child, transform=tr
            )
        ]
    )


def crowd_at(t: float) -> list[tuple[str, float, float]]:
    """Three people: two walking across the robot's line, one standing."""
    return [
        ("person_1", 4.0, -3.0 + 1.0 * t),
        ("person_2", 7.0, 4.0 - 0.8 * t),
        ("person_3", 9.0, 0.5),
    ]


def robot_at(t: float) -> tuple[float, float, float, tuple[float, float]]:
    """The robot drives along +x at 1 m/s (odometry: x, y, yaw, body twist)."""
    return (1.0 * t, 0.0, 0.0, (1.0, 0.0))


def simple_recording(
    *,
    seconds: float = 4.0,
    people_dt: float = 0.1,
    people_frame: str = "odom",
    people_topic: str = "/people",
    markers: bool = False,
    people_times: Sequence[float] | None = None,
    odom_rate: float = 50.0,
    robot: Callable[[float], tuple[float, float, float, tuple[float, float]]] = robot_at,
) -> Recording:
    """People at ``people_dt`` (or at ``people_times``), odometry at ``odom_rate``."""
    rec = Recording()
    times = (
        list(people_times)
        if people_times is not None
        else [k * people_dt for k in range(round(seconds / people_dt) + 1)]
    )
    for t in times:
        ns = T0 + round(t * 1e9)
        if markers:
            rec.add(people_topic, MARKER_ARRAY, ns, markers_msg(ns, people_frame, crowd_at(t)))
        else:
            rec.add(people_topic, PEOPLE, ns, people_msg(ns, people_frame, crowd_at(t)))
    for i in range(round(seconds * odom_rate) + 1):
        t = i / odom_rate
        ns = T0 + round(t * 1e9)
        x, y, yaw, v = robot(t)
        rec.add("/odom", ODOMETRY, ns, odom_msg(ns, x, y, yaw, v))
    return rec


@pytest.fixture(params=["mcap", "sqlite3"])
def storage(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def simple_bag(tmp_path: Path, storage: str) -> Path:
    """A 4 s bag: people (People, 10 Hz) and odometry (50 Hz) in ``odom``."""
    return simple_recording().write_bag(tmp_path / f"bag_{storage}", storage=storage)


@pytest.fixture
def rb() -> SimpleNamespace:
    """The builders above (tests import nothing from conftest)."""
    return SimpleNamespace(
        T0=T0,
        crowd_at=crowd_at,
        robot_at=robot_at,
        people_msg=people_msg,
        markers_msg=markers_msg,
        odom_msg=odom_msg,
        tf_msg=tf_msg,
        recording=simple_recording,
        PEOPLE=PEOPLE,
        MARKER_ARRAY=MARKER_ARRAY,
        ODOMETRY=ODOMETRY,
        TF_MESSAGE=TF_MESSAGE,
    )
