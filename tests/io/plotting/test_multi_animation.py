"""The multi-robot animation: every frame of the window, from the CLI run directory."""

from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np
import pytest

from conformal_control.cli import main
from conformal_control.io.plotting.animation import animation_frames, load_record, render_animation


def test_cli_robots_run_and_animate(tmp_path, capsys):
    run = tmp_path / "run"
    argv = [
        "run",
        "--robots",
        "3",
        "--robot-layout",
        "antipodal",
        "--radius",
        "5",
        "--center",
        "0.5,0.5",
        "--frames",
        "40",
        "--seed",
        "2",
        "--out",
        str(run),
    ]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "n_collide_robot_pairs" in out and out.count("\n    ") >= 3  # one line per robot
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["n_robots"] == 3 and cfg["layout"]["layout"] == "antipodal"
    np.testing.assert_allclose(
        [np.hypot(r["start_m"][0] - 15.0, r["start_m"][1] - 8.0) for r in cfg["robots"]], 5.0
    )
    rec = load_record(run)
    assert rec["kind"] == "multi"
    expected = len(animation_frames(rec, None, None, 5.0))
    gif = tmp_path / "multi.gif"
    argv = ["animate", str(run), "--fps", "5", "--dpi", "30", "--width", "6", "--no-progress"]
    assert main([*argv, "--out", str(gif)]) == 0
    frames = iio.imread(gif, index=None)
    assert frames.shape[0] == expected
    # 6 in at 30 dpi wide; the height follows the scene's aspect, within [0.4, 0.95] x width
    h, w = frames.shape[1:3]
    assert w == 180 and h % 2 == 0 and 0.4 * 180 <= h <= 0.95 * 180
    # the robots move: consecutive frames differ
    assert not np.array_equal(frames[0], frames[-1])


def test_robots_file_from_the_cli(tmp_path):
    f = tmp_path / "robots.json"
    f.write_text(
        json.dumps(
            {"robots": [{"start": [3, 8], "goal": [27, 8]}, {"start": [27, 8.5], "goal": [3, 8.5]}]}
        )
    )
    run = tmp_path / "run"
    assert main(["run", "--robots-file", str(f), "--frames", "20", "--out", str(run)]) == 0
    cfg = json.loads((run / "config.json").read_text())
    assert [r["start_m"] for r in cfg["robots"]] == [[3.0, 8.0], [27.0, 8.5]]
    assert cfg["layout"] == {"layout": "explicit"}


def test_one_rendering_path_checks_the_output_for_one_robot_and_for_several(tmp_path):
    for record in ({"kind": "multi"}, {"t": np.zeros(3)}):
        with pytest.raises(ValueError, match=r"\.gif or \.mp4"):
            render_animation(record, tmp_path / "x.png")
