"""Shared check of the batch engine's tests: its episodes against run_episode's."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

#: Metrics that measure the machine, not the episode.
WALL = {"wall_s"}


def same(a: Any, b: Any) -> bool:
    """Equal, NaN equal to NaN, floats compared exactly (bit for bit)."""
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


def _differences(batch: Any, single: Any) -> list[str]:
    da, db = dataclasses.asdict(batch), dataclasses.asdict(single)
    assert da.keys() == db.keys()
    return [
        f"{k}: batch {da[k]!r} != run_episode {db[k]!r}"
        for k in da
        if k not in WALL and not same(da[k], db[k])
    ]


def _compare(scenes, *, max_frames=None, seeds=None, batch_size=3, output="metrics", **kw):
    """Run the scenes batched and one by one (the per-episode loop, `engine="loop"`: the
    default would take the engine too); assert every metric is identical (and, with
    ``output="results"``, every interval's row). Returns (batched, run_episode results)."""
    from conformal_control.runs.engines.batch import run_batch
    from conformal_control.runs.episode import run_episode

    frames = max_frames if isinstance(max_frames, list) else [max_frames] * len(scenes)
    seed_list = seeds if isinstance(seeds, list) else [seeds or 0] * len(scenes)
    batched = run_batch(
        scenes, max_frames=max_frames, seeds=seeds, batch_size=batch_size, output=output, **kw
    )
    assert len(batched) == len(scenes)
    singles = [
        run_episode(sc, max_frames=mf, seed=seed, record_animation=False, engine="loop", **kw)
        for sc, mf, seed in zip(scenes, frames, seed_list, strict=True)
    ]
    problems = {}
    for i, (b, s) in enumerate(zip(batched, singles, strict=True)):
        diff = _differences(b.metrics if output == "results" else b, s.metrics)
        if output == "results" and not same(b.intervals, s.intervals):
            diff.append("intervals differ")
        if diff:
            problems[i] = diff
    assert not problems, problems
    return batched, singles


@pytest.fixture
def compare_batch() -> Callable[..., tuple[list[Any], list[Any]]]:
    """``compare_batch(scenes, **run_batch_kwargs)``: run the scenes with
    :func:`run_batch` and with :func:`run_episode`, assert the metrics are identical."""
    return _compare


def _gappy_track(scene, p0, v, gaps=()):
    """p0 + v (t - t_start) at every frame of ``scene``, NaN on the frame ranges ``gaps``
    (clipped at the first frame)."""
    t = (np.arange(scene.n_frames) - scene.start_index)[:, None] / scene.fps
    out = np.asarray(p0, dtype=float) + t * np.asarray(v, dtype=float)
    for lo, hi in gaps:
        out[max(scene.start_index + lo, 0) : scene.start_index + hi] = np.nan
    return out


@pytest.fixture(scope="module")
def gappy():
    """Crossing scenes whose agents enter late, leave and come back, or blink (agents
    appear and disappear between sampling times: delayed and dropped agents then have no
    current sample, recorded forecasts none for them), and a plain second scene."""
    from conformal_control.data import load_scene

    base = load_scene("crossing", seed=0)
    tracks = [
        _gappy_track(base, (6.0, 2.0), (0.0, 1.2), gaps=[(-40, 12)]),  # appears after the start
        _gappy_track(base, (9.0, 14.0), (-0.2, -1.0), gaps=[(30, 44)]),  # leaves, comes back
        _gappy_track(base, (4.0, 9.0), (0.8, -0.1), gaps=[(20, 21), (23, 24), (60, 10_000)]),
        _gappy_track(base, (12.0, 3.0), (-0.9, 0.9), gaps=[(-40, 2), (5, 6)]),
    ]
    pos = np.stack(tracks, axis=1)
    ids = np.array([3, 17, 40, 1001])
    other = load_scene("crossing", seed=1)
    return [dataclasses.replace(base, positions=pos, agent_ids=ids), other]
