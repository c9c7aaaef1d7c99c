"""Sparse scene storage: memory proportional to the observations, the same numbers."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from conformal_control.data.scene import Scene, SparseTracks, scene_from_tracks
from conformal_control.data.synthetic import crossing_scene
from conformal_control.data.tracks import Tracks


def _sparse(scene: Scene) -> bool:
    """Whether the scene holds its positions sparsely only (no dense array): read from its
    storage, as only a test may."""
    return vars(scene)["_dense"] is None


def _random_dense(rng: np.random.Generator, frames: int = 40, agents: int = 7) -> np.ndarray:
    pos = rng.normal(size=(frames, agents, 2))
    for j in range(agents):  # a span per agent, with gaps inside it
        a, b = sorted(rng.integers(0, frames, size=2))
        pos[:a, j] = np.nan
        pos[b + 1 :, j] = np.nan
        pos[rng.random(frames) < 0.2, j] = np.nan
    pos[:, 3] = np.nan  # an agent never seen
    pos[5, 1, 1] = np.nan  # x without y: present for the sensor, NaN distance
    pos[7, 2, 0] = np.inf
    return pos


@pytest.mark.parametrize("seed", range(5))
def test_dense_round_trip_is_exact(seed: int) -> None:
    pos = _random_dense(np.random.default_rng(seed))
    sp = SparseTracks.from_dense(pos)
    back = sp.dense()
    assert back.shape == pos.shape
    np.testing.assert_array_equal(back, pos)  # NaN where NaN, inf where inf
    assert sp.nbytes < pos.nbytes * 4  # index tables included; the point is the scaling below


@pytest.mark.parametrize("seed", range(5))
def test_present_and_window_read_the_dense_values(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pos = _random_dense(rng)
    sp = SparseTracks.from_dense(pos)
    for f in range(pos.shape[0]):
        cols, xy = sp.present(f)
        want = np.flatnonzero(np.isfinite(pos[f, :, 0]))
        np.testing.assert_array_equal(cols, want)
        np.testing.assert_array_equal(xy, pos[f, want])
    idx = np.array([0, 2, 3, 6])
    for lo, hi in ((-5, 3), (0, 40), (10, 55), (38, 45), (60, 70), (4, 4)):
        out = np.full((idx.size, max(hi - lo, 0), 2), np.nan)
        a, b = max(lo, 0), min(hi, pos.shape[0])
        if b > a:
            out[:, a - lo : b - lo] = pos[a:b, idx].transpose(1, 0, 2)
        np.testing.assert_array_equal(sp.window(lo, hi, idx), out)
    lo, hi = 12, 30
    ov = sp.overlapping(lo, hi)
    outside = np.setdiff1d(np.arange(pos.shape[1]), ov)
    assert np.isnan(pos[lo:hi, outside]).all()  # the others are not there
    np.testing.assert_array_equal(sp.dense(lo, hi, ov), pos[lo:hi, ov])


@pytest.mark.parametrize(("lo", "hi"), [(0, 40), (5, 20), (-3, 12), (30, 80), (17, 17)])
def test_clip_keeps_exactly_the_frames_asked_for(lo: int, hi: int) -> None:
    pos = _random_dense(np.random.default_rng(7))
    clipped = SparseTracks.from_dense(pos).clip(lo, hi)
    want = np.full_like(pos, np.nan)
    a, b = max(lo, 0), min(hi, pos.shape[0])
    want[a:b] = pos[a:b]
    assert clipped.n_frames == pos.shape[0] and clipped.n_agents == pos.shape[1]
    np.testing.assert_array_equal(clipped.dense(), want)
    for f in range(pos.shape[0]):
        cols, _ = clipped.present(f)
        assert cols.size == (np.isfinite(want[f, :, 0]).sum())


def test_from_tracks_equals_the_dense_window() -> None:
    rng = np.random.default_rng(3)
    tracks = {}
    for i in range(12):
        f0 = int(rng.integers(0, 80))
        frames = np.sort(rng.choice(np.arange(f0, f0 + 40), size=15, replace=False))
        tracks[100 + 7 * i] = (frames, rng.normal(size=(frames.size, 2)))
    tracks[999] = (np.array([10, 90]), np.zeros((2, 2)))  # spans the window, no sample in it
    tr = Tracks(fps=10.0, tracks=tracks)
    for first, last in ((20, 60), (0, 130), (-10, 15)):
        ids_d, dense = tr.dense(first, last)
        ids_s, sp = SparseTracks.from_tracks(tr, first, last)
        np.testing.assert_array_equal(ids_s, ids_d)
        np.testing.assert_array_equal(sp.dense(), dense)


def test_scene_from_tracks_is_sparse_and_reads_as_before() -> None:
    scene = crossing_scene(seed=1)
    assert _sparse(scene)
    dense = scene.positions  # assembled on request
    assert dense.shape == (scene.n_frames, scene.n_agents, 2)
    np.testing.assert_array_equal(SparseTracks.from_dense(dense).dense(), dense)
    # replace keeps the storage; dataclasses.replace reads the dense array (still works)
    moved = scene.replace(goals=np.array([[1.0, 2.0]]))
    assert _sparse(moved) and moved.tracks is scene.tracks
    copy = dataclasses.replace(scene, goals=np.array([[1.0, 2.0]]))
    assert not _sparse(copy)
    np.testing.assert_array_equal(copy.positions, dense)
    back = pickle.loads(pickle.dumps(scene))
    assert _sparse(back)
    np.testing.assert_array_equal(back.positions, dense)


def test_a_dense_scene_keeps_its_array_and_caches_its_tracks() -> None:
    pos = _random_dense(np.random.default_rng(0))
    pos[7, 2, 0] = 1.0
    scene = Scene(
        name="s", fps=10.0, first_frame=0, start_index=2, positions=pos,
        agent_ids=np.arange(pos.shape[1]), start=np.zeros(2), goals=np.ones((1, 2)), v_max=1.0,
    )  # fmt: skip
    assert scene.positions is pos and not _sparse(scene)
    assert scene.tracks is scene.tracks  # built once
    assert scene.nbytes() == pos.nbytes
    other = pos * 2.0
    scene.positions = other  # a new array: new tracks
    np.testing.assert_array_equal(scene.tracks.dense(), other)


def test_inf_in_sparse_storage_is_refused() -> None:
    scene = crossing_scene(seed=0)
    xy = scene.tracks.xy.copy()
    xy[3] = np.inf
    t = scene.tracks
    bad = scene.replace(positions=SparseTracks(t.n_frames, t.start, t.length, xy))
    with pytest.raises(ValueError, match="positions contain inf"):
        bad.validate()


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((10, [0], [5, 1], np.zeros((6, 2))), "one value per agent"),
        ((10, [8], [5], np.zeros((5, 2))), "outside the scene"),
        ((10, [0], [5], np.zeros((4, 2))), "xy has 4 rows"),
        ((10, [0], [-1], np.zeros((0, 2))), ">= 0"),
    ],
)
def test_malformed_sparse_tracks_are_refused(args: tuple, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SparseTracks(*args)


def test_memory_follows_the_observations_not_frames_times_agents() -> None:
    """A 100,000-frame scene of 9,000 passers-by (300 frames each): the dense array would be
    13.4 GB; the sparse scene holds its 2.7 million samples and indexes."""
    rng = np.random.default_rng(0)
    n, life, frames = 9000, 300, 100_000
    f0 = rng.integers(0, frames - life, size=n)
    tracks = {i: (np.arange(f0[i], f0[i] + life), rng.normal(size=(life, 2))) for i in range(n)}
    tr = Tracks(fps=30.0, tracks=tracks)
    scene = scene_from_tracks(
        tr, name="long", start=np.zeros(2), goals=np.ones((1, 2)), start_frame=200,
        v_max=1.0, history_frames=120,
    )  # fmt: skip
    dense_bytes = scene.n_frames * scene.n_agents * 2 * 8
    assert dense_bytes > 13e9
    assert scene.nbytes() < 100e6  # 16 + 8 bytes per sample, 8 per frame
    assert scene.nbytes() < dense_bytes / 100


@pytest.mark.parametrize("engine", ["batch", "loop"])
def test_an_episode_never_assembles_the_dense_array(monkeypatch, engine: str) -> None:
    """The replay world, the compiled engine, the measuring and the animation record read
    the sparse tracks (windows of the episode's frames), never the whole dense array."""
    from conformal_control.runs.episode import run_episode

    scene = crossing_scene(seed=4)
    assert _sparse(scene)
    want = run_episode(scene.replace(positions=scene.positions), "constant_velocity", engine=engine)
    full = SparseTracks.dense

    def no_full_array(self, lo=0, hi=None, cols=None):  # type: ignore[no-untyped-def]
        if lo == 0 and hi is None and cols is None:
            raise AssertionError("the dense array of the whole scene was assembled")
        return full(self, lo, hi, cols)

    monkeypatch.setattr(SparseTracks, "dense", no_full_array)
    with pytest.raises(AssertionError, match="whole scene"):
        scene.positions  # noqa: B018 - the guard works
    got = run_episode(scene, "constant_velocity", engine=engine)
    for key, value in want.metrics.as_dict().items():
        if key != "wall_s":
            assert repr(getattr(got.metrics, key)) == repr(value), key
    assert got.animation is not None and want.animation is not None
    for key in ("peds", "ped_ids", "h_true_min", "status", "pred", "pred_cols"):
        np.testing.assert_array_equal(got.animation[key], want.animation[key])
