"""The MCAP export read back: topics, counts, timestamps and values equal the run's files."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
from mcap.reader import make_reader

from conformal_control.core.exceptions import DataFormatError
from conformal_control.io.export import export_run, read_run


def _read(path):
    """topic -> list of (log_time, publish_time, sequence, message); schemas by topic."""
    out, schemas = {}, {}
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        for schema, channel, msg in reader.iter_messages(log_time_order=False):
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            schemas[channel.topic] = (schema.name, json.loads(schema.data))
            data = json.loads(msg.data)
            out.setdefault(channel.topic, []).append(
                (msg.log_time, msg.publish_time, msg.sequence, data)
            )
    return out, schemas


def _ns(t: float) -> int:
    return round(t * 1e9)


def test_single_run_topics_counts_and_values(single_run, read_csv):
    path = export_run(single_run)
    assert path == single_run / "run.mcap"
    topics, schemas = _read(path)
    traj = read_csv(single_run / "trajectory.csv")
    intervals = read_csv(single_run / "intervals.csv")
    trace = read_csv(single_run / "trace.csv")
    anim = np.load(single_run / "animation.npz")
    assert {t: n for t, (n, _) in schemas.items()} == {
        "/tf": "foxglove.FrameTransform",
        "/robot/pose": "foxglove.PoseInFrame",
        "/robot/state": "conformal_control.RobotState",
        "/robot/conformal": "conformal_control.ConformalInterval",
        "/scene/map": "foxglove.SceneUpdate",
        "/scene/robots": "foxglove.SceneUpdate",
        "/scene/pedestrians": "foxglove.SceneUpdate",
        "/scene/predictions": "foxglove.SceneUpdate",
    }
    n = len(traj)
    for topic in ("/tf", "/robot/pose", "/robot/state", "/scene/robots", "/scene/pedestrians"):
        assert len(topics[topic]) == n, topic
    # the robot: every row of trajectory.csv, at its time, with the same numbers
    for row, (log, pub, _, st), (tlog, _, _, tf) in zip(
        traj, topics["/robot/state"], topics["/tf"], strict=True
    ):
        assert log == pub == tlog == _ns(row["t"])
        assert {k: st[k] for k in ("frame", "t", "x", "y", "vx", "vy", "d_min")} == row
        assert st["speed"] == math.hypot(row["vx"], row["vy"])
        assert tf["parent_frame_id"] == "world" and tf["child_frame_id"] == "robot"
        assert (tf["translation"]["x"], tf["translation"]["y"]) == (row["x"], row["y"])
        assert tf["timestamp"] == {"sec": log // 10**9, "nsec": log % 10**9}
    assert [m[2] for m in topics["/robot/state"]] == list(range(n))  # sequence numbers
    np.testing.assert_array_equal([m[3]["status"] for m in topics["/robot/state"]], anim["status"])
    # lambda and loss: every row of intervals.csv; the scored ones are trace.csv
    conf = topics["/robot/conformal"]
    assert len(conf) == len(intervals)
    for row, (log, _, _, msg) in zip(intervals, conf, strict=True):
        assert log == _ns(row["t"])
        assert {k: msg[k] for k in row} == row
        assert msg["epsilon"] == -0.1
    scored = [
        {k: m[3][k] for k in ("k", "t", "lambda", "loss")} for m in conf if m[3]["loss"] is not None
    ]
    assert scored == trace and len(trace) > 0
    # the scene: pedestrians present per frame, predictions per interval with sensed agents
    peds = anim["peds"]
    for f, (_, _, _, upd) in enumerate(topics["/scene/pedestrians"]):
        (ent,) = upd["entities"]
        cyl = ent["cylinders"]
        assert len(cyl) == int(np.isfinite(peds[f, :, 0]).sum())
        xy = [(c["pose"]["position"]["x"], c["pose"]["position"]["y"]) for c in cyl]
        np.testing.assert_array_equal(xy, peds[f][np.isfinite(peds[f, :, 0])].astype(float))
    with_preds = int((anim["pred_cols"] >= 0).any(axis=1).sum())
    assert len(topics["/scene/predictions"]) == with_preds > 0
    times = [m[0] for ms in topics.values() for m in ms]
    assert min(times) == 0 and max(times) == _ns(traj[-1]["t"])


def test_messages_follow_their_schemas_strictly(single_run, multi_run):
    import jsonschema

    def strict(schema):
        if isinstance(schema, dict):
            out = {k: strict(v) for k, v in schema.items()}
            if "properties" in schema:
                out["additionalProperties"] = False
            return out
        if isinstance(schema, list):
            return [strict(v) for v in schema]
        return schema

    for run in (single_run, multi_run):
        topics, schemas = _read(export_run(run, run / "strict.mcap"))
        for topic, messages in topics.items():
            validator = jsonschema.Draft202012Validator(strict(schemas[topic][1]))
            for m in messages:
                validator.validate(m[3])


def test_file_is_in_time_order_deterministic_and_read_by_an_independent_reader(single_run):
    a = export_run(single_run, single_run / "a.mcap")
    b = export_run(single_run, single_run / "b.mcap")
    assert a.read_bytes() == b.read_bytes()
    with open(a, "rb") as fh:
        reader = make_reader(fh)
        times = [m.log_time for _, _, m in reader.iter_messages(log_time_order=False)]
        summary = reader.get_summary()
        attachments = list(reader.iter_attachments())
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert times == sorted(times)
    assert [x.name for x in attachments] == ["config.json"]
    assert json.loads(attachments[0].data) == json.loads((single_run / "config.json").read_text())
    assert metadata["conformal_control"]["lambda_unit"] == "1/s"
    counts = {
        summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()
    }
    # Rerun's MCAP reader (Rust, written apart from the mcap package) sees the same file
    from rerun.chunk import McapReader

    info = McapReader(a).info()
    assert {c.topic: c.message_count for c in info.channels} == counts
    assert info.message_count == len(times)


def test_multi_robot_run(multi_run, read_csv):
    topics, _ = _read(export_run(multi_run))
    rec = read_run(multi_run)
    assert [r.name for r in rec.robots] == ["robot_0", "robot_1", "robot_2"]
    n_tf = 0
    for i, r in enumerate(rec.robots):
        traj = read_csv(multi_run / "robots" / f"robot_{i:02d}" / "trajectory.csv")
        intervals = read_csv(multi_run / "robots" / f"robot_{i:02d}" / "intervals.csv")
        states = topics[f"/{r.name}/state"]
        assert [{k: m[3][k] for k in traj[0]} for m in states] == traj
        assert [m[0] for m in states] == [_ns(row["t"]) for row in traj]
        conf = topics[f"/{r.name}/conformal"]
        assert [{k: m[3][k] for k in intervals[0]} for m in conf] == intervals
        n_tf += len(traj)
    assert len(topics["/tf"]) == n_tf
    frames = np.load(multi_run / "animation.npz")["t"].size
    assert len(topics["/scene/robots"]) == len(topics["/scene/pedestrians"]) == frames
    assert all(len(m[3]["entities"]) == 3 for m in topics["/scene/robots"])
    assert "/scene/predictions" not in topics


def test_run_without_animation_exports_the_robot_only(single_run, tmp_path, capsys):
    from conformal_control.cli import main

    run = tmp_path / "run"
    shutil.copytree(single_run, run)
    (run / "animation.npz").unlink()
    assert main(["export", str(run), "--out", str(tmp_path / "x.mcap")]) == 0
    out = capsys.readouterr().out
    assert "x.mcap" in out and "no animation.npz" in out
    topics, _ = _read(tmp_path / "x.mcap")
    assert set(topics) == {"/tf", "/robot/pose", "/robot/state", "/robot/conformal", "/scene/map"}


IV = "k,t,lambda,loss,loss_applied,max_gap,n_sensed,n_steps"
TR = "frame,t,x,y,vx,vy,d_min"


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda d: (d / "trajectory.csv").unlink(), "trajectory.csv not found"),
        (lambda d: (d / "config.json").unlink(), "not a run directory"),
        (lambda d: (d / "intervals.csv").write_text(f"{IV}\n1,2\n"), "line 2: 2 cells"),
        (lambda d: (d / "trajectory.csv").write_text(f"{TR}\nx,1,0,0,0,0,1\n"), "column frame"),
    ],
)
def test_incomplete_or_damaged_run_directories_fail_in_one_line(
    single_run, tmp_path, damage, message
):
    run = tmp_path / "run"
    shutil.copytree(single_run, run)
    damage(run)
    with pytest.raises((FileNotFoundError, DataFormatError), match=message):
        export_run(run)


def test_unknown_format_is_refused_with_a_suggestion(single_run):
    with pytest.raises(ValueError, match="did you mean 'mcap'"):
        export_run(single_run, format="mcp")


def test_start_time_puts_the_run_on_a_date(single_run, tmp_path, capsys):
    """The issue: an exported run started at 1970-01-01. `--start-time` (``start_time=``)
    shows its first frame at the date given: every log time and every timestamp inside the
    messages moves by the same offset; without it the file stays the same for the same run."""
    from conformal_control.cli import EXIT_ERROR, main

    plain, _ = _read(export_run(single_run, tmp_path / "plain.mcap"))
    out = tmp_path / "dated.mcap"
    assert (
        main(["export", str(single_run), "--out", str(out), "--start-time", "2026-05-04T09:30:00Z"])
        == 0
    )
    dated, _ = _read(out)
    offset = 1_777_887_000 * 10**9  # 2026-05-04T09:30:00Z, seconds since the epoch
    assert set(dated) == set(plain)
    for topic in plain:
        assert [m[0] - offset for m in dated[topic]] == [m[0] for m in plain[topic]], topic
    stamp = dated["/tf"][5][3]["timestamp"]
    assert stamp["sec"] * 10**9 + stamp["nsec"] == plain["/tf"][5][0] + offset
    assert (
        export_run(single_run, tmp_path / "again.mcap").read_bytes()
        == (tmp_path / "plain.mcap").read_bytes()
    )
    capsys.readouterr()
    argv = ["export", str(single_run), "--out", str(tmp_path / "x.mcap"), "--start-time", "May 4"]
    assert main(argv) == EXIT_ERROR
    err = capsys.readouterr().err.strip()
    assert err == (
        "error: start time 'May 4' is not an ISO 8601 date and time, e.g. 2026-05-04T09:30:00Z"
    )
    assert not (tmp_path / "x.mcap").exists()
