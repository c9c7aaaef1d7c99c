"""Shadow mode: the commands are the step-wise controller's on the recorded data, the
timing counts are honest, and every output reads back equal to ``commands.csv``."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from conformal_control.core.exceptions import DataFormatError, InputError
from conformal_control.families.cbf.stepwise import StepwiseCBF, Stream
from conformal_control.io.ros2.shadow import COLUMNS, shadow


def _read_commands(path: Path) -> dict[str, np.ndarray]:
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert rows and list(rows[0]) == list(COLUMNS)
    out = {}
    for c in COLUMNS:
        if c in ("stamp_ns", "fallback"):
            out[c] = np.array([int(r[c]) for r in rows], dtype=np.int64)
        else:
            out[c] = np.array([float(r[c]) if r[c] else math.nan for r in rows])
    return out


def test_commands_are_the_stepwise_controllers_on_the_recording(simple_bag: Path, rb) -> None:
    """People on an exact 10 Hz grid, odometry at 50 Hz: driving StepwiseCBF by hand with
    the same samples and the recorded states gives the same commands, lambdas and losses."""
    res = shadow(simple_bag, (10.0, 0.0), params={"epsilon": -0.05, "eta": 0.5, "substeps": 2})
    assert res.config["stream"] == {"tau": 0.4, "dt": 0.1, "substeps": 2, "dt_from_data": True}
    assert res.counts["n_merged"] == res.counts["n_missing"] == res.counts["n_held"] == 0
    ctrl = StepwiseCBF(epsilon=-0.05, eta=0.5, stream=Stream(tau=0.4, dt=0.1, substeps=2))
    goal = np.array([10.0, 0.0])
    cmds, lams, losses = [], [], []
    for k in range(res.counts["n_samples"]):
        crowd = rb.crowd_at(k * 0.1)
        ctrl.observe([0, 1, 2], np.array([[x, y] for _, x, y in crowd]), t=k * 0.1)
        for j in range(2):
            t = k * 0.1 + j * 0.05
            n = len(ctrl.result().intervals)
            cmds.append(ctrl.step(np.array([t, 0.0, 1.0, 0.0]), t=t, goal=goal))
            lams.append(ctrl.lam)
            new = ctrl.result().intervals[n:]
            losses.append(new[-1].loss if new and new[-1].loss is not None else math.nan)
    c = res.commands
    assert c["t"].size == len(cmds) == 2 * 40  # the last sample's instants need odometry beyond 4 s
    np.testing.assert_allclose(np.c_[c["vx"], c["vy"]], np.array(cmds), rtol=0, atol=1e-9)
    np.testing.assert_allclose(c["lambda"], lams, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.isnan(c["loss"]), np.isnan(losses))
    np.testing.assert_allclose(c["loss"][~np.isnan(c["loss"])], np.array(losses)[~np.isnan(losses)])
    assert np.isfinite(c["loss"]).sum() == res.result.n_updates >= 8
    assert c["stamp_ns"][0] == rb.T0 and c["stamp_ns"][3] == rb.T0 + 150_000_000
    # heading 0: the body frame is the odometry's
    np.testing.assert_array_equal(c["vx_body"], c["vx"])


def test_body_frame_commands_turn_with_the_robot(tmp_path: Path, rb) -> None:
    def north(t: float):
        return (0.0, t, math.pi / 2, (1.0, 0.0))

    res = shadow(rb.recording(robot=north).write_bag(tmp_path / "b"), (0.0, 10.0))
    c = res.commands
    # body x is the world's +y, body y the world's -x
    np.testing.assert_allclose(c["vx_body"], c["vy"], atol=1e-12)
    np.testing.assert_allclose(c["vy_body"], -c["vx"], atol=1e-12)
    assert np.abs(c["vy"]).max() > 0.5


def test_jitter_dropouts_and_doubles_are_counted(tmp_path: Path, rb) -> None:
    """Stamps jittered by 20 ms; sample 6 missing (between sampling times: a dropout),
    sample 8 missing (a sampling time: the previous one is held), two messages near 1.3 s
    (one merged)."""
    times = [k * 0.1 + (0.02 if k % 2 else -0.02) for k in range(41) if k not in (6, 8)]
    times[0] = 0.0
    times.append(1.34)
    times.sort()
    res = shadow(rb.recording(people_times=times).write_bag(tmp_path / "b"), (10.0, 0.0))
    assert res.config["stream"]["dt"] == pytest.approx(0.1)
    assert res.counts["n_missing"] == 1
    assert res.counts["n_held"] == 1
    assert res.counts["n_merged"] == 1
    assert res.counts["n_samples"] == 38


def test_the_grid_fits_tau(tmp_path: Path, rb) -> None:
    """People at 15 Hz: dt = 0.4 / 6 (the nearest whole number of samples per interval)."""
    times = [k / 15 for k in range(61)]
    res = shadow(rb.recording(people_times=times).write_bag(tmp_path / "b"), (10.0, 0.0))
    assert res.config["stream"]["dt"] == pytest.approx(0.4 / 6)
    assert res.counts["n_missing"] == res.counts["n_held"] == res.counts["n_merged"] == 0


def test_bad_settings_are_one_line(tmp_path: Path, rb) -> None:
    simple_bag = rb.recording(seconds=1.0).write_bag(tmp_path / "b")
    with pytest.raises(InputError, match="goal must be two finite numbers"):
        shadow(simple_bag, (1.0, math.nan))
    with pytest.raises(InputError, match="tau must be"):
        shadow(simple_bag, (1.0, 0.0), params={"tau": -1})
    with pytest.raises(ValueError, match="epsilon"):
        shadow(simple_bag, (1.0, 0.0), params={"epsilon": 0.7})


def test_no_overlap_in_time(tmp_path: Path, rb) -> None:
    rec = rb.recording(seconds=1.0)
    rec.messages = [m for m in rec.messages if m[1] != "/odom"]
    ns = rb.T0 + 5_000_000_000
    rec.add("/odom", rb.ODOMETRY, ns, rb.odom_msg(ns, 0, 0, 0, (0, 0)))
    with pytest.raises(DataFormatError, match="before the first odometry"):
        shadow(rec.write_bag(tmp_path / "b"), (1.0, 0.0))


def test_an_mpc_family_runs_in_shadow(tmp_path: Path, rb) -> None:
    bag = rb.recording().write_bag(tmp_path / "b")
    res = shadow(bag, (10.0, 0.0), family="mpc", params={"v_max": 1.5})
    speed = np.hypot(res.commands["vx"], res.commands["vy"])
    assert speed.max() <= 1.5 + 1e-9 and speed.max() > 0.5
    assert res.result.n_updates >= 8
    assert res.config["family"] == "mpc"


@pytest.mark.parametrize("family", ["fcp_mpc", "soft_mpc"])
def test_every_registered_planning_family_runs_in_shadow(
    tmp_path: Path, rb, family: str, capsys, error_line
) -> None:
    """The command took only cbf, mpc, acp_mpc and ecp_mpc (a list written by hand)."""
    from conformal_control.cli import main

    bag = rb.recording(seconds=2.0).write_bag(tmp_path / "b")
    out = tmp_path / "out"
    assert main(["shadow", str(bag), "--goal", "10,0", "--family", family, "--out", str(out)]) == 0
    assert json.loads((out / "config.json").read_text())["family"] == family
    capsys.readouterr()
    # a family that does not plan is refused in one line
    out = tmp_path / "acp"
    assert main(["shadow", str(bag), "--goal", "10,0", "--family", "acp", "--out", str(out)]) == 2
    assert "StepwiseMPC runs a planning family" in error_line()


def test_outputs_read_back_equal_to_commands_csv(tmp_path: Path, simple_bag: Path, capsys) -> None:
    """The command line writes commands.csv, config.json, the bag and the plots; the bag's
    messages (read with rosbags, and decoded again with mcap-ros2-support) are the CSV's
    rows: one Twist and one lambda per row at its stamp, one loss per scored row."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    from conformal_control.cli import main

    out = tmp_path / "out"
    code = main(
        ["shadow", str(simple_bag), "--goal", "10,0", "--param", "epsilon=-0.05", "--out", str(out)]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert f"results written to {out}" in printed and "intervals scored" in printed
    assert {p.name for p in out.iterdir()} == {
        "commands.csv",
        "config.json",
        "shadow_bag",
        "plot.png",
        "guarantee.png",
    }
    c = _read_commands(out / "commands.csv")
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["params"] == {"epsilon": -0.05} and cfg["goal"] == [10.0, 0.0]
    assert cfg["counts"]["n_steps"] == c["t"].size
    scored = np.isfinite(c["loss"])
    got: dict[str, list[tuple[int, object]]] = {}
    with AnyReader([out / "shadow_bag"]) as reader:
        types = {x.topic: x.msgtype for x in reader.connections}
        assert types == {
            "/cmd_vel_safe": "geometry_msgs/msg/Twist",
            "/conformal/lambda": "std_msgs/msg/Float64",
            "/conformal/loss": "std_msgs/msg/Float64",
        }
        for con, ns, raw in reader.messages():
            got.setdefault(con.topic, []).append((ns, reader.deserialize(raw, con.msgtype)))
    cmd = got["/cmd_vel_safe"]
    assert [ns for ns, _ in cmd] == c["stamp_ns"].tolist()
    np.testing.assert_array_equal([m.linear.x for _, m in cmd], c["vx_body"])
    np.testing.assert_array_equal([m.linear.y for _, m in cmd], c["vy_body"])
    np.testing.assert_array_equal([m.data for _, m in got["/conformal/lambda"]], c["lambda"])
    loss = got["/conformal/loss"]
    assert [ns for ns, _ in loss] == c["stamp_ns"][scored].tolist()
    np.testing.assert_array_equal([m.data for _, m in loss], c["loss"][scored])
    # the bag's MCAP decodes with an independent ROS 2 decoder
    (mcap_file,) = (out / "shadow_bag").glob("*.mcap")
    with mcap_file.open("rb") as fh:
        decoded = [
            (ch.topic, m.log_time, d)
            for _, ch, m, d in make_reader(
                fh, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages()
        ]
    twists = [d for topic, _, d in decoded if topic == "/cmd_vel_safe"]
    np.testing.assert_array_equal([d.linear.x for d in twists], c["vx_body"])
    assert sum(topic == "/conformal/loss" for topic, _, _ in decoded) == scored.sum()
    # a second run into the same folder does not overwrite the bag
    code = main(["shadow", str(simple_bag), "--goal", "10,0", "--out", str(out)])
    assert code != 0 and "exists already" in capsys.readouterr().err
