"""The replay environment's faster reads give the numbers of the forms they replaced, bit for
bit: the compiled window against :meth:`SparseTracks.window`, the episode's index of present
agents against :meth:`SparseTracks.present`, and whole episodes (sensed histories, truths,
frame log, steps, goal) against the previous reads on the recording (real data) and on a
synthetic crossing."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformal_control.core.jit import compile_now
from conformal_control.data.scene import SparseTracks
from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
from conformal_control.world import replay
from conformal_control.world.replay import ReplayEnvironment, _sparse_window_numpy, sparse_window

compile_now()


@st.composite
def tracks(draw: st.DrawFn) -> SparseTracks:
    rng = np.random.default_rng(draw(st.integers(0, 10_000)))
    n_frames, m = draw(st.integers(1, 30)), draw(st.integers(0, 8))
    start = rng.integers(0, n_frames, m)
    length = np.array([rng.integers(0, n_frames - s + 1) for s in start], dtype=np.int64)
    xy = rng.uniform(-5, 5, (int(length.sum()), 2))
    xy[rng.random(xy.shape[0]) < 0.2] = np.nan  # unseen inside a span
    return SparseTracks(n_frames, start, length, xy)


@settings(max_examples=80, deadline=None, derandomize=True)
@given(tracks(), st.data())
def test_the_compiled_window_equals_the_tracks_window(src: SparseTracks, data) -> None:
    lo = data.draw(st.integers(-12, src.n_frames + 3))
    hi = data.draw(st.integers(lo - 2, src.n_frames + 12))
    m = src.start.size
    cols = np.array(data.draw(st.lists(st.integers(0, m - 1), max_size=6)) if m else [], np.int64)
    want = src.window(lo, hi, cols)
    for form in (sparse_window, sparse_window.py_func, _sparse_window_numpy):
        got = form(src.xy, src.start, src.length, src.offset, lo, hi, cols)
        assert got.shape == want.shape and got.dtype == want.dtype
        assert got.tobytes() == want.tobytes()


class PreviousReads(ReplayEnvironment):
    """The reads before: :meth:`SparseTracks.present` and ``window`` at every call."""

    def _index_present(self) -> None:
        self._pres = None

    def _window(self, lo: int, hi: int, idx: np.ndarray) -> np.ndarray:
        return self._positions.window(lo, hi, idx)


def _episode(env: ReplayEnvironment, seed: int) -> list[bytes]:
    """Drive ``env`` with random commands: every read and record as bytes."""
    rng = np.random.default_rng(seed)
    env.reset()
    out: list[bytes] = []
    while not env.done:
        q = env.sense()
        out += [q.ids.tobytes(), q.history.tobytes(), q.truth_provider(3).tobytes()]
        for _ in range(env.control_instants()):
            st_ = env.state()
            out += [st_.x.tobytes(), st_.goal.tobytes(), np.float64(st_.t).tobytes()]
            env.apply(rng.uniform(-1.5, 1.5, 2))
            if env.done:
                break
        out.append(env.reveal().samples.tobytes())
    log = env.log.arrays()
    out += [v.tobytes() for v in log.values()]
    out += [np.array(env.steps_x).tobytes(), np.array(env.steps_cmd).tobytes()]
    out += [repr((env.t_goal_, env.n_sensed_, env._goal)).encode()]
    return out


@pytest.mark.parametrize("which", ["nexus4", "crossing"])
def test_episodes_read_as_before(which: str, request: pytest.FixtureRequest) -> None:
    scene = request.getfixturevalue(which)
    assert type(scene.tracks) is SparseTracks
    kw = {"tau_frames": 4, "substeps": 2, "max_frames": 120, "sensing_radius": 8.0}
    for seed in (0, 1):
        new = ReplayEnvironment(scene, VelocityTrackingDoubleIntegrator(K_acc=10.0), **kw)
        old = PreviousReads(scene, VelocityTrackingDoubleIntegrator(K_acc=10.0), **kw)
        a, b = _episode(new, seed), _episode(old, seed)
        assert len(a) == len(b) and a == b
        for f in range(scene.start_index, new._last + 1):  # the index, frame by frame
            cols, xy = new._present(f)
            want_cols, want_xy = scene.tracks.present(f)
            assert cols.dtype == want_cols.dtype and cols.tobytes() == want_cols.tobytes()
            assert xy.tobytes() == want_xy.tobytes()


def test_a_goal_reached_ends_the_episode_as_before(crossing) -> None:
    """Commands straight to the goal: the goal check in floats stops at the same step."""
    kw = {"tau_frames": 4, "substeps": 2, "max_frames": 400}
    ends = []
    for cls in (ReplayEnvironment, PreviousReads):
        env = cls(crossing, VelocityTrackingDoubleIntegrator(K_acc=10.0), **kw)
        env.reset()
        while not env.done:
            env.sense()
            for _ in range(env.control_instants()):
                d = env.state().goal - env.state().x[:2]
                env.apply(1.5 * d / max(np.hypot(*d), 1e-9))
                if env.done:
                    break
            env.reveal()
        ends.append((env.t_goal_, env._step, env._fi, len(env.steps_t)))
    assert ends[0][0] is not None
    assert ends[0] == ends[1]


def _d_min_before(xy: np.ndarray, x: np.ndarray) -> float:
    """The frame log's distance as it was computed before (numpy, per frame)."""
    d = np.hypot(*(xy - x[:2]).T) if xy.shape[0] else np.zeros(0)
    return float(d.min()) if d.size else float("nan")


@settings(max_examples=80, deadline=None, derandomize=True)
@given(st.integers(0, 9), st.integers(0, 2**32 - 1), st.sampled_from(["none", "nan", "inf", "tie"]))
def test_the_frame_logs_distance_equals_the_numpy_form(k: int, seed: int, odd: str) -> None:
    """nearest_distance (compiled, its loop interpreted, its numpy form) gives the frame
    log's former numpy expression bit for bit: no agent (NaN), NaN and infinite positions,
    ties, a strided (k, 2) view."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-3, 3, 4)
    big = rng.uniform(-10, 10, (k, 4))
    xy = big[:, 1:3]  # a strided view, as some sources hand out
    if k and odd == "nan":
        xy[rng.integers(0, k), rng.integers(0, 2)] = np.nan
    elif k and odd == "inf":
        xy[rng.integers(0, k), rng.integers(0, 2)] = np.inf
    elif k > 1 and odd == "tie":
        xy[1] = 2 * x[:2] - xy[0]  # mirrored: the same distance
    want = _d_min_before(xy, x)
    for form in (
        replay.nearest_distance,
        replay.nearest_distance.py_func,
        replay._nearest_distance_numpy,
    ):
        got = form(xy, float(x[0]), float(x[1]))
        assert type(got) is float
        assert np.array_equal(np.float64(got), np.float64(want), equal_nan=True)
        assert np.float64(got).tobytes() == np.float64(want).tobytes() or np.isnan(want)
