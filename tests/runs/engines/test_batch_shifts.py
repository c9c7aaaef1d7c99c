"""Predictor shifts run compiled in the batch engine, equal to the per-episode loop.

The shift wrappers (``delayed``, ``noisy``, ``scaled``, ``dropout``) of a compiled
predictor (constant velocity, the oracle) are applied inside the engine's compiled
prediction: every metric (the wrappers' counters in ``predictor_info`` included) and every
interval's row must be those of the per-episode loop, which calls the wrappers themselves.
"""

from __future__ import annotations

import pytest

from conformal_control.data import load_scene
from conformal_control.families.cbf.controller import PredictorError
from conformal_control.predictors.shift import (
    DelayedPredictor,
    DropoutPredictor,
    NoisyPredictor,
    ScaledPredictor,
)
from conformal_control.runs.engines.batch import run_batch
from conformal_control.runs.episode import run_episode

WRAPPERS = {
    "delayed": DelayedPredictor,
    "noisy": NoisyPredictor,
    "scaled": ScaledPredictor,
    "dropout": DropoutPredictor,
}
SHIFTS = [
    ("delayed", {"delay_s": 0.5}),
    ("delayed", {"delay_s": 1.0}),
    ("noisy", {"sigma_m": 0.25}),
    ("scaled", {"scale": 0.0}),
    ("scaled", {"scale": 0.5}),
    ("dropout", {"p": 0.3, "duration_s": 1.0}),
]


@pytest.mark.parametrize("base", ["constant_velocity", "oracle"])
@pytest.mark.parametrize(("shift", "params"), SHIFTS)
def test_shifted_predictors_match_the_loop(gappy, compare_batch, monkeypatch, base, shift, params):
    kw = {"predictor": shift, "predictor_params": {**params, "predictor": base}}
    # the batch engine must not call the wrapper: it runs the shift compiled
    calls = []
    real = WRAPPERS[shift].predict
    monkeypatch.setattr(
        WRAPPERS[shift], "predict", lambda self, q: calls.append(1) or real(self, q)
    )
    batched, _ = run_batch(gappy, seeds=[3, 4], max_frames=150, **kw), None
    assert calls == []
    monkeypatch.undo()
    _, singles = compare_batch(
        gappy, seeds=[3, 4], max_frames=150, output="results", batch_size=2, **kw
    )
    assert [b.n_updates for b in batched] == [s.metrics.n_updates for s in singles]


def test_the_fallbacks_of_the_shifts_are_exercised(gappy):
    """Stale, unseen and dropped agents occur in these scenes (the comparisons above
    cover the wrappers' fallbacks, not only their plain path)."""
    seen = {}
    # dropout p=0.5: with 0.3 no agent is unseen since the default lambda floor moved the robot
    for shift, params in (("delayed", {"delay_s": 1.0}), ("dropout", {"p": 0.5})):
        for m in run_batch(
            gappy,
            seeds=[3, 4],
            max_frames=150,
            predictor=shift,
            predictor_params={**params, "predictor": "constant_velocity"},
        ):
            for key, value in m.predictor_info.items():
                seen[(shift, key)] = seen.get((shift, key), 0) + value
    for key in ("n_stale", "n_unseen"):
        assert seen[("delayed", key)] > 0 and seen[("dropout", key)] > 0, seen
    assert seen[("dropout", "n_dropped")] > 0


@pytest.mark.parametrize(
    "params",
    [
        {"predictor": "var"},  # a wrapped predictor the engine does not compile
        {"predictor": "constant_velocity", "predictor_params": {"window": 1}},
        {"delay_s": 0.0},  # neutral: the wrapped forecast itself
    ],
)
def test_other_wrapped_predictors_and_neutral_shifts(gappy, compare_batch, params):
    compare_batch(
        gappy[:1],
        seeds=[1],
        max_frames=90,
        predictor="delayed",
        predictor_params={"delay_s": 0.4, **params},
    )


def test_a_delay_beyond_the_history_fails_as_in_the_loop(gappy):
    kw = {"predictor": "delayed", "predictor_params": {"delay_s": 5.0}, "max_frames": 60}
    with pytest.raises(PredictorError, match="delay_s=5 s is") as loop:
        run_episode(gappy[0], engine="loop", **kw)
    with pytest.raises(PredictorError, match="delay_s=5 s is") as batch:
        run_batch(gappy[:1], **kw)
    assert str(batch.value) == str(loop.value)


def test_suite_scenarios_under_the_benchmark_shifts(data_root, compare_batch):
    from conformal_control.data.suites import load_suite
    from conformal_control.experiments.bench.methods import expand_methods
    from conformal_control.experiments.bench.shifts import SHIFTS as BENCH_SHIFTS

    ids = [sc.id for sc in load_suite("crossings-v1").scenarios_for("dev")][:3]
    scenes = [load_scene(f"scenario:crossings-v1/{i}", str(data_root)) for i in ids]
    frames = [sc.meta["max_frames"] for sc in scenes]
    for name in ("delay-0.5s", "noise-0.25m", "frozen", "dropout-0.3-1s"):
        for method in ("nolearn", "conformal"):
            kw = expand_methods([method], {"conformal": [-0.1]})[0].run_kwargs()
            predictor, pparams = BENCH_SHIFTS[name].predictor_for(
                kw.pop("predictor", "constant_velocity"), kw.pop("predictor_params", None)
            )
            compare_batch(
                scenes, max_frames=frames, batch_size=2, predictor=predictor,
                predictor_params=pparams, **kw,
            )  # fmt: skip
