"""Reading a robot's ROS 2 bag: both storages, folder or bare file, People or MarkerArray,
frames and static transforms, and a one-line error for every kind of bad bag."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from conformal_control.core.exceptions import DataFormatError, InputError
from conformal_control.io.ros2.bag import read_bag, static_transform
from conformal_control.io.ros2.types import PEOPLE_MSGS, typestore
from conformal_control.io.ros2.writer import Recording


def _one_line(exc: pytest.ExceptionInfo[BaseException]) -> str:
    text = str(exc.value)
    assert "\n" not in text and text, text
    return text


def test_reads_people_and_odometry_as_written(simple_bag: Path, rb) -> None:
    bag = read_bag(simple_bag)
    p, o = bag.people, bag.odometry
    assert p.msgtype == rb.PEOPLE and p.frame == "odom" and o.frame == "odom"
    assert o.child_frame == "base_link"
    assert p.stamps.size == 41 and o.stamps.size == 201
    assert p.stamps[0] == rb.T0 and p.stamps[10] == rb.T0 + 1_000_000_000
    assert p.names == ["person_1", "person_2", "person_3"]
    for k in (0, 17, 40):
        t = k * 0.1
        assert p.ids[k].tolist() == [0, 1, 2]
        want = np.array([[x, y] for _, x, y in rb.crowd_at(t)])
        np.testing.assert_array_equal(p.positions[k], want)
    np.testing.assert_allclose(o.xy[:, 0], np.arange(201) / 50.0)
    np.testing.assert_allclose(o.velocity, np.tile([1.0, 0.0], (201, 1)))
    assert bag.transform == (0.0, 0.0, 0.0)


def test_reads_a_bare_storage_file(simple_bag: Path, storage: str) -> None:
    (file,) = simple_bag.glob("*.mcap" if storage == "mcap" else "*.db3")
    a, b = read_bag(simple_bag), read_bag(file)
    np.testing.assert_array_equal(a.people.stamps, b.people.stamps)
    np.testing.assert_array_equal(a.odometry.xy, b.odometry.xy)


def test_marker_array_people_get_ids_from_their_keys(tmp_path: Path, rb) -> None:
    path = rb.recording(markers=True, people_topic="/tracked").write_bag(tmp_path / "b")
    p = read_bag(path, people_topic="/tracked").people
    assert p.msgtype == rb.MARKER_ARRAY
    assert p.names == ["people/1", "people/2", "people/3"]  # DELETEALL markers ignored
    np.testing.assert_array_equal(p.positions[5], [[x, y] for _, x, y in rb.crowd_at(0.5)])


def test_odometry_twist_is_rotated_from_the_body_frame(tmp_path: Path, rb) -> None:
    """A robot heading +y (yaw pi/2) moving forward at 1 m/s moves along +y."""

    def north(t: float):
        return (0.0, t, math.pi / 2, (1.0, 0.0))

    path = rb.recording(robot=north).write_bag(tmp_path / "b")
    o = read_bag(path).odometry
    np.testing.assert_allclose(o.velocity, np.tile([0.0, 1.0], (o.stamps.size, 1)), atol=1e-12)
    np.testing.assert_allclose(o.yaw, math.pi / 2)


def test_people_in_another_frame_need_a_static_transform(tmp_path: Path, rb) -> None:
    rec = rb.recording(people_frame="map")
    with pytest.raises(DataFormatError) as exc:
        read_bag(rec.write_bag(tmp_path / "a"))
    msg = _one_line(exc)
    assert "'map'" in msg and "'odom'" in msg and "/tf_static" in msg
    # with map -> odom: odom's origin at (2, 1) in map, turned by +90 degrees
    rec.add(
        "/tf_static", rb.TF_MESSAGE, rb.T0, rb.tf_msg(rb.T0, "map", "odom", 2.0, 1.0, math.pi / 2)
    )
    bag = read_bag(rec.write_bag(tmp_path / "b"))
    x_map, y_map = rb.crowd_at(0.0)[0][1:]  # person_1 at (4, -3) in map
    # in odom: rotate (p - t) by -90 degrees: (dx, dy) -> (dy, -dx)
    want = (y_map - 1.0, -(x_map - 2.0))
    np.testing.assert_allclose(bag.people.positions[0][0], want, atol=1e-12)
    assert bag.transform == pytest.approx((-1.0, 2.0, -math.pi / 2))


def test_static_transform_chains_in_either_direction() -> None:
    edges = {("map", "odom"): (1.0, 0.0, 0.0), ("world", "map"): (0.0, 2.0, math.pi)}
    # the pose of world in odom: invert both hops
    pose = static_transform(edges, "odom", "world")
    assert pose is not None
    c, s = math.cos(pose[2]), math.sin(pose[2])
    # world's origin -> map (0, 2) -> odom (-1, 2)
    assert (pose[0], pose[1]) == pytest.approx((-1.0, 2.0))
    # world's x axis points along -x of map, hence of odom
    assert (c, s) == pytest.approx((-1.0, 0.0), abs=1e-12)
    assert static_transform(edges, "odom", "camera") is None
    assert static_transform(edges, "odom", "odom") == (0.0, 0.0, 0.0)


def test_people_msgs_are_registered_from_their_text() -> None:
    store = typestore()
    for name in PEOPLE_MSGS:
        assert name in store.types
    fields = [f[0] for f in store.fielddefs["people_msgs/msg/Person"][1]]
    assert fields == ["name", "position", "velocity", "reliability", "tagnames", "tags"]


# ---------------------------------------------------------------------------- bad bags
def test_missing_bag(tmp_path: Path) -> None:
    with pytest.raises(InputError) as exc:
        read_bag(tmp_path / "nothing")
    assert "no such bag" in _one_line(exc)


def test_not_a_bag(tmp_path: Path) -> None:
    path = tmp_path / "notes.mcap"
    path.write_text("not a bag\n")
    with pytest.raises(DataFormatError) as exc:
        read_bag(path)
    assert "not a readable ROS 2 bag" in _one_line(exc)


def test_empty_bag(tmp_path: Path, storage: str, rb) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer

    path = tmp_path / "empty"
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        w.add_connection("/people", rb.PEOPLE, typestore=typestore())
        w.add_connection("/odom", rb.ODOMETRY, typestore=typestore())
    with pytest.raises(DataFormatError) as exc:
        read_bag(path)
    assert "holds no messages" in _one_line(exc)


def test_missing_topics(simple_bag: Path) -> None:
    with pytest.raises(InputError) as exc:
        read_bag(simple_bag, people_topic="/tracks")
    msg = _one_line(exc)
    assert "no topic '/tracks'" in msg and "--people-topic" in msg
    assert "/odom (nav_msgs/msg/Odometry)" in msg and "/people (people_msgs/msg/People)" in msg
    with pytest.raises(InputError) as exc:
        read_bag(simple_bag, odom_topic="/odometry/filtered")
    assert "--odom-topic" in _one_line(exc)


def test_topics_of_the_wrong_type(simple_bag: Path) -> None:
    with pytest.raises(InputError) as exc:
        read_bag(simple_bag, people_topic="/odom")
    msg = _one_line(exc)
    assert "/odom is nav_msgs/msg/Odometry" in msg and "people_msgs/msg/People" in msg
    with pytest.raises(InputError) as exc:
        read_bag(simple_bag, odom_topic="/people")
    assert "needs nav_msgs/msg/Odometry" in _one_line(exc)


def test_a_topic_without_messages(tmp_path: Path, rb) -> None:
    rec = rb.recording()
    rec.topics["/scan_people"] = rb.PEOPLE  # registered, never written
    with pytest.raises(DataFormatError) as exc:
        read_bag(rec.write_bag(tmp_path / "b"), people_topic="/scan_people")
    assert "/scan_people has no messages" in _one_line(exc)


@pytest.mark.parametrize("repeat", [False, True])
def test_out_of_order_stamps(tmp_path: Path, rb, repeat: bool) -> None:
    rec = Recording()
    stamps = [0, 100, 200, 200 if repeat else 150, 300]
    for i, ms in enumerate(stamps):
        # received in this order (the receive time increases), stamped out of order
        ns = rb.T0 + ms * 1_000_000
        rec.add("/people", rb.PEOPLE, rb.T0 + i, rb.people_msg(ns, "odom", rb.crowd_at(0)))
    rec.add("/odom", rb.ODOMETRY, rb.T0, rb.odom_msg(rb.T0, 0, 0, 0, (0, 0)))
    with pytest.raises(DataFormatError) as exc:
        read_bag(rec.write_bag(tmp_path / "b"))
    msg = _one_line(exc)
    assert "topic /people: message 3" in msg and "out of order" in msg
    assert ("repeats" if repeat else "comes before") in msg


def test_nan_person(tmp_path: Path, rb) -> None:
    rec = rb.recording()
    ns = rb.T0 + 5_000_000_000
    rec.add("/people", rb.PEOPLE, ns, rb.people_msg(ns, "odom", [("ghost", math.nan, 1.0)]))
    with pytest.raises(DataFormatError) as exc:
        read_bag(rec.write_bag(tmp_path / "b"))
    msg = _one_line(exc)
    assert "person 'ghost'" in msg and "not finite" in msg and "message 41" in msg


def test_nan_odometry(tmp_path: Path, rb) -> None:
    rec = rb.recording()
    ns = rb.T0 + 5_000_000_000
    rec.add("/odom", rb.ODOMETRY, ns, rb.odom_msg(ns, 1.0, math.inf, 0.0, (0.0, 0.0)))
    with pytest.raises(DataFormatError) as exc:
        read_bag(rec.write_bag(tmp_path / "b"))
    msg = _one_line(exc)
    assert "topic /odom" in msg and "position is not finite" in msg


def test_a_tilted_static_transform(tmp_path: Path, rb) -> None:
    rec = rb.recording(people_frame="camera")
    tf = rb.tf_msg(rb.T0, "odom", "camera", 0.0, 0.0, 0.0)
    q = tf.transforms[0].transform.rotation
    q.x, q.w = math.sin(0.2), math.cos(0.2)  # rolled by 0.4 rad
    rec.add("/tf_static", rb.TF_MESSAGE, rb.T0, tf)
    with pytest.raises(DataFormatError) as exc:
        read_bag(rec.write_bag(tmp_path / "b"))
    assert "not about z" in _one_line(exc)


def test_the_cli_prints_one_line(tmp_path: Path, simple_bag: Path, capsys) -> None:
    from conformal_control.cli import main

    code = main(
        [
            "shadow",
            str(simple_bag),
            "--goal",
            "10,0",
            "--people-topic",
            "/nope",
            "--out",
            str(tmp_path / "out"),
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and err[0].startswith("error: ") and "/nope" in err[0]
    assert not (tmp_path / "out").exists()
