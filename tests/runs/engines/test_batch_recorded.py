"""Recorded forecasts (the ``recorded`` predictor, the benchmark's ``learned`` shift) run
compiled in the batch engine, equal to the per-episode loop.

The engine replays the forecasts of the predictions file itself (the latest issue, anchored
at the current position, interpolated as ``numpy.interp`` does, the last segment held beyond
the last step; an agent without a forecast predicted by the constant-velocity fallback):
every metric (the predictor's counters in ``predictor_info`` included) and every interval's
row must be those of the loop, which calls the predictor itself.
"""

from __future__ import annotations

import numpy as np
import pytest

from conformal_control.data import load_scene
from conformal_control.families.cbf.controller import PredictorError
from conformal_control.predictors.recorded import RecordedPredictor
from conformal_control.runs.engines import recorded_kernels as rk
from conformal_control.runs.engines.batch import run_batch
from conformal_control.runs.episode import run_episode


def write_predictions(path, scenes, *, every=7, steps=12, per_step=4, seed=0):
    """A predictions file for ``scenes`` (scene frame = CSV frame, ``step_s`` = ``per_step``
    frames): forecasts issued every ``every`` frames from 40 frames before the start (none
    before: the first sampling times have no issue), each a noisy future of the recording,
    with every gap a file can have: agents left out of an issue (fallback), steps missing
    (absent rows, and every step of a future the recording does not have), forecasts whose
    last steps are missing (extrapolated), issues between sampling times (interpolated) and
    on them (the file's values exactly)."""
    rng = np.random.default_rng(seed)
    rows = ["frame,track_id,step,x,y"]
    written: set[tuple[int, int]] = set()  # (the scenes share ids: the first one's kept)
    for sc in scenes:
        pos = sc.positions
        for f in range(sc.start_index - 40 + sc.start_index % 3, sc.n_frames, every):
            for j, tid in enumerate(sc.agent_ids.tolist()):
                key = (sc.first_frame + f, tid)
                if not np.isfinite(pos[f, j]).all() or rng.random() < 0.2 or key in written:
                    continue  # not seen, or left out of the issue: the fallback's
                written.add(key)
                cut = steps if rng.random() < 0.6 else int(rng.integers(1, steps))
                for s in range(1, cut + 1):
                    g = f + s * per_step
                    if g >= sc.n_frames or not np.isfinite(pos[g, j]).all() or rng.random() < 0.1:
                        continue  # a missing step
                    x, y = (pos[g, j] + rng.normal(0.0, 0.15, 2)).tolist()
                    rows.append(f"{sc.first_frame + f},{tid},{s},{x!r},{y!r}")
    path.write_text("\n".join(rows) + "\n")
    return str(path)


@pytest.fixture(scope="module")
def predictions(gappy, tmp_path_factory):
    return write_predictions(tmp_path_factory.mktemp("rec") / "pred.csv", gappy)


def _params(path, fps=10.0, per_step=4, **kw):
    step_s = per_step / fps
    return {"path": path, "step_s": step_s, "frames_per_step": float(per_step), **kw}


def test_recorded_forecasts_match_the_loop(gappy, predictions, compare_batch, monkeypatch):
    kw = {"predictor": "recorded", "predictor_params": _params(predictions)}
    calls = []
    real = RecordedPredictor.predict
    monkeypatch.setattr(RecordedPredictor, "predict", lambda s, q: calls.append(1) or real(s, q))
    batched = run_batch(gappy, seeds=[3, 4], max_frames=200, output="results", **kw)
    assert calls == []  # the engine replays the forecasts itself
    monkeypatch.undo()
    _, singles = compare_batch(
        gappy, seeds=[3, 4], max_frames=200, output="results", batch_size=2, **kw
    )
    assert [b.metrics.n_updates for b in batched] == [s.metrics.n_updates for s in singles]
    # every path of the predictor ran: forecasts missing (fallback), missing steps,
    # extrapolation beyond the last step
    info = [s.metrics.predictor_info for s in singles]
    for key in ("n_missing", "n_missing_steps", "n_extrapolated"):
        assert sum(i[key] for i in info) > 0, (key, info)
    assert [i["n_nonfinite_current"] for i in info] == [0, 0]  # sensed agents are seen


@pytest.mark.parametrize(
    "extra",
    [
        {"fallback_predictor": "constant_velocity"},
        {"per_step": 3},  # issues and steps off the sampling grid: interpolated throughout
        {"per_step": 5, "every": 10},
    ],
)
def test_other_clocks_and_learning(gappy, tmp_path, compare_batch, extra):
    extra = dict(extra)
    per_step, every = extra.pop("per_step", 4), extra.pop("every", 7)
    path = write_predictions(tmp_path / "p.csv", gappy, every=every, per_step=per_step, seed=1)
    compare_batch(
        gappy,
        seeds=[1, 2],
        max_frames=150,
        predictor="recorded",
        predictor_params=_params(path, per_step=per_step, **extra),
        params={"epsilon": -0.1, "eta": 2.0},
        output="results",
        batch_size=2,
    )


def test_other_fallbacks_are_called_as_they_are(gappy, predictions, compare_batch):
    compare_batch(
        gappy[:1],
        seeds=[1],
        max_frames=90,
        predictor="recorded",
        predictor_params=_params(predictions, fallback_predictor="var"),
    )


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"fallback_predictor": "oracle"}, "cannot reveal the future"),  # no truth: refused
        ({"path": {"biwi_eth": "x.csv"}}, "no recorded predictions for scene"),
    ],
)
def test_what_the_predictor_refuses_fails_as_in_the_loop(gappy, predictions, params, message):
    kw = {
        "predictor": "recorded",
        "predictor_params": {**_params(predictions), **params},
        "max_frames": 60,
    }
    with pytest.raises(PredictorError, match=message) as loop:
        run_episode(gappy[0], engine="loop", record_animation=False, **kw)
    with pytest.raises(PredictorError, match=message) as batch:
        run_batch(gappy[:1], **kw)
    assert str(batch.value) == str(loop.value)


def test_the_interpolation_is_numpys_to_the_bit():
    rng = np.random.default_rng(0)
    for _ in range(400):
        n = int(rng.integers(2, 14))
        xp = np.sort(rng.uniform(0.0, 5.0, n)) * rng.choice([1e-3, 1.0, 1e3])
        xp = np.unique(xp)
        n = xp.size
        if n < 2:
            continue
        fp = rng.normal(size=n) * rng.choice([1.0, 1e5])
        xs = np.concatenate([rng.uniform(xp[0] - 1, xp[-1] + 1, 20), xp])
        got = [rk.interp(float(x), xp, fp, n) for x in xs]
        assert got == np.interp(xs, xp, fp).tolist()


def test_suite_scenarios_under_the_learned_shift(data_root, compare_batch, monkeypatch):
    """Scenarios of biwi_eth (on its corrected clock) and crowds_zara01 under the
    benchmark's ``learned`` shift (Trajectron++'s published forecasts), nolearn and
    conformal: compiled, and equal to the loop (six scenarios two at a time: slots are
    refilled and their forecasts' blocks moved to make room)."""
    from conformal_control.data.suites import load_suite
    from conformal_control.experiments.bench.methods import expand_methods
    from conformal_control.experiments.bench.shifts import SHIFTS

    test = load_suite("crossings-v2").scenarios_for("test")
    picked = [s for r in ("ethucy:biwi_eth:corrected", "ethucy:crowds_zara01")
              for s in [x for x in test if x.recording == r][:3]]  # fmt: skip
    scenes = [load_scene(f"scenario:crossings-v2/{s.id}", str(data_root)) for s in picked]
    frames = [sc.meta["max_frames"] for sc in scenes]
    calls = []
    real = RecordedPredictor.predict
    monkeypatch.setattr(RecordedPredictor, "predict", lambda s, q: calls.append(1) or real(s, q))
    shift = SHIFTS["learned"]
    for method in ("nolearn", "conformal"):
        kw = expand_methods([method], {"conformal": [-0.1]})[0].run_kwargs()
        predictor, pparams = shift.predictor_for(
            kw.pop("predictor", "constant_velocity"), kw.pop("predictor_params", None),
            str(data_root),
        )  # fmt: skip
        run_batch(scenes, max_frames=frames, predictor=predictor, predictor_params=pparams, **kw)
        assert calls == []  # compiled
        _, singles = compare_batch(
            scenes, max_frames=frames, batch_size=2, predictor=predictor,
            predictor_params=pparams, output="results", **kw,
        )  # fmt: skip
        info = [s.metrics.predictor_info for s in singles]
        assert sum(i["n_missing"] for i in info) > 0 and calls  # (the loop's calls)
        calls.clear()


@pytest.mark.parametrize("crowd", ["social_force", "orca"])
def test_reactive_crowds(gappy, predictions, compare_batch, crowd):
    """The forecasts anchored at the positions of pedestrians who react to the robot."""
    compare_batch(
        gappy,
        seeds=[1, 2],
        max_frames=80,
        crowd=crowd,
        predictor="recorded",
        predictor_params=_params(predictions),
        output="results",
        batch_size=2,
    )
