"""fetch-data: manifest, mirror copy with checksums, corrupted sources, conversion."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest

from conformal_control.cli import main
from conformal_control.data import load_scene
from conformal_control.data.fetch import (
    ChecksumError,
    fetch,
    load_manifest,
    plan,
    trajnet_metres_to_pixels,
)


def test_manifest_matches_the_shared_data(data_root: Path) -> None:
    man = load_manifest()
    listed = {e["path"]: e["sha256"] for e in man["files"]}
    on_disk = {str(p.relative_to(data_root)) for p in data_root.rglob("*") if p.is_file()} - {
        "README.md"
    }
    assert set(listed) == on_disk
    for rel in (
        "sdd/annotations/nexus/video4/annotations.txt",
        "ethucy/zara1/test/crowds_zara01.txt",
    ):
        assert hashlib.sha256((data_root / rel).read_bytes()).hexdigest() == listed[rel]


def test_upstream_plan_points_at_the_source_repositories() -> None:
    items = {it.path: it for it in plan(["sdd:nexus_4", "ethucy:eth"])}
    ann = items["sdd/annotations/nexus/video4/annotations.txt"]
    assert ann.url.endswith("OpenTraj/master/datasets/SDD/nexus/video4/annotations.txt")
    tn = items["sdd/trajnet_pixels/nexus_4.txt"]
    assert tn.convert == "trajnet_pixels" and tn.url.endswith("data/sdd/train/nexus_4.txt")
    eth = items["ethucy/eth/test/biwi_eth.txt"]
    assert eth.url.endswith("experiments/pedestrians/raw/eth/test/biwi_eth.txt")
    assert not any(p.startswith("sdd/annotations/quad") for p in items)
    with pytest.raises(ValueError, match="matches no file"):
        plan(["sdd:atlantis_9"])


def test_fetch_from_a_mirror_then_run(tmp_path: Path, data_root: Path) -> None:
    dest = tmp_path / "data"
    counts = fetch(dest, only=["sdd:nexus_4"], mirror=str(data_root), progress=False)
    assert counts == {"downloaded": 5, "verified_existing": 0}
    again = fetch(dest, only=["sdd:nexus_4"], mirror=str(data_root), progress=False)
    assert again == {"downloaded": 0, "verified_existing": 5}
    scene = load_scene("nexus_4", dest)
    assert scene.n_agents == 47


def test_corrupted_source_is_rejected_and_not_kept(tmp_path: Path, data_root: Path) -> None:
    mirror = tmp_path / "mirror"
    shutil.copytree(
        data_root / "sdd" / "annotations" / "nexus" / "video4",
        mirror / "sdd" / "annotations" / "nexus" / "video4",
    )
    shutil.copy(data_root / "sdd" / "estimated_scales.yaml", mirror / "sdd")
    shutil.copy(data_root / "sdd" / "LICENSE", mirror / "sdd")
    (mirror / "sdd" / "trajnet_pixels").mkdir()
    (mirror / "sdd" / "trajnet_pixels" / "nexus_4.txt").write_text("0 1 2.0 3.0\n")
    dest = tmp_path / "dest"
    with pytest.raises(ChecksumError, match=r"sdd/trajnet_pixels/nexus_4\.txt: SHA-256"):
        fetch(dest, only=["sdd:nexus_4"], mirror=str(mirror), progress=False)
    assert not (dest / "sdd" / "trajnet_pixels" / "nexus_4.txt").exists()
    assert not list(dest.rglob("*.part"))


def test_trajnet_conversion_reproduces_the_pixel_file(data_root: Path) -> None:
    scale = 0.045883871
    pixel_lines = (data_root / "sdd/trajnet_pixels/nexus_4.txt").read_text().splitlines()[:50]
    metres = "\n".join(
        f"{f} {i} {float(x) * scale!r} {float(y) * scale!r}"
        for f, i, x, y in (ln.split() for ln in pixel_lines)
    )
    assert trajnet_metres_to_pixels(metres, scale).splitlines() == pixel_lines
    with pytest.raises(ValueError, match="line 1: expected 4 fields"):
        trajnet_metres_to_pixels("1 2 3\n", scale)


def test_cli_dry_run(capsys) -> None:
    assert main(["fetch-data", "--dest", "x", "--only", "ethucy:zara1", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "ethucy/zara1/test/crowds_zara01.txt" in out and "Trajectron" in out
