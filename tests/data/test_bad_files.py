"""Broken data files are refused with file:line; odd but valid rows are counted."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from conformal_control.core.exceptions import DataFetchError, DataFormatError, InputError
from conformal_control.data import load_scene, read_annotations, read_trajnet
from conformal_control.data.fetch import fetch
from conformal_control.data.paths import DataNotFoundError, missing
from conformal_control.data.sdd import sdd_video

GOOD = '1 10 20 30 40 5 0 0 0 "Pedestrian"\n1 12 20 32 40 6 0 0 1 "Pedestrian"\n'


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        (GOOD + '1 nan 20 32 40 7 0 0 1 "Pedestrian"\n', r":3: non-finite box coordinate"),
        (GOOD + '2 nan 20 32 40 7 0 0 1 "Biker"\n', r":3: non-finite box coordinate"),
        (GOOD + '1 12 inf 32 40 7 1 0 1 "Pedestrian"\n', r":3: non-finite"),
        (GOOD + '1 12 20 32 40 7 0 0 1 "Pe\n', r":3: the label \"Pe is not a quoted name"),
        (GOOD + "1 12 20 32 40 7 0 0 1 Pedestrian\n", r":3: the label Pedestrian is not"),
        (GOOD + '1.5 12 20 32 40 7 0 0 1 "Pedestrian"\n', r":3: track_id, frame and lost"),
    ],
    ids=["nan pedestrian", "nan other label", "inf lost row", "cut label", "unquoted", "float id"],
)
def test_bad_annotation_rows_are_refused(tmp_path: Path, text: str, pattern: str) -> None:
    p = tmp_path / "annotations.txt"
    p.write_text(text)
    with pytest.raises(DataFormatError, match=pattern):
        read_annotations(p, 0.05)


def test_every_row_is_counted(tmp_path: Path) -> None:
    p = tmp_path / "annotations.txt"
    p.write_text(GOOD + '1 12 20 32 40 7 1 0 1 "Pedestrian"\n2 0 0 2 2 5 0 0 0 "Biker"\n')
    t = read_annotations(p, 0.5)
    m = t.meta
    assert (m["n_rows"], m["n_lost_rows"], m["n_other_label_rows"]) == (2, 1, 1)


def test_trajnet_duplicate_row_names_file_track_and_frame(tmp_path: Path) -> None:
    p = tmp_path / "gates_1.txt"
    p.write_text("0 7 1.0 2.0\n12 7 1.5 2.0\n12 7 1.6 2.0\n24 7 2.0 2.0\n")
    with pytest.raises(DataFormatError) as err:
        read_trajnet(p, 0.05)
    msg = str(err.value)
    assert f"{p}:3: track 7 has a second row for frame 12 (first at line 2)" == msg


def test_trajnet_non_finite_row_gives_its_line(tmp_path: Path) -> None:
    p = tmp_path / "t.txt"
    p.write_text("0 7 1.0 2.0\n12 7 nan 2.0\n")
    with pytest.raises(DataFormatError, match=r"t\.txt:2: non-finite"):
        read_trajnet(p, 0.05)


def test_start_frame_before_the_data_is_refused(sdd_dir: Path) -> None:
    with pytest.raises(InputError, match=r"start frame -500 is before the data \(it covers"):
        load_scene("nexus_4", sdd_dir, start_frame=-500)
    with pytest.raises(InputError, match=r"frames 60\.\.1056; the start may precede"):
        load_scene("nexus_4:trajnet", sdd_dir, start_frame=60 - 121)
    assert load_scene("nexus_4", sdd_dir, start_frame=0).start_frame == 0  # 20 frames early
    assert load_scene("nexus_4:trajnet", sdd_dir).start_frame == 50  # the paper's, 10 early


def test_scene_and_video_names_suggest(sdd_dir: Path) -> None:
    with pytest.raises(InputError, match=r"did you mean 'nexus_4'\?"):
        load_scene("nexsu_4", sdd_dir)
    with pytest.raises(InputError, match=r"did you mean 'gates_1'\?"):
        load_scene("gate_1", sdd_dir)
    with pytest.raises(InputError, match=r"nexus has videos 0, 1, .*11"):
        sdd_video("nexus", 99, sdd_dir)
    with pytest.raises(InputError, match=r"did you mean 'nexus'\?"):
        sdd_video("nexsu", 4, sdd_dir)


def test_missing_says_what_stands_there_instead(tmp_path: Path) -> None:
    (tmp_path / "a.txt").mkdir()
    assert "is a folder, not a file" in str(missing(tmp_path / "a.txt", "ETH/UCY file"))
    (tmp_path / "empty").mkdir()
    msg = str(missing(tmp_path / "empty", "ETH/UCY zara1/test data"))
    assert "exists but holds none of its files" in msg
    assert "not found at" in str(missing(tmp_path / "none", "SDD annotations"))


def test_annotations_folder_is_not_reported_missing(tmp_path: Path) -> None:
    (tmp_path / "annotations.txt").mkdir()
    with pytest.raises(DataNotFoundError, match="is a folder, not a file"):
        read_annotations(tmp_path / "annotations.txt", 0.05)


def test_unreadable_reference_image(sdd_dir: Path, tmp_path: Path) -> None:
    root = tmp_path / "sdd"
    video = root / "annotations" / "nexus" / "video4"
    video.mkdir(parents=True)
    shutil.copyfile(sdd_dir / "estimated_scales.yaml", root / "estimated_scales.yaml")
    shutil.copyfile(sdd_dir / "annotations/nexus/video4/annotations.txt", video / "annotations.txt")
    (video / "reference.jpg").write_bytes(b"\x00" * 64)
    with pytest.raises(DataFormatError, match=r"reference\.jpg: the scene's reference image"):
        load_scene("nexus_4", root)


def test_fetch_unreachable_is_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(DataFetchError, match=r"127\.0\.0\.1:9 is unreachable") as err:
        fetch(tmp_path, only=["sdd:nexus_4"], mirror="http://127.0.0.1:9", progress=False)
    assert "--mirror" in str(err.value)
    assert not list(tmp_path.rglob("*.part"))  # nothing half-downloaded left behind


def test_nexus4_still_loads_with_every_row_accounted(sdd_dir: Path) -> None:
    path = sdd_dir / "annotations/nexus/video4/annotations.txt"
    t = read_annotations(path, 0.05)
    n_lines = sum(1 for line in path.read_text().splitlines() if line.strip())
    m = t.meta
    assert m["n_rows"] + m["n_lost_rows"] + m["n_other_label_rows"] == n_lines
    assert sum(len(f) for f, _ in t.tracks.values()) == m["n_rows"]
    assert all(np.isfinite(xy).all() for _, xy in t.tracks.values())
