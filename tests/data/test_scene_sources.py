"""Scenes on ETH/UCY recordings and on the TrajNet form of any SDD video."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conformal_control.data import load_scene
from conformal_control.data.ethucy import ethucy_recording, read_ethucy
from conformal_control.data.scenes import (
    CROWD_A_SI,
    CROWD_EPSILON,
    CROWD_K_REP_SI,
    ETHUCY_DEFAULTS,
    ETHUCY_PUBLISHED,
    read_tracks,
)
from conformal_control.runs.params import resolve_params


def test_ethucy_interpolated_to_30_fps_keeps_the_samples(ethucy_dir: Path) -> None:
    path = ethucy_dir / "univ" / "test" / "students001.txt"
    raw = np.loadtxt(path)  # independent read: frame ped_id x y, frames step 10
    tracks = read_ethucy(path, fps=30)
    assert tracks.fps == 30 and len(tracks) == len(np.unique(raw[:, 1]))
    pid = int(raw[0, 1])
    rows = raw[raw[:, 1] == pid]
    frames, xy = tracks.tracks[pid]
    assert np.all(np.diff(frames) == 1)
    # sample k (frame 10 k of the file) is frame 12 k at 30 fps, exactly on the data
    for fr, x, y in rows[:, [0, 2, 3]]:
        i = int(np.flatnonzero(frames == round(fr / 10) * 12)[0])
        np.testing.assert_allclose(xy[i], [x, y], atol=1e-9)
    assert frames[0] == rows[0, 0] / 10 * 12 and frames[-1] == rows[-1, 0] / 10 * 12


def test_ethucy_gaps_stay_gaps_and_bad_rates_are_refused(tmp_path: Path) -> None:
    p = tmp_path / "gap.txt"
    rows = [(f, 1, 0.1 * f, 1.0) for f in (0, 10, 20, 30, 60, 70, 80, 90)]
    p.write_text("".join(f"{f}\t{i}\t{x}\t{y}\n" for f, i, x, y in rows))
    t = read_ethucy(p, fps=30)
    frames, xy = t.tracks[1]
    assert t.meta["n_track_gaps"] == 1
    # samples 0..3 -> frames 0..36, samples 6..9 -> frames 72..108, nothing in between
    assert frames[0] == 0 and frames[-1] == 108
    assert not np.any((frames > 36) & (frames < 72))
    np.testing.assert_allclose(xy[frames == 72][0], [6.0, 1.0])
    with pytest.raises(ValueError, match=r"whole multiple of 2\.5"):
        read_ethucy(p, fps=24)


def test_ethucy_scene_in_metres_and_frames(data_root: Path) -> None:
    scene = load_scene(
        "ethucy:crowds_zara01",
        data_root,
        start_m=(2.0, 6.0),
        goals_m=[(12.0, 6.0)],
        start_frame=600,
        last_frame=900,
    )
    assert scene.fps == 30 and scene.start_frame == 600
    assert scene.first_frame + scene.n_frames - 1 == 900
    assert scene.units.length == 1.0 and scene.units.time == pytest.approx(1 / 30)
    np.testing.assert_allclose(scene.start, [2.0, 6.0])
    assert scene.defaults["rho0"] == pytest.approx(16.0)
    # the crowd barrier defaults (SI) in the scene's units; the paper's kept beside them
    assert scene.defaults["K_rep"] == pytest.approx(CROWD_K_REP_SI)
    si = resolve_params(scene, {}).si
    assert si["a"] == pytest.approx(CROWD_A_SI) and si["tau"] == pytest.approx(4 / 30)
    assert si["K_rep"] == pytest.approx(CROWD_K_REP_SI)
    assert ETHUCY_DEFAULTS["a"] == pytest.approx(CROWD_A_SI / 30)
    assert scene.meta["published_params"] == ETHUCY_PUBLISHED
    assert ETHUCY_PUBLISHED["a"] == 10.0 and ETHUCY_PUBLISHED["K_rep"] == pytest.approx(0.064)
    with pytest.raises(ValueError, match=r"unknown ETH/UCY recording 'ethucy:atlantis'"):
        load_scene("ethucy:atlantis", data_root, start_m=(0, 0), goals_m=[(1, 1)])
    with pytest.raises(ValueError, match="no image; give metres"):
        load_scene("ethucy:crowds_zara01", data_root, start="10px,10px")
    with pytest.raises(ValueError, match="unknown ETH/UCY recording"):
        ethucy_recording("atlantis", data_root)


@pytest.mark.parametrize(("name", "along"), [("ethucy:crowds_zara01", 0), ("ethucy:biwi_hotel", 1)])
def test_an_ethucy_recording_has_a_default_task_across_its_walkable_box(
    data_root: Path, name: str, along: int
) -> None:
    """No task given: the documented rule, from 5 % to 95 % of the walkable box's longer
    side on its middle line, one history window after the recording's first frame; the box
    holds the middle 95 % of the file's own positions along each axis (counted here from
    the file, without the loader)."""
    scene = load_scene(name, data_root)
    lo, hi = (np.array(c) for c in scene.meta["walkable_box"])
    size = hi - lo
    assert int(np.argmax(size)) == along
    frac_start, frac_goal = np.array([0.05, 0.5]), np.array([0.95, 0.5])
    if along == 1:
        frac_start, frac_goal = frac_start[::-1], frac_goal[::-1]
    np.testing.assert_allclose(scene.start, lo + frac_start * size)
    np.testing.assert_allclose(scene.goals, [lo + frac_goal * size])
    stem = name.partition(":")[2]
    raw = np.loadtxt(next((data_root / "ethucy").glob(f"*/test/{stem}.txt")))
    for axis in (0, 1):
        inside = np.mean((raw[:, 2 + axis] >= lo[axis]) & (raw[:, 2 + axis] <= hi[axis]))
        assert 0.93 <= inside <= 0.97, (axis, inside)
    first = int(raw[:, 0].min()) // 10 * 12  # rows every 10 video frames, 12 frames per row
    assert scene.start_frame == first + 120
    # fractions are of the same box, metres are metres
    other = load_scene(name, data_root, start=(0.25, 0.25), goals=["1.5m,2.5m", (1.0, 1.0)])
    np.testing.assert_allclose(other.start, lo + 0.25 * size)
    np.testing.assert_allclose(other.goals, [[1.5, 2.5], hi])


def test_trajnet_form_of_any_video_and_metre_positions(sdd_dir: Path) -> None:
    scene = load_scene(
        "sdd:hyang/video5:trajnet", sdd_dir, start_m=(5.0, 20.0), goals_m=[(15.0, 20.0)]
    )
    assert scene.meta["form"] == "trajnet" and scene.name == "hyang_5:trajnet"
    wh = np.array(scene.extent)
    np.testing.assert_allclose(scene.meta["start_fraction"], np.array([5.0, 20.0]) / wh)
    np.testing.assert_allclose(scene.goals, [[15.0, 20.0]])
    raw = load_scene("sdd:nexus/video4:raw", sdd_dir)
    assert raw.meta["form"] == "raw"
    with pytest.raises(ValueError, match="bad SDD scene name"):
        load_scene("sdd:nexus/video4:lidar", sdd_dir)


def test_read_tracks_reads_a_file_once_and_again_when_it_changes(tmp_path: Path) -> None:
    p = tmp_path / "a.txt"
    p.write_text("0\t1\t0.0\t0.0\n10\t1\t1.0\t0.0\n")
    first = read_tracks("ethucy", p)
    assert read_tracks("ethucy", p) is first
    p.write_text("0\t1\t0.0\t0.0\n10\t1\t2.0\t0.0\n20\t1\t3.0\t0.0\n")
    again = read_tracks("ethucy", p)
    assert again is not first and len(again.tracks[1][0]) == 3
    with pytest.raises(ValueError, match="kind must be"):
        read_tracks("lidar", p)


def test_sdd_video_defaults_are_the_crowd_barrier_in_si_and_paper_scenes_keep_the_paper(
    data_root: Path,
) -> None:
    scene = load_scene("sdd:little/video0", data_root)
    si = resolve_params(scene, {}).si
    assert si["a"] == pytest.approx(CROWD_A_SI) and si["K_rep"] == pytest.approx(CROWD_K_REP_SI)
    m_per_px = scene.meta["m_per_px"]
    assert scene.defaults["K_rep"] == pytest.approx(CROWD_K_REP_SI / m_per_px**2)
    # everything else is the paper's Table II, which the scene keeps for comparison
    published = scene.meta["published_params"]
    assert published["a"] == 10.0 and published["K_rep"] == 40.0
    assert scene.defaults["epsilon"] == CROWD_EPSILON and published["epsilon"] == -0.25
    tuned = ("a", "K_rep", "epsilon")
    assert {k: v for k, v in scene.defaults.items() if k not in tuned} == {
        k: v for k, v in published.items() if k not in tuned
    }
    nexus = load_scene("nexus_4", data_root)
    assert nexus.defaults["a"] == 10.0 and nexus.defaults["K_rep"] == 40.0
