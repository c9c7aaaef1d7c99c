"""``export --schema ros2`` and ``--format ros2-bag``: the run as ROS 2 messages, decoded
back with an independent decoder (mcap-ros2-support) and with rosbags, equal to the run
directory's files."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from conformal_control.io.export import export_run, read_run


def _decode_mcap(path: Path) -> dict[str, list[tuple[int, Any]]]:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, list[tuple[int, Any]]] = {}
    with path.open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            out.setdefault(channel.topic, []).append((message.log_time, decoded))
    return out


def _read_bag(path: Path) -> dict[str, list[tuple[int, Any]]]:
    from rosbags.highlevel import AnyReader

    out: dict[str, list[tuple[int, Any]]] = {}
    with AnyReader([path]) as reader:
        for con, ns, raw in reader.messages():
            out.setdefault(con.topic, []).append((ns, reader.deserialize(raw, con.msgtype)))
    return out


def _ns(t: np.ndarray) -> list[int]:
    return [round(float(v) * 1e9) for v in t]


def test_single_robot_mcap_decodes_to_the_run(single_run: Path, read_csv, tmp_path: Path) -> None:
    out = export_run(single_run, tmp_path / "r.mcap", schema="ros2")
    msgs = _decode_mcap(out)
    assert set(msgs) == {
        "/tf",
        "/robot/pose",
        "/robot/cmd_vel",
        "/robot/distance",
        "/robot/lambda",
        "/robot/loss",
        "/scene/robots",
        "/scene/pedestrians",
        "/scene/predictions",
        "/scene/map",
    }
    traj = read_csv(single_run / "trajectory.csv")
    t = np.array([r["t"] for r in traj])
    poses = msgs["/robot/pose"]
    assert [ns for ns, _ in poses] == _ns(t)
    assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in poses] == _ns(t)
    np.testing.assert_array_equal([m.pose.position.x for _, m in poses], [r["x"] for r in traj])
    np.testing.assert_array_equal([m.pose.position.y for _, m in poses], [r["y"] for r in traj])
    speed = [math.hypot(r["vx"], r["vy"]) for r in traj]
    np.testing.assert_allclose([m.linear.x for _, m in msgs["/robot/cmd_vel"]], speed)
    dist = [m.data for _, m in msgs["/robot/distance"]]
    np.testing.assert_array_equal(
        dist, [r["d_min"] if r["d_min"] is not None else math.nan for r in traj]
    )
    iv = read_csv(single_run / "intervals.csv")
    assert [m.data for _, m in msgs["/robot/lambda"]] == [r["lambda"] for r in iv]
    scored = [r for r in iv if r["loss"] is not None]
    assert scored and [m.data for _, m in msgs["/robot/loss"]] == [r["loss"] for r in scored]
    assert [ns for ns, _ in msgs["/robot/loss"]] == _ns(np.array([r["t"] for r in scored]))
    # pedestrians: a DELETEALL, then one cylinder per pedestrian present, id = its id
    rec = read_run(single_run)
    assert rec.peds is not None and rec.ped_ids is not None
    peds = msgs["/scene/pedestrians"]
    assert len(peds) == rec.peds.shape[0]
    for f in (0, len(peds) // 2, len(peds) - 1):
        ms = peds[f][1].markers
        assert ms[0].action == 3
        present = np.flatnonzero(np.isfinite(rec.peds[f, :, 0]))
        assert [m.id for m in ms[1:]] == rec.ped_ids[present].astype(int).tolist()
        np.testing.assert_array_equal([m.pose.position.x for m in ms[1:]], rec.peds[f, present, 0])
    assert len(msgs["/scene/predictions"]) == len(rec.predictions)


def test_bag_folder_of_either_storage_holds_the_same_messages(
    single_run: Path, tmp_path: Path
) -> None:
    mcap = _decode_mcap(export_run(single_run, tmp_path / "r.mcap", schema="ros2"))
    for storage in ("mcap", "sqlite3"):
        from conformal_control.io.export.to_ros2 import write_ros2_bag

        bag = write_ros2_bag(single_run, tmp_path / f"bag_{storage}", storage=storage)
        assert (bag / "metadata.yaml").is_file()
        got = _read_bag(bag)
        assert set(got) == set(mcap)
        for topic in ("/robot/pose", "/robot/lambda", "/scene/pedestrians"):
            assert [ns for ns, _ in got[topic]] == [ns for ns, _ in mcap[topic]], topic
        np.testing.assert_array_equal(
            [m.data for _, m in got["/robot/lambda"]], [m.data for _, m in mcap["/robot/lambda"]]
        )


def test_multi_robot_run(multi_run: Path, tmp_path: Path) -> None:
    msgs = _decode_mcap(export_run(multi_run, tmp_path / "m.mcap", schema="ros2"))
    rec = read_run(multi_run)
    for r in rec.robots:
        assert len(msgs[f"/{r.name}/pose"]) == r.trajectory["t"].size
    robots = msgs["/scene/robots"]
    assert max(len(m.markers) for _, m in robots) == 3


def test_cli_defaults_and_errors(single_run: Path, tmp_path: Path, capsys) -> None:
    import shutil

    from conformal_control.cli import main

    run = Path(shutil.copytree(single_run, tmp_path / "run"))
    assert main(["export", str(run), "--schema", "ros2"]) == 0
    assert (run / "run_ros2.mcap").is_file()
    assert main(["export", str(run), "--format", "ros2-bag"]) == 0
    assert (run / "run_ros2_bag" / "metadata.yaml").is_file()
    assert "run_ros2_bag" in capsys.readouterr().out
    # a bag folder is never written over
    assert main(["export", str(run), "--format", "ros2-bag"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists already" in err[0]
    assert main(["export", str(run), "--format", "rerun", "--schema", "ros2"]) != 0
    assert "--schema ros2 applies to --format mcap" in capsys.readouterr().err
    with pytest.raises(ValueError, match="unknown export schema"):
        export_run(run, schema="ros1")
