"""The lockstep batch engine gives run_episode's metrics, field by field (wall time aside)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from conformal_control.core.exceptions import NoUpdatesWarning
from conformal_control.data import load_scene
from conformal_control.runs.engines.batch import iter_batch, run_batch, supports
from conformal_control.runs.episode import run_episode


@pytest.fixture(scope="module")
def crossings():
    """The built-in crossing scene with four seeds."""
    return [load_scene("crossing", seed=s) for s in range(4)]


@pytest.mark.parametrize("learn", [True, False])
def test_crossing_seeds_match_run_episode(crossings, compare_batch, learn):
    # batch_size 3 < 4 scenes: a freed slot is refilled mid-run
    batched, singles = compare_batch(crossings, seeds=[0, 1, 2, 3], learn=learn)
    assert all(m.wall_s > 0 for m in batched)
    # the seeds give different episodes (the comparison is not trivially of equal runs)
    assert len({s.metrics.path_length for s in singles}) == len(singles)
    if learn:
        assert all(m.n_updates > 0 for m in batched)


def test_crossing_oracle_and_brake_with_si_parameters(crossings, compare_batch):
    compare_batch(
        crossings[:2],
        predictor="oracle",
        units="si",
        params={"epsilon": -0.1, "eta": 10.0},
        fallback="brake",
        max_frames=120,
    )


@pytest.mark.parametrize("fallback", ["relax", "brake"])
def test_acp_family_matches_run_episode(crossings, compare_batch, fallback):
    """The acp family (its regions, its miscoverage loss, ACI) with the compiled and a
    Python fallback: every metric and every interval's row."""
    from conformal_control.experiments.bench.methods import expand_methods

    kw = expand_methods(["acp"])[0].run_kwargs()
    kw["family_params"] = {"window": 200, "max_inflation": 0.6}
    _, singles = compare_batch(
        crossings, seeds=[0, 1, 2, 3], output="results", fallback=fallback, **kw
    )
    assert all(s.metrics.n_updates > 0 for s in singles)
    assert len({s.metrics.lambda_final for s in singles}) > 1  # not four equal episodes
    assert sum(s.metrics.n_fallback for s in singles) > 0  # the fallback decided too


def test_relax_fallback_matches_run_episode(crossings, compare_batch):
    """The relax fallback decides in Python (its LP) on the compiled step's rows, for the
    paused episode only, while the others of the batch run on."""
    _, singles = compare_batch(
        crossings,
        seeds=[0, 1, 2, 3],
        output="results",
        fallback="relax",
        fallback_params={"weights": "inverse_gradient"},
        params={"epsilon": -0.3, "lambda_min": -math.inf},  # below the default floor
        max_frames=[240, 200, 160, 240],
    )
    assert all(s.metrics.n_fallback > 20 for s in singles)


# ------------------------------------------------------------------ crossings-v1 scenarios
DEV_SCENARIOS = 4


@pytest.fixture(scope="module")
def suite_scenes(data_root):
    from conformal_control.data.suites import load_suite

    ids = [sc.id for sc in load_suite("crossings-v1").scenarios_for("dev")][:DEV_SCENARIOS]
    return [load_scene(f"scenario:crossings-v1/{i}", str(data_root)) for i in ids]


@pytest.mark.parametrize("method", ["nolearn", "conformal", "inflated", "acp", "fallback:relax"])
def test_suite_scenarios_match_run_episode(suite_scenes, compare_batch, method):
    from conformal_control.experiments.bench.methods import expand_methods

    m = expand_methods([method], {"conformal": [-0.1], "inflated": [0.25]})[0]
    kw = m.run_kwargs()
    frames = [sc.meta["max_frames"] for sc in suite_scenes]
    assert len(set(frames)) > 1 or len({sc.n_frames for sc in suite_scenes}) > 1
    compare_batch(suite_scenes, max_frames=frames, batch_size=2, **kw)


# ------------------------------------------------------------------ edge cases
def _with_tracks(scene, tracks):
    """``scene`` (its parameters, start and goal) with these (F, 2) tracks as its crowd."""
    pos = np.stack(tracks, axis=1) if tracks else np.full((scene.n_frames, 0, 2), np.nan)
    return dataclasses.replace(scene, positions=pos, agent_ids=np.arange(pos.shape[1]) + 1)


def _track(scene, p0, v, gaps=()):
    """p0 + v (t - t_start) at every frame of ``scene``, NaN on the frame ranges ``gaps``."""
    t = (np.arange(scene.n_frames) - scene.start_index)[:, None] / scene.fps
    out = np.asarray(p0, dtype=float) + t * np.asarray(v, dtype=float)
    for lo, hi in gaps:
        out[scene.start_index + lo : scene.start_index + hi] = np.nan
    return out


def test_empty_scene_and_episodes_of_different_lengths(crossings, compare_batch):
    """A scene without agents beside crossing scenes stopped after different frame counts."""
    empty = _with_tracks(crossings[0], [])
    assert empty.n_agents == 0
    with pytest.warns(NoUpdatesWarning):  # both engines warn about the empty scene
        batched, _ = compare_batch(
            [empty, crossings[0], crossings[1], empty], max_frames=[40, 7, 150, 1], batch_size=4
        )
    assert batched[0].n_scored == 0 and batched[0].n_updates == 0
    assert len({m.frames for m in batched}) == 4


def test_agents_appearing_and_disappearing(crossings, compare_batch):
    """Agents enter after the start, leave and come back, or vanish, near the robot."""
    base = crossings[0]
    tracks = [
        _track(base, (6.0, 2.0), (0.0, 1.2), gaps=[(0, 25)]),  # appears late
        _track(base, (9.0, 14.0), (-0.2, -1.0), gaps=[(30, 60)]),  # leaves, comes back
        _track(base, (4.0, 9.0), (0.8, -0.1), gaps=[(45, 10_000)]),  # vanishes for good
    ]
    scenes = [_with_tracks(base, tracks), _with_tracks(base, tracks[::-1][:2])]
    for learn in (True, False):
        _, singles = compare_batch(scenes, max_frames=150, learn=learn, batch_size=2)
        assert all(s.metrics.n_scored > 0 for s in singles)
        assert any(s.metrics.n_truth_missing > 0 for s in singles)  # a gap fell inside an interval


def test_results_output_keeps_config_intervals_and_trajectory(crossings):
    [res] = run_batch(crossings[:1], output="results", max_frames=60, extra_config={"x": 1})
    ref = run_episode(
        crossings[0], max_frames=60, record_animation=False, extra_config={"x": 1}, engine="loop"
    )
    assert res.config.pop("engine") == "batch"
    assert ref.config.pop("engine") == "loop"
    assert res.config["spec"].pop("engine") == "auto"  # asked for, in the specification
    assert ref.config["spec"].pop("engine") == "loop"
    assert res.config == ref.config
    assert res.intervals == ref.intervals
    assert res.trajectory.keys() == ref.trajectory.keys()
    for k, v in ref.trajectory.items():
        np.testing.assert_array_equal(res.trajectory[k], v)
    assert res.animation is None and res.steps == {}


def test_iter_batch_yields_indices_in_completion_order(crossings):
    out = dict(iter_batch(crossings[:3], max_frames=[200, 10, 60], batch_size=3))
    assert sorted(out) == [0, 1, 2]
    order = [i for i, _ in iter_batch(crossings[:3], max_frames=[200, 10, 60], batch_size=3)]
    assert order == [1, 2, 0]


# ------------------------------------------------------------------ what it accepts
@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"crowd": "social_force", "crowd_params": {"noise": 0.1}}, "deterministic crowds"),
        ({"loss": "miscoverage"}, "loss 'miscoverage'"),
        ({"predictor": object()}, "predictor given as a object instance"),
        ({"fallback": "brake", "fallback_params": {"x": 1}}, "fallback parameters for 'brake'"),
        ({"family": "mpc"}, "family 'mpc'"),
        ({"barrier": "distance_squared"}, "barrier 'distance_squared'"),
        ({"record_animation": True}, "animation"),
        ({"robots": 2}, "one robot"),
        ({"robotz": 2}, "unexpected keyword argument 'robotz'"),
    ],
)
def test_supports_names_the_reason(kwargs, words):
    why = supports(**kwargs)
    assert why is not None and words in why


def test_supported_configuration_and_clear_error(crossings):
    assert supports(predictor="oracle", learn=False, fallback="hold") is None
    with pytest.raises(ValueError, match="does not support this configuration: crowd noise"):
        run_batch(crossings[:1], crowd="social_force", crowd_params={"noise": 0.1})
    with pytest.raises(ValueError, match="batch_size must be a positive integer"):
        run_batch(crossings[:1], batch_size=0)


def test_a_plugin_runs_compiled_only_if_its_class_declares_it():
    """Capability, not a list of names: a subclass inherits no declaration (it may compute
    something else); one that declares the compiled counterpart runs compiled."""
    from conformal_control.core import registry
    from conformal_control.families.cbf.barriers import APFBarrier

    class Tweaked(APFBarrier):
        """An APF barrier computing something else."""

    class Same(APFBarrier, compiled="apf"):
        """An APF barrier under another name."""

    assert APFBarrier.capabilities.compiled == "apf" and Tweaked.capabilities.compiled is None
    assert Tweaked.capabilities.run_values == APFBarrier.capabilities.run_values  # inherited
    registry.register("barrier", "tweaked_apf", Tweaked)
    registry.register("barrier", "same_apf", Same)
    try:
        assert "compiles apf" in (supports(barrier="tweaked_apf") or "")
        assert supports(barrier="same_apf") is None
    finally:
        registry.unregister("barrier", "tweaked_apf")
        registry.unregister("barrier", "same_apf")


def test_a_third_party_barrier_runs_compiled_through_its_compiled_form(crossing) -> None:
    """A barrier of its own class (no APFBarrier subclass) that declares the ``apf`` form
    and hands its constants over runs in the compiled engine, with the same result as the
    loop running its own evaluate()."""
    from conformal_control.core import registry
    from conformal_control.families.cbf.barriers import APFBarrier, APFForm
    from conformal_control.families.cbf.roles import Barrier

    class OwnAPF(Barrier, compiled="apf", run_values=APFBarrier.capabilities.run_values):
        """The APF barrier written by someone else (same arithmetic, own class).

        Parameters
        ----------
        K_rep, rho0, d_c, convention, delta
            As APFBarrier's.
        """

        def __init__(self, K_rep=1.0, rho0=10.0, d_c=1.0, convention="surface", delta=None):
            self.K_rep, self.rho0, self.d_c = K_rep, rho0, d_c
            self.convention, self.delta = convention, delta

        def _apf(self) -> APFBarrier:
            return APFBarrier(**self.get_params())

        def evaluate(self, x_ego, x_agent):
            return self._apf().evaluate(x_ego, x_agent)

        @property
        def upper_bound(self):
            return self._apf().upper_bound

        def compiled_state(self) -> APFForm:
            return self._apf().compiled_state()

    registry.register("barrier", "own_apf", OwnAPF)
    try:
        assert supports(barrier="own_apf", learn=True) is None
        kw = {"barrier": "own_apf", "max_frames": 60, "seed": 0}
        compiled = run_episode(crossing, engine="batch", **kw)
        loop = run_episode(crossing, engine="loop", **kw)
    finally:
        registry.unregister("barrier", "own_apf")
    assert compiled.config["engine"] == "batch" and loop.config["engine"] == "loop"
    assert np.array_equal(compiled.trajectory["x"], loop.trajectory["x"])
    assert [iv["lambda"] for iv in compiled.intervals] == [iv["lambda"] for iv in loop.intervals]
