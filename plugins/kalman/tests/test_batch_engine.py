"""The Kalman predictor by name in the core's batch engine: run_episode's metrics."""

from __future__ import annotations

import dataclasses
import json

from conformal_control.data import load_scene
from conformal_control.runs.engines.batch import run_batch, supports
from conformal_control.runs.episode import run_episode


def _metrics(m):
    """Every metric but the wall time, as exact text (floats by repr, NaN as NaN)."""
    return json.dumps({k: v for k, v in dataclasses.asdict(m).items() if k != "wall_s"})


def test_kalman_batched_equals_run_episode():
    assert supports(predictor="kalman") is None
    scenes = [load_scene("crossing", seed=s) for s in range(3)]
    kw = {"predictor": "kalman", "max_frames": 120}
    batched = run_batch(scenes, seeds=[0, 1, 2], batch_size=2, **kw)
    singles = [
        run_episode(sc, seed=s, record_animation=False, engine="loop", **kw).metrics
        for s, sc in enumerate(scenes)
    ]
    assert [_metrics(m) for m in batched] == [_metrics(m) for m in singles]
    assert all(m.n_updates > 0 for m in singles)
