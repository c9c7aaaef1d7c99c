"""run_episode on the compiled engine gives the per-episode loop's result, to the last bit."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from conformal_control.data import load_scene
from conformal_control.runs.episode import run_episode
from conformal_control.runs.results.episode import EpisodeResult

#: Table II settings with a = 10 (scene units), the benchmark's nexus_4 configuration.
PAPER_A10 = {"epsilon": -0.25, "eta": 1, "tau": 4, "a": 10, "K_rep": 40}


def _same(a, b) -> bool:
    """Equal, NaN equal to NaN, floats and arrays compared exactly (bit for bit)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        if a.dtype != b.dtype or a.shape != b.shape:
            return False
        if a.dtype.kind == "f":
            return bool(np.array_equal(a, b, equal_nan=True))
        return bool(np.array_equal(a, b))
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


def _differences(fast: EpisodeResult, loop: EpisodeResult) -> list[str]:
    out = []
    m_fast, m_loop = dataclasses.asdict(fast.metrics), dataclasses.asdict(loop.metrics)
    out += [f"metrics.{k}" for k in m_loop if k != "wall_s" and not _same(m_fast[k], m_loop[k])]
    for name in ("intervals", "trajectory", "steps", "animation"):
        a, b = getattr(fast, name), getattr(loop, name)
        if isinstance(b, dict) and isinstance(a, dict):
            out += [f"{name}.{k}" for k in b if k not in a or not _same(a[k], b[k])]
            out += [f"{name}.{k} (extra)" for k in a if k not in b]
        elif not _same(a, b):
            out.append(name)
    assert fast.loop is not None and loop.loop is not None
    if not _same(
        [dataclasses.asdict(iv) for iv in fast.loop.intervals],
        [dataclasses.asdict(iv) for iv in loop.loop.intervals],
    ) or not _same(fast.loop.lambda_final, loop.loop.lambda_final):
        out.append("loop")
    # the engine that ran, and the one asked for (in the run specification), differ
    c_fast = {k: v for k, v in fast.config.items() if k != "engine"}
    c_loop = {k: v for k, v in loop.config.items() if k != "engine"}
    for c in (c_fast, c_loop):
        c["spec"] = {k: v for k, v in c["spec"].items() if k != "engine"}
    if not _same(c_fast, c_loop):
        out.append("config")
    return out


def _both(scene, *args, **kw) -> tuple[EpisodeResult, EpisodeResult]:
    fast = run_episode(scene, *args, engine="auto", **kw)
    loop = run_episode(scene, *args, engine="loop", **kw)
    assert fast.config["engine"] == "batch"
    assert loop.config["engine"] == "loop"
    problems = _differences(fast, loop)
    assert not problems, problems
    assert len(loop.steps["t"]) == loop.metrics["n_steps"] > 0
    return fast, loop


def test_nexus4_short(nexus4):
    fast, loop = _both(nexus4, "constant_velocity", PAPER_A10, max_frames=120)
    assert fast.animation is not None and fast.animation["pred"].size > 0
    assert loop.metrics["n_updates"] > 0


def test_nexus4_full_episode_reaches_the_goal(nexus4):
    fast, _ = _both(nexus4, "constant_velocity", PAPER_A10, safety_filter="exact2d")
    assert fast.metrics["goal_reached"]


@pytest.mark.parametrize("seed", [0, 3])
def test_crossing(seed):
    scene = load_scene("crossing", seed=seed)
    fast, _ = _both(scene, "constant_velocity", {"a": 2.0, "epsilon": 0.1}, seed=seed)
    # the filter acted: the comparison covers constrained instants
    assert (fast.animation["status"] == 1).any()


@pytest.mark.parametrize("fallback", ["lambda_search", "brake", "hold"])
def test_fallback_heavy(crossing, fallback):
    # lambda far below the feasibility floor (a large negative lambda_init, no learning,
    # the default lambda floor opened): the fallback decides on many instants
    params = {"a": 2.0, "epsilon": 0.1, "lambda_init": -50.0, "lambda_min": -math.inf}
    fast, loop = _both(crossing, "oracle", params, fallback=fallback, learn=False, max_frames=150)
    assert loop.metrics["n_fallback"] > 20
    assert (fast.animation["status"] == 2).any()


@pytest.mark.parametrize(
    ("predictor", "kw"),
    [
        ("constant_velocity", {"rule": "pid"}),
        ("constant_velocity", {"rule": "dtaci"}),
        ("constant_velocity", {"rule": "decaying_eta"}),
        ("constant_velocity", {"rule": "aci", "loss": "collision"}),
        ("constant_velocity", {"loss": "distance_shortfall"}),
        ("var", {}),
    ],
    ids=["pid", "dtaci", "decaying_eta", "aci-collision", "distance_shortfall", "var"],
)
def test_rules_losses_and_predictors(crossing, predictor, kw):
    # what the engine runs besides the fixed-eta rule, the gap loss and its compiled
    # predictors, through run_episode with the animation record: the loop's result exactly
    _, loop = _both(crossing, predictor, {"a": 2.0, "epsilon": 0.1}, max_frames=150, **kw)
    assert loop.metrics["n_updates"] > 0


def test_multiple_goals(crossing):
    # waypoints, two of them within the goal radius of each other (reached at one instant)
    goals = np.array([[10.0, 6.0], [10.2, 6.1], [18.0, 9.0], [28.0, 8.0]])
    scene = dataclasses.replace(crossing, goals=goals)
    fast, _ = _both(scene, "constant_velocity", {"a": 2.0, "epsilon": 0.1})
    assert fast.metrics["goal_reached"]


def test_without_animation_and_forced_engines(crossing):
    res = run_episode(crossing, max_frames=40, record_animation=False, engine="batch")
    assert res.animation is None and res.config["engine"] == "batch"
    # a configuration the engine does not run: auto falls back, batch says why
    res = run_episode(crossing, max_frames=40, safety_filter="qp")
    assert res.config["engine"] == "loop"
    with pytest.raises(ValueError, match="safety_filter 'qp'"):
        run_episode(crossing, max_frames=40, safety_filter="qp", engine="batch")
    with pytest.raises(ValueError, match="engine must be"):
        run_episode(crossing, max_frames=40, engine="fast")


def test_animation_barrier_minimum_is_the_per_frame_one(nexus4):
    # the record's h_true_min (computed for all frames at once) against the barrier
    # evaluated frame by frame on the agents present within the sensing radius
    res = run_episode(nexus4, "constant_velocity", PAPER_A10, max_frames=200)
    anim, sc = res.animation, res.scene
    from conformal_control.families.cbf.barriers import APFBarrier

    barrier = APFBarrier(**res.config["barrier"]["params"])
    robot = np.column_stack([res.trajectory["x"], res.trajectory["y"]])
    want = np.full(len(robot), np.nan)
    for i, frame in enumerate(res.trajectory["frame"] - sc.first_frame):
        p = sc.positions[frame]
        p = p[np.isfinite(p[:, 0])]
        near = p[np.hypot(*(p - robot[i]).T) <= anim["sensing_radius"]]
        if near.size:
            want[i] = np.min(barrier.evaluate(robot[i], near)[0])
    assert np.isfinite(want).sum() > 50
    assert np.array_equal(anim["h_true_min"], want.astype(np.float32), equal_nan=True)


def test_warnings_point_at_the_caller(crossing):
    """Both entry points (``run_episode`` and ``conformal_control.run``, with and without
    its progress bar) make the one engine choice, ``run_single``: on either engine, and on
    the loop an episode the compiled engine turned down once built, the run's warnings
    point at the caller's line."""
    import inspect

    import conformal_control as cc
    from conformal_control.core import registry
    from conformal_control.core.exceptions import FeasibilityWarning
    from conformal_control.families.cbf.barriers import APFBarrier
    from conformal_control.runs.engines.batch import supports

    class HandsNoForm(APFBarrier, compiled="apf"):
        """Declares the compiled APF form but hands none: turned down once built."""

        def compiled_state(self):  # type: ignore[override]
            return None

    infeasible = {"params": {"epsilon": -0.3, "a": 0.5}, "max_frames": 30}

    def line() -> int:
        frame = inspect.currentframe()
        assert frame is not None and frame.f_back is not None
        return frame.f_back.f_lineno + 1  # the call on the next line

    registry.register("barrier", "hands_no_form", HandsNoForm)
    try:
        assert supports(barrier="hands_no_form") is None  # known only once built
        for engine, kw, ran in [
            ("auto", {}, "batch"),
            ("loop", {}, "loop"),
            ("auto", {"barrier": "hands_no_form"}, "loop"),
        ]:
            for entry in ("run_episode", "run", "run with progress"):
                bar = "progress" in entry
                with pytest.warns(FeasibilityWarning) as caught:
                    if entry == "run_episode":
                        at = line()
                        res = run_episode(crossing, engine=engine, **infeasible, **kw)
                    else:
                        at = line()
                        res = cc.run(crossing, engine=engine, progress=bar, **infeasible, **kw)
                assert res.config["engine"] == ran, (engine, kw, entry)
                assert [(w.filename, w.lineno) for w in caught] == [(__file__, at)], (
                    engine, kw, entry, [(w.filename, w.lineno) for w in caught]
                )  # fmt: skip
    finally:
        registry.unregister("barrier", "hands_no_form")


def test_a_lone_episode_reads_its_recording_in_place_and_never_writes_it():
    # the engine reads a lone episode's recording without copying it; a batch copies it out
    # before a second episode joins: the scenes' data stay as they were
    from conformal_control.runs.engines.batch import run_batch

    scenes = [load_scene("crossing", seed=s) for s in range(3)]
    before = [sc.positions.copy() for sc in scenes]
    frozen = dataclasses.replace(scenes[2], positions=scenes[2].positions.copy())
    frozen.positions.flags.writeable = False  # read-only data are copied, not borrowed
    run_batch([*scenes, frozen], max_frames=80, batch_size=2)
    run_episode(scenes[0], max_frames=80)
    assert all(
        np.array_equal(sc.positions, b, equal_nan=True)
        for sc, b in zip(scenes, before, strict=True)
    )


def test_on_interval_is_called_alike_by_both_engines(crossing):
    """The compiled engine is a backend of the loop: it calls on_interval with the same
    logs, in the same order, as the generic loop."""
    logs: dict[str, list] = {"auto": [], "loop": []}
    params = {"a": 2.0, "epsilon": 0.1}
    for engine, seen in logs.items():
        res = run_episode(
            crossing, "constant_velocity", params, engine=engine, on_interval=seen.append,
            max_frames=150,
        )  # fmt: skip
        assert res.config["engine"] == ("batch" if engine == "auto" else "loop")
    assert len(logs["loop"]) == len(res.intervals) > 5
    assert [dataclasses.asdict(iv) for iv in logs["auto"]] == [
        dataclasses.asdict(iv) for iv in logs["loop"]
    ]
