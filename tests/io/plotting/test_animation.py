"""``conformal-control animate``: readable GIF/MP4 with the expected frame count."""

from __future__ import annotations

import math

import imageio.v3 as iio
import numpy as np
import pytest

from conformal_control.cli import main
from conformal_control.io.plotting.animation import animation_frames, load_record


def test_animate_crossing_gif_and_mp4(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["run", "--frames", "30", "--no-plot", "--out", str(run)]) == 0
    rec = load_record(run)
    assert rec["peds"].shape[0] == rec["robot"].shape[0] == len(rec["t"])
    assert rec["pred"].shape[0] == len(rec["lam"]) == len(rec["k_start"])
    # crossing is at 10 fps: --fps 5 renders every 2nd frame of the window [0.5, 2] s
    expected = len(animation_frames(rec, 0.5, 2.0, 5.0))
    t = rec["t"]
    assert expected == len(np.flatnonzero((t >= 0.5 - 1e-9) & (t <= 2.0 + 1e-9))[::2])
    gif = tmp_path / "a.gif"
    argv = ["animate", str(run), "--start", "0.5", "--end", "2", "--fps", "5", "--dpi", "40"]
    assert main([*argv, "--out", str(gif), "--no-progress"]) == 0
    frames = iio.imread(gif, index=None)
    assert frames.shape[0] == expected and frames.shape[-1] in (3, 4)
    # streamed frame by frame: real-time playback (1/5 s per frame), looping, distinct frames
    meta = iio.immeta(gif, index=0)
    assert meta["duration"] == 200 and "loop" in meta
    assert len({f.tobytes() for f in frames}) == expected  # the time cursor moves every frame
    assert frames.std() > 10  # an image, not a blank canvas
    assert f"{expected} frames written" in capsys.readouterr().out
    mp4 = tmp_path / "a.mp4"
    assert main([*argv, "--out", str(mp4), "--no-progress"]) == 0
    video = iio.imread(mp4, index=None, plugin="pyav") if _has_pyav() else _read_ffmpeg(mp4)
    assert len(video) == expected


def _has_pyav() -> bool:
    try:
        import av  # noqa: F401
    except ImportError:
        return False
    return True


def _read_ffmpeg(path):
    import imageio.v2 as imageio

    with imageio.get_reader(path, format="FFMPEG") as r:
        return [f for f in r]


def test_animate_nexus4_window(tmp_path, sdd_dir):
    run = tmp_path / "nexus"
    args = ["run", "--scene", "nexus_4", "--data-root", str(sdd_dir), "--frames", "90"]
    assert main([*args, "--no-plot", "--out", str(run)]) == 0
    rec = load_record(run)
    assert rec["image"].endswith("reference.jpg")
    assert (rec["pred_cols"] >= 0).any()  # sensed agents with predictions were recorded
    out = tmp_path / "n.gif"
    argv = ["animate", str(run), "--out", str(out), "--start", "1", "--end", "2", "--fps", "10"]
    assert main([*argv, "--dpi", "40", "--no-progress"]) == 0
    # 30 fps scene at 10 fps output: one frame in 3 of the 31 frames in [1, 2] s
    frames = iio.imread(out, index=None)
    assert frames.shape[0] == 11


def test_animate_bad_input(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["run", "--frames", "10", "--no-plot", "--out", str(run)]) == 0
    assert main(["animate", str(run), "--out", str(tmp_path / "x.avi")]) == 2
    assert "must end in .gif or .mp4" in capsys.readouterr().err
    assert main(["animate", str(run), "--start", "50", "--end", "60"]) == 2
    assert "no frame in the window" in capsys.readouterr().err
    (run / "animation.npz").unlink()
    assert main(["animate", str(run)]) == 2
    assert "no animation record" in capsys.readouterr().err
    with pytest.raises(ValueError, match="fps must be > 0"):
        animation_frames({"t": np.zeros(3), "fps": 10.0}, fps=0)


def test_animation_record_content(crossing):
    from conformal_control.runs.episode import run_episode

    # epsilon below the feasibility floor and the default lambda floor opened: the fallback
    # runs, and the record shows it
    params = {"epsilon": -0.3, "lambda_min": -math.inf}
    res = run_episode(crossing, "constant_velocity", params, max_frames=80)
    rec = res.animation
    assert res.metrics["n_fallback"] > 0
    assert set(np.unique(rec["status"])) <= {0, 1, 2} and (rec["status"] == 2).any()
    np.testing.assert_allclose(rec["robot"][:, 0], res.trajectory["x"], atol=1e-5)
    # predictions start at the sensed agent's position at the interval's first frame
    n_checked = 0
    for k, start in enumerate(rec["k_start"]):
        for n, col in enumerate(rec["pred_cols"][k]):
            if col >= 0:
                np.testing.assert_allclose(rec["pred"][k, n, 0], rec["peds"][start, col], atol=1e-5)
                n_checked += 1
    assert n_checked > 0
    # the true barrier is evaluated only for agents within the sensing radius
    assert np.isfinite(rec["h_true_min"]).any()
    off = run_episode(crossing, "constant_velocity", max_frames=20, record_animation=False)
    assert off.animation is None


def test_a_frame_too_narrow_to_read_is_warned() -> None:
    import warnings

    from conformal_control.core.exceptions import SuspiciousValueWarning
    from conformal_control.io.plotting.animation import LEGIBLE_WIDTH_PX, frame_size

    with pytest.warns(SuspiciousValueWarning, match=r"480 x 216 px .* use --dpi 90 or more"):
        assert frame_size(8, 60) == (480, 216)  # the size the multi-robot GIF had
    with warnings.catch_warnings():
        warnings.simplefilter("error", SuspiciousValueWarning)
        w, h = frame_size(9.6, 80)  # the defaults
    assert (w, h) == (768, 346) and w >= LEGIBLE_WIDTH_PX
    with pytest.raises(ValueError, match="must be > 0"):
        frame_size(0, 80)
