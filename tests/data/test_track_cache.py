"""Parsed recordings cached on disk (.npz): the same tracks, never a stale entry."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conformal_control.data import scenes, sdd, track_cache
from conformal_control.data.tracks import Tracks

ROWS = [
    # track_id xmin ymin xmax ymax frame lost occluded generated label
    '0 10 10 20 20 {f} 0 0 0 "Pedestrian"',
    '1 50 60 70 80 {f} 0 0 1 "Pedestrian"',
    '2 5 5 9 9 {f} 0 0 0 "Biker"',
]


def _annotations(path: Path, frames: int = 12, shift: float = 0.0) -> Path:
    lines = [r.format(f=f) for f in range(frames) for r in ROWS]
    if shift:
        lines[0] = f'0 {10 + shift} 10 20 20 0 0 0 0 "Pedestrian"'
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(autouse=True)
def _private_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CONFORMAL_CONTROL_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("CONFORMAL_CONTROL_TRACK_CACHE", raising=False)
    scenes._read_tracks_cached.cache_clear()  # the in-memory layer above it


def _same(a: Tracks, b: Tracks) -> None:
    assert (a.fps, a.source, a.meta) == (b.fps, b.source, b.meta)
    assert a.ids == b.ids
    for i in a.ids:
        np.testing.assert_array_equal(a.tracks[i][0], b.tracks[i][0])
        np.testing.assert_array_equal(a.tracks[i][1], b.tracks[i][1])
        assert a.tracks[i][0].dtype == b.tracks[i][0].dtype


def _count_parses(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    calls: list[int] = []
    real = sdd.read_annotations

    def counting(*a, **k):  # type: ignore[no-untyped-def]
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(scenes, "read_annotations", counting)
    return calls


def test_a_second_process_reads_the_cache_not_the_file(tmp_path, monkeypatch) -> None:
    path = _annotations(tmp_path / "annotations.txt")
    calls = _count_parses(monkeypatch)
    first = scenes.read_tracks("raw", path, 0.05)
    scenes._read_tracks_cached.cache_clear()  # as a new process
    second = scenes.read_tracks("raw", path, 0.05)
    assert len(calls) == 1
    _same(first, second)
    _same(second, sdd.read_annotations(path, 0.05))
    assert len(list((tmp_path / "cache" / "tracks").glob("*.npz"))) == 1


def test_new_content_or_arguments_parse_again(tmp_path, monkeypatch) -> None:
    path = _annotations(tmp_path / "annotations.txt")
    calls = _count_parses(monkeypatch)
    scenes.read_tracks("raw", path, 0.05)
    scenes._read_tracks_cached.cache_clear()
    scenes.read_tracks("raw", path, 0.04)  # another scale
    _annotations(path, shift=3.0)  # same size and name, other content
    scenes._read_tracks_cached.cache_clear()
    got = scenes.read_tracks("raw", path, 0.05)
    assert len(calls) == 3
    _same(got, sdd.read_annotations(path, 0.05))


def test_an_unreadable_entry_is_parsed_again_and_replaced(tmp_path, monkeypatch) -> None:
    path = _annotations(tmp_path / "annotations.txt")
    scenes.read_tracks("raw", path, 0.05)
    [entry] = (tmp_path / "cache" / "tracks").glob("*.npz")
    entry.write_bytes(b"not a zip file")
    scenes._read_tracks_cached.cache_clear()
    calls = _count_parses(monkeypatch)
    _same(scenes.read_tracks("raw", path, 0.05), sdd.read_annotations(path, 0.05))
    assert len(calls) == 1
    scenes._read_tracks_cached.cache_clear()
    scenes.read_tracks("raw", path, 0.05)
    assert len(calls) == 1  # replaced by a good entry


def test_errors_are_the_parsers_and_nothing_is_cached(tmp_path) -> None:
    path = tmp_path / "annotations.txt"
    path.write_text("0 1 2 3\n")
    with pytest.raises(ValueError, match="expected 10 space-separated fields"):
        scenes.read_tracks("raw", path, 0.05)
    assert not list((tmp_path / "cache").rglob("*.npz"))
    with pytest.raises(FileNotFoundError):
        scenes.read_tracks("raw", tmp_path / "missing.txt", 0.05)


def test_the_cache_can_be_switched_off(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("CONFORMAL_CONTROL_TRACK_CACHE", "0")
    path = _annotations(tmp_path / "annotations.txt")
    calls = _count_parses(monkeypatch)
    scenes.read_tracks("raw", path, 0.05)
    scenes._read_tracks_cached.cache_clear()
    scenes.read_tracks("raw", path, 0.05)
    assert len(calls) == 2
    assert not (tmp_path / "cache" / "tracks").exists()


def test_meta_that_json_would_change_is_not_cached(tmp_path) -> None:
    tracks = Tracks(fps=30.0, tracks={1: (np.arange(3), np.zeros((3, 2)))}, meta={"k": (1, 2)})
    path = tmp_path / "f.txt"
    path.write_text("x")
    got = track_cache.cached_tracks("test", path, {}, lambda: tracks)
    assert got is tracks
    assert not list((tmp_path / "cache").rglob("*.npz"))
