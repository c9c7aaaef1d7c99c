"""The built-in crossing scene: the vectorised generator is bit-identical to the loop one."""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.data.scene import scene_from_tracks
from conformal_control.data.synthetic import SYNTHETIC_DEFAULTS, crossing_scene, crossing_tracks
from conformal_control.data.tracks import Tracks
from conformal_control.data.units import SI

_W, _H = 30.0, 16.0


# ----------------------------------------------------------------------------- reference
# The generator as it was before vectorisation (one Python step per agent per frame),
# kept verbatim as the reference the vectorised one must reproduce bit for bit.
def _reference_walk(
    rng: np.random.Generator, p0: np.ndarray, heading: float, n: int, dt: float
) -> np.ndarray:
    speed0 = max(0.6, rng.normal(1.3, 0.15))
    th = np.empty(n)
    sp = np.empty(n)
    th_dev, sp_dev = 0.0, 0.0
    theta_rate, sigma_th, sigma_sp = 0.5, 0.35, 0.25
    for i in range(n):
        th_dev += -theta_rate * th_dev * dt + sigma_th * np.sqrt(dt) * rng.normal()
        sp_dev += -theta_rate * sp_dev * dt + sigma_sp * np.sqrt(dt) * rng.normal()
        th[i] = heading + th_dev
        sp[i] = max(0.2, speed0 + sp_dev)
    vel = np.column_stack([sp * np.cos(th), sp * np.sin(th)])
    return p0 + np.vstack([np.zeros(2), np.cumsum(vel[:-1] * dt, axis=0)])


def _reference_tracks(
    seed: int = 0,
    duration: float = 60.0,
    fps: float = 10.0,
    rate: float = 0.3,
    history: float = 12.0,
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    dt = 1.0 / fps
    n_total = round((duration + history) * fps)
    flows = [
        (lambda: np.array([rng.uniform(8.0, 22.0), -0.5]), np.pi / 2),
        (lambda: np.array([rng.uniform(8.0, 22.0), _H + 0.5]), -np.pi / 2),
        (lambda: np.array([_W + 0.5, rng.uniform(5.0, 11.0)]), np.pi),
    ]
    tracks: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    tid = 0
    warm = 25.0
    for spawn, heading in flows:
        t = -warm + rng.exponential(1.0 / rate) if rate > 0 else np.inf
        while t < duration + history:
            f0 = int(np.floor(t * fps))
            n = int(40.0 * fps)
            xy = _reference_walk(rng, spawn(), heading, n, dt)
            frames = np.arange(f0, f0 + n)
            inside = (xy[:, 0] > -1) & (xy[:, 0] < _W + 1) & (xy[:, 1] > -1) & (xy[:, 1] < _H + 1)
            keep = inside & (frames >= 0) & (frames < n_total)
            if keep.any():
                idx = np.flatnonzero(keep)
                run_end = idx[0] + np.argmin(np.append(keep[idx[0] :], False))
                sel = slice(idx[0], run_end)
                tracks[tid] = (frames[sel], xy[sel])
                tid += 1
            t += rng.exponential(1.0 / rate)
    return tracks


# ----------------------------------------------------------------------------- tests
CASES = [{"seed": s} for s in (0, 1, 2, 7, 42)] + [
    {"seed": 5, "fps": 30.0},
    {"seed": 6, "rate": 1.0, "duration": 20.0},
    {"seed": 8, "fps": 2.5, "history": 0.0},
    {"seed": 9, "rate": 0.05, "duration": 200.0, "fps": 7.0},
]


@pytest.mark.parametrize("kw", CASES, ids=lambda kw: ",".join(f"{k}={v}" for k, v in kw.items()))
def test_tracks_bit_identical_to_the_loop_generator(kw):
    ref = _reference_tracks(**kw)
    new = crossing_tracks(**kw).tracks
    assert list(new) == list(ref) and len(ref) > 0
    for tid, (frames, xy) in ref.items():
        f2, xy2 = new[tid]
        assert f2.dtype == frames.dtype and xy2.dtype == xy.dtype
        np.testing.assert_array_equal(f2, frames)
        # bit for bit: equal bytes, not merely close values
        assert xy2.tobytes() == xy.tobytes(), f"track {tid} differs (seed {kw['seed']})"


def test_scene_identical_to_one_built_from_the_reference_tracks():
    ref = Tracks(fps=10.0, tracks=_reference_tracks(seed=3), source="ref")
    old = scene_from_tracks(
        ref,
        name="crossing",
        start=np.array([2.0, _H / 2]),
        goals=np.array([[_W - 2.0, _H / 2]]),
        start_frame=120,
        v_max=2.0,
        history_frames=120,
        last_frame=719,
        units=SI,
        defaults=dict(SYNTHETIC_DEFAULTS),
    )
    new = crossing_scene(seed=3)
    assert new.positions.tobytes() == old.positions.tobytes()
    np.testing.assert_array_equal(new.agent_ids, old.agent_ids)
    assert (new.start_index, new.first_frame) == (old.start_index, old.first_frame)


def test_no_arrivals_and_bad_arguments():
    assert crossing_tracks(seed=0, rate=0.0).tracks == {}
    with pytest.raises(ValueError, match="duration and fps"):
        crossing_scene(fps=0.0)
    with pytest.raises(ValueError, match="duration and fps"):
        crossing_tracks(rate=-1.0)
