"""Reactive crowds in the batch engine: run_episode's metrics, field by field (wall time
aside), for the social force, ORCA and mixed crowds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conformal_control.data import load_scene
from conformal_control.runs.engines.batch import run_batch, supports
from conformal_control.runs.episode import run_episode

DEV_SCENARIOS = 3


@pytest.fixture(scope="module")
def suite_scenes(data_root):
    from conformal_control.data.suites import load_suite

    ids = [sc.id for sc in load_suite("crossings-v1").scenarios_for("dev")][:DEV_SCENARIOS]
    return [load_scene(f"scenario:crossings-v1/{i}", str(data_root)) for i in ids]


@pytest.fixture(scope="module")
def crossings():
    return [load_scene("crossing", seed=s) for s in range(3)]


CASES = [
    (crowd, None, method)
    for crowd in ("social_force", "orca")
    for method in ("nolearn", "conformal", "acp")
] + [
    ("mixed", {"model": "social_force", "radius": 4.0}, "nolearn"),
    ("mixed", {"model": "social_force"}, "conformal"),
    ("mixed", {"model": "orca"}, "conformal"),
]


@pytest.mark.parametrize(("crowd", "crowd_params", "method"), CASES)
def test_suite_scenarios_match_run_episode(
    suite_scenes, compare_batch, crowd, crowd_params, method
):
    from conformal_control.experiments.bench.methods import expand_methods

    kw = expand_methods([method], {"conformal": [-0.1]})[0].run_kwargs()
    frames = [sc.meta["max_frames"] for sc in suite_scenes]
    # batch_size 2 < 3 scenes: a freed slot is refilled by a crowd of another scene
    batched, singles = compare_batch(
        suite_scenes,
        max_frames=frames,
        batch_size=2,
        output="results",
        crowd=crowd,
        crowd_params=crowd_params,
        **kw,
    )
    for b, s in zip(batched, singles, strict=True):
        # the crowd walked as in the loop: its counters, the trajectory the robot drove
        assert b.config["crowd"] == s.config["crowd"]
        for k, v in s.trajectory.items():
            np.testing.assert_array_equal(b.trajectory[k], v)
    counts = [s.config["crowd"] for s in singles]
    if crowd == "mixed":  # some pedestrians switched to the model, others were replayed
        assert any(c["n_simulated"] > 0 for c in counts)
        assert any(c["n_replayed_throughout"] > 0 for c in counts)
    else:
        assert all(c["n_simulated"] > 0 for c in counts)
    # the crowd reacted: the replayed crowd gives other distances
    replay = [
        run_episode(sc, max_frames=f, record_animation=False, engine="loop", **kw).metrics
        for sc, f in zip(suite_scenes, frames, strict=True)
    ]
    assert any(r.d_min != s.metrics.d_min for r, s in zip(replay, singles, strict=True))


@pytest.mark.parametrize("crowd", ["social_force", "orca"])
def test_crossing_seeds_learning_match_run_episode(crossings, compare_batch, crowd):
    batched, singles = compare_batch(crossings, seeds=[0, 1, 2], crowd=crowd, batch_size=2)
    assert all(m.n_updates > 0 for m in batched)
    assert len({s.metrics.path_length for s in singles}) == len(singles)


def test_episodes_ending_within_a_frame_and_of_different_lengths(crossings, compare_batch):
    """Goals reached between two frames (the crowd finishes the frame with the robot
    standing), episodes cut after different numbers of frames, side by side."""
    _, singles = compare_batch(
        crossings, max_frames=[5, 400, 37], crowd="orca", batch_size=3, output="results"
    )
    ends = [s.steps["t"].size % s.config["family"]["params"]["substeps"] for s in singles]
    assert any(s.metrics.goal_reached for s in singles)
    assert any(e != 0 for e in ends)  # an episode ended within a frame


def _with_tracks(scene, tracks):
    pos = np.stack(tracks, axis=1)
    return dataclasses.replace(scene, positions=pos, agent_ids=np.arange(pos.shape[1]) + 1)


def _track(scene, p0, v, gaps=()):
    t = (np.arange(scene.n_frames) - scene.start_index)[:, None] / scene.fps
    out = np.asarray(p0, dtype=float) + t * np.asarray(v, dtype=float)
    for lo, hi in gaps:
        out[scene.start_index + lo : scene.start_index + hi] = np.nan
    return out


@pytest.mark.parametrize("crowd", ["social_force", "orca", "mixed"])
def test_pedestrians_entering_late_and_leaving(crossings, compare_batch, crowd):
    """A pedestrian recorded from a later frame enters then; one whose recording ends
    walks on and leaves; a recording with a gap."""
    base = crossings[0]
    tracks = [
        _track(base, (6.0, 2.0), (0.0, 1.2), gaps=[(-10_000, 25)]),  # enters late
        _track(base, (9.0, 14.0), (-0.2, -1.0), gaps=[(30, 60)]),  # a gap in its record
        _track(base, (4.0, 9.0), (0.8, -0.1), gaps=[(45, 10_000)]),  # its recording ends
    ]
    scenes = [_with_tracks(base, tracks), _with_tracks(base, tracks[::-1][:2])]
    _, singles = compare_batch(scenes, max_frames=200, crowd=crowd, batch_size=2, output="results")
    assert any(s.config["crowd"]["n_left"] + s.config["crowd"]["n_late"] > 0 for s in singles)


def test_losses_scored_on_the_record_and_the_truth(suite_scenes, compare_batch):
    """The collision loss reads the truth the environment reveals: the simulated crowd."""
    frames = [sc.meta["max_frames"] for sc in suite_scenes]
    compare_batch(suite_scenes, max_frames=frames, batch_size=2, crowd="orca", loss="collision")


def test_the_oracle_cannot_see_a_reactive_crowd(suite_scenes):
    with pytest.raises(Exception, match="oracle predictor needs crowd='replay'") as loop_err:
        run_episode(
            suite_scenes[0], crowd="social_force", predictor="oracle", record_animation=False,
            engine="loop",
        )  # fmt: skip
    with pytest.raises(type(loop_err.value), match="oracle predictor needs crowd='replay'"):
        run_batch(suite_scenes[:1], crowd="social_force", predictor="oracle")


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"crowd": "social_force", "crowd_params": {"noise": 0.2}}, "deterministic crowds"),
        ({"crowd": "orca", "crowd_params": {"neighbor_dist": float("inf")}}, "in cells"),
        ({"crowd": "orca", "record_animation": True}, "animation record"),
    ],
)
def test_supports_reactive_crowds_and_names_what_it_does_not(kwargs, words):
    for crowd in ("social_force", "orca", "mixed"):
        assert supports(crowd=crowd) is None
    assert supports(crowd="mixed", crowd_params={"model": "orca", "radius": 3.0}) is None
    why = supports(**kwargs)
    assert why is not None and words in why


@pytest.mark.parametrize("crowd", ["social_force", "mixed"])
def test_run_episode_takes_the_engine_for_one_reactive_episode(suite_scenes, crowd):
    """run_episode's default engine runs a reactive episode compiled: the loop's result,
    per-instant steps and animation record (drawn with the pedestrians the robot met)."""
    from tests.runs.engines.conftest import WALL, same

    sc = suite_scenes[1]
    kw = {"crowd": crowd, "max_frames": 120}
    fast = run_episode(sc, **kw)
    ref = run_episode(sc, engine="loop", **kw)
    assert fast.config["engine"] == "batch" and ref.config["engine"] == "loop"
    da, db = dataclasses.asdict(fast.metrics), dataclasses.asdict(ref.metrics)
    assert [k for k in da if k not in WALL and not same(da[k], db[k])] == []
    assert fast.config["crowd"] == ref.config["crowd"]
    for k, v in ref.steps.items():
        np.testing.assert_array_equal(fast.steps[k], v)
    assert fast.animation is not None and ref.animation is not None
    assert fast.animation.keys() == ref.animation.keys()
    for k, v in ref.animation.items():
        assert (
            same(fast.animation[k], v)
            if not isinstance(v, np.ndarray)
            else np.array_equal(fast.animation[k], v, equal_nan=v.dtype.kind == "f")
        ), k
