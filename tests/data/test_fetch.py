"""fetch-data: manifest, mirror copy with checksums, corrupted sources, conversion."""

from __future__ import annotations

import dataclasses
import hashlib
import shutil
from pathlib import Path

import pytest

from conformal_control.cli import EXIT_ERROR, main
from conformal_control.data import load_scene
from conformal_control.data.fetch import (
    ChecksumError,
    DataFetchError,
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
    assert counts == {"downloaded": 5, "verified_existing": 0, "mirror_only": 0}
    again = fetch(dest, only=["sdd:nexus_4"], mirror=str(data_root), progress=False)
    assert again == {"downloaded": 0, "verified_existing": 5, "mirror_only": 0}
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
    # the folder the paths are relative to is named (the per-user folder when --dest is unset)
    assert out.splitlines()[0].endswith("into x (paths below are relative to it):")


def test_cli_dry_run_names_the_per_user_folder(capsys, monkeypatch, tmp_path: Path) -> None:
    from conformal_control.data import paths

    monkeypatch.setattr(paths, "user_data_dir", lambda: tmp_path / "cc-data")
    assert main(["fetch-data", "--only", "ethucy:zara1", "--dry-run"]) == 0
    assert f"into {tmp_path / 'cc-data'} " in capsys.readouterr().out


# ---------------------------------------------------------------------- external/ (mirror only)
def test_external_files_are_listed_and_mirror_only(tmp_path: Path, data_root: Path) -> None:
    items = {it.path: it for it in plan(["external"])}
    assert set(items) == {
        "external/README.md",
        "external/fcp-planar/protocol.json",
        "external/trajectron-ethucy/eth.csv.gz",
        "external/trajectron-ethucy/hotel.csv.gz",
        "external/trajectron-ethucy/zara1.csv.gz",
    }
    assert all(it.url is None for it in items.values())  # upstream pickles are never read
    assert {it.path for it in plan(["external:fcp-planar"])} == {
        "external/README.md",
        "external/fcp-planar/protocol.json",
    }
    with pytest.raises(DataFetchError, match="can only be copied from a mirror"):
        fetch(tmp_path / "d", only=["external:trajectron-ethucy"], progress=False)
    assert not (tmp_path / "d").exists() or not list((tmp_path / "d").rglob("*.gz"))
    dest = tmp_path / "d"
    counts = fetch(dest, only=["external:trajectron-ethucy"], mirror=str(data_root), progress=False)
    assert counts["downloaded"] == 4
    got = hashlib.sha256((dest / "external/trajectron-ethucy/eth.csv.gz").read_bytes()).hexdigest()
    assert got == items["external/trajectron-ethucy/eth.csv.gz"].sha256


def test_a_fetch_of_everything_without_a_mirror_skips_the_mirror_only_files(
    tmp_path: Path, data_root: Path, monkeypatch
) -> None:
    import conformal_control.data.fetch as fetch_mod

    real = fetch_mod.plan
    upstream = data_root / "ethucy/zara1/test/crowds_zara01.txt"

    def small_plan(only=None, mirror=None):  # one upstream file (served from disk) + external
        keep = [it for it in real(None, mirror) if it.path.startswith("external/")]
        zara = next(it for it in real(["ethucy:zara1"], mirror) if "test/crowds_zara01" in it.path)
        return [dataclasses.replace(zara, url=str(upstream)), *keep]

    monkeypatch.setattr(fetch_mod, "plan", small_plan)
    counts = fetch_mod.fetch(tmp_path / "d", progress=False)
    assert counts == {"downloaded": 1, "verified_existing": 0, "mirror_only": 5}
    assert main(["fetch-data", "--dest", str(tmp_path / "e"), "--quiet"]) == 0


def test_cli_only_external_without_a_mirror_is_one_line(tmp_path: Path, capsys) -> None:
    argv = ["fetch-data", "--dest", str(tmp_path / "d"), "--only", "external", "--quiet"]
    assert main(argv) == EXIT_ERROR
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--mirror DIR" in err[0] and "pickles" in err[0]


# ---------------------------------------------------------------------- downloads are capped
def test_an_oversized_mirror_file_is_not_copied(tmp_path: Path, data_root: Path) -> None:
    mirror = tmp_path / "mirror"
    src = data_root / "ethucy/zara1/test/crowds_zara01.txt"
    target = mirror / "ethucy/zara1/test/crowds_zara01.txt"
    target.parent.mkdir(parents=True)
    target.write_bytes(src.read_bytes() + b"0" * 5_000_000)
    dest = tmp_path / "dest"
    with pytest.raises(ChecksumError, match=r"more than the .* the manifest allows"):
        fetch(dest, only=["ethucy:zara1"], mirror=str(mirror), progress=False)
    assert not list(dest.rglob("crowds_zara01*"))


def test_an_endless_http_download_is_cut_off_at_the_manifest_size(tmp_path: Path) -> None:
    """A server that never stops (no Content-Length) used to fill the disk."""
    import http.server
    import threading

    sent = []

    class Endless(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            self.send_response(200)
            self.end_headers()
            chunk = b"x" * 65536
            try:
                for _ in range(2000):  # 131 MB at most, then the test server gives up
                    self.wfile.write(chunk)
                    sent.append(len(chunk))
            except (BrokenPipeError, ConnectionResetError):
                pass

        def log_message(self, *args: object) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Endless)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        mirror = f"http://127.0.0.1:{server.server_address[1]}"
        dest = tmp_path / "dest"
        with pytest.raises(ChecksumError, match=r"larger than the .* bytes the manifest allows"):
            fetch(dest, only=["ethucy:zara1"], mirror=mirror, progress=False)
    finally:
        server.shutdown()
        server.server_close()
    assert not list(dest.rglob("*.part"))
    assert sum(sent) < 50_000_000  # stopped long before the server's 131 MB


def test_a_full_disk_names_the_file(tmp_path: Path, data_root: Path, monkeypatch) -> None:
    import errno

    import conformal_control.data.fetch as fetch_mod
    from conformal_control.core.exceptions import OutputNotWritableError

    def full(*args: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(fetch_mod, "_copy_capped", full)
    with pytest.raises(OutputNotWritableError, match=r"crowds_zara01\.txt: no space left"):
        fetch(tmp_path / "d", only=["ethucy:zara1"], mirror=str(data_root), progress=False)
