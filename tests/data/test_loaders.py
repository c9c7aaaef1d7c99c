"""Loaders on the real SDD files and on malformed ones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conformal_control.data import (
    DataNotFoundError,
    load_scales,
    load_scene,
    read_annotations,
    read_trajnet,
    sdd_video,
)


def test_nexus4_raw_annotations(sdd_dir: Path) -> None:
    vid = sdd_video("nexus", 4, sdd_dir)
    assert vid.m_per_px == pytest.approx(0.045883871)
    tracks = read_annotations(vid.annotations, vid.m_per_px)
    # independent count straight from the text file
    rows = [ln.split() for ln in vid.annotations.read_text().splitlines() if ln.strip()]
    peds = [r for r in rows if r[9] == '"Pedestrian"' and r[6] == "0"]
    assert len(tracks) == len({r[0] for r in peds}) == 47
    assert tracks.frame_range() == (min(int(r[5]) for r in peds), max(int(r[5]) for r in peds))
    assert tracks.frame_range() == (20, 1061)
    assert tracks.meta["n_rows"] == len(peds)
    # bbox centre in metres
    r = peds[0]
    frames, xy = tracks.tracks[int(r[0])]
    i = int(np.flatnonzero(frames == int(r[5]))[0])
    cx = 0.5 * (float(r[1]) + float(r[3])) * vid.m_per_px
    assert xy[i, 0] == pytest.approx(cx)


def test_nexus4_scene_geometry(nexus4) -> None:
    assert nexus4.start_frame == 50
    assert nexus4.extent == pytest.approx((1284 * 0.045883871, 1759 * 0.045883871))
    np.testing.assert_allclose(nexus4.start, [0.95 * 1284 * 0.045883871, 0.55 * 1759 * 0.045883871])
    assert nexus4.v_max == 6.0
    assert nexus4.units.length_name == "px" and nexus4.units.time == pytest.approx(1 / 30)


def test_trajnet_relinks_segments(sdd_dir: Path) -> None:
    vid = sdd_video("nexus", 4, sdd_dir)
    raw = read_trajnet(vid.trajnet, vid.m_per_px, relink_segments=False, interpolate=False)
    linked = read_trajnet(vid.trajnet, vid.m_per_px, interpolate=False)
    assert len(raw) == 63
    assert linked.meta["n_links"] > 20
    assert len(linked) == len(raw) - linked.meta["n_links"]
    n_samples = sum(len(f) for f, _ in raw.tracks.values())
    assert sum(len(f) for f, _ in linked.tracks.values()) == n_samples
    for frames, xy in linked.tracks.values():
        assert np.all(np.diff(frames) == 12)
        step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        assert step.max() < 2.0  # < 5 m/s: no jump at the link points
    dense = read_trajnet(vid.trajnet, vid.m_per_px)
    for frames, _ in dense.tracks.values():
        assert np.all(np.diff(frames) == 1)


def test_gates1_from_trajnet(sdd_dir: Path) -> None:
    scene = load_scene("gates_1", sdd_dir)
    assert scene.meta["form"] == "trajnet" and scene.fps == 30
    assert scene.n_agents > 50


def test_missing_file_names_path_and_download_command(tmp_path: Path) -> None:
    with pytest.raises(DataNotFoundError) as err:
        read_annotations(tmp_path / "nope" / "annotations.txt", 0.05)
    msg = str(err.value)
    assert str(tmp_path / "nope" / "annotations.txt") in msg
    assert "conformal-control fetch-data" in msg
    with pytest.raises(DataNotFoundError, match=r"estimated_scales\.yaml"):
        load_scene("nexus_4", tmp_path)


GOOD = '1 10 20 30 40 5 0 0 0 "Pedestrian"\n1 12 20 32 40 6 0 0 1 "Pedestrian"\n'


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        (GOOD + "1 12 20 32 40 7 0 0\n", r":3: expected 10"),  # truncated last line
        (GOOD + '1 12 20 x 40 7 0 0 1 "Pedestrian"\n', r":3: non-numeric"),
        (GOOD + '1 12 20 32 40 6 0 0 1 "Pedestrian"\n', r"two rows for frame 6"),
        ('1 10 20 30 40 5 0 0 0 "Biker"\n', r"no Pedestrian rows"),
        ('1 10 20 30 40 5 1 0 0 "Pedestrian"\n', r"no Pedestrian rows"),
        ("", r"no Pedestrian rows"),
    ],
)
def test_malformed_annotations(tmp_path: Path, text: str, pattern: str) -> None:
    p = tmp_path / "annotations.txt"
    p.write_text(text)
    with pytest.raises(ValueError, match=pattern):
        read_annotations(p, 0.05)


def test_lost_rows_are_dropped_and_counted(tmp_path: Path) -> None:
    p = tmp_path / "annotations.txt"
    p.write_text(GOOD + '1 12 20 32 40 7 1 0 1 "Pedestrian"\n2 0 0 2 2 5 0 0 0 "Car"\n')
    t = read_annotations(p, 0.5)
    assert len(t) == 1 and t.meta["n_lost_rows"] == 1 and t.meta["n_other_label_rows"] == 1
    frames, xy = t.tracks[1]
    np.testing.assert_array_equal(frames, [5, 6])
    np.testing.assert_allclose(xy[0], [10.0, 15.0])


def test_malformed_scales(tmp_path: Path) -> None:
    (tmp_path / "estimated_scales.yaml").write_text("nexus:\n  video4:\n    certainty: 1\n")
    with pytest.raises(ValueError, match="nexus/video4 needs a scale in metres per pixel > 0"):
        load_scales(tmp_path)


def test_unknown_scene_names() -> None:
    with pytest.raises(ValueError, match="unknown scene"):
        load_scene("atlantis_1")
    with pytest.raises(ValueError, match="sdd:<scene>/video<N>"):
        load_scene("sdd:nexus4")


def test_any_sdd_video_by_name(sdd_dir: Path) -> None:
    scene = load_scene(
        "sdd:quad/video2", sdd_dir, start=(0.05, 0.5), goals=[(0.95, 0.5)], start_frame=0
    )
    w, h = scene.extent
    np.testing.assert_allclose(scene.start, [0.05 * w, 0.5 * h])
    with pytest.raises(ValueError, match=r"fractions of the scene's width and height.*1\.5m"):
        load_scene("sdd:quad/video2", sdd_dir, start=(1.5, 0.5))
    # metres and pixels of the image, typed with their unit
    px = scene.meta["m_per_px"]
    other = load_scene("sdd:quad/video2", sdd_dir, start="3.5m,10m", goals=["100px,200px"])
    np.testing.assert_allclose(other.start, [3.5, 10.0])
    np.testing.assert_allclose(other.goals, [[100 * px, 200 * px]])


def test_builtin_scene_is_seeded() -> None:
    a, b, c = (load_scene("crossing", seed=s) for s in (0, 0, 1))
    np.testing.assert_array_equal(a.positions, b.positions)
    assert a.positions.shape != c.positions.shape or not np.array_equal(
        np.nan_to_num(a.positions), np.nan_to_num(c.positions)
    )
    assert a.n_agents > 40
