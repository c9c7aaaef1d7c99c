"""lambda run per agent on the batch engine: run_episode's episodes, bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformal_control.data import load_scene


@pytest.fixture(scope="module")
def crossings():
    return [load_scene("crossing", seed=s) for s in range(3)]


def _same_agents(batched, singles):
    """Every interval's agents, their lambdas and their losses are the loop's."""
    for b, s in zip(batched, singles, strict=True):
        ib, il = b.loop.intervals, s.loop.intervals
        assert len(ib) == len(il)
        for x, y in zip(ib, il, strict=True):
            assert np.array_equal(x.keys, y.keys)
            assert np.array_equal(x.lams, y.lams)
            assert np.array_equal(x.agent_losses, y.agent_losses, equal_nan=True)
        assert b.loop.monitor.summary() == s.loop.monitor.summary()


@pytest.mark.parametrize(
    ("rule", "extra"),
    [
        ("fixed_eta", {}),  # the compiled predictor and fallback
        ("dtaci", {"predictor": "delayed", "predictor_params": {"delay_s": 0.5}}),
        # Python fallback: below the default lambda floor
        ("fixed_eta", {"fallback": "relax", "params": {"epsilon": -0.3, "lambda_min": -math.inf}}),
    ],
)
def test_per_agent_matches_run_episode(crossings, compare_batch, rule, extra):
    params = {"lambda_per": "agent", "epsilon": -0.05, "lambda_prior": 0.3}
    params.update(extra.pop("params", {}))
    batched, singles = compare_batch(
        crossings,
        seeds=[0, 1, 2],
        output="results",
        rule=rule,
        params=params,
        max_frames=[200, 160, 240],
        batch_size=2,
        **extra,
    )
    _same_agents(batched, singles)
    mons = [s.loop.monitor for s in singles]
    assert all(m.n_agents > 3 for m in mons)
    # agents' lambdas differ within an episode (it is not one lambda repeated)
    assert all(np.ptp(m.current()) > 1e-3 for m in mons)
    if "fallback" in extra:
        assert sum(s.metrics.n_fallback for s in singles) > 0


def test_per_agent_with_a_loss_that_does_not_split_is_refused(crossings):
    from conformal_control.runs.engines.batch import run_batch

    with pytest.raises(ValueError, match="does not split by agent"):
        run_batch(crossings[:1], params={"lambda_per": "agent"}, loss="collision", max_frames=40)


@pytest.fixture(scope="module")
def suite_scenes(data_root):
    from conformal_control.data.suites import load_suite

    ids = [sc.id for sc in load_suite("crossings-v2").scenarios_for("dev")][:3]
    return [load_scene(f"scenario:crossings-v2/{i}", str(data_root)) for i in ids]


@pytest.mark.parametrize(
    "family",
    [
        "conformal_agent",
        "conformal_agent_dtaci",
        "conformal_agent_shortfall",
        "conformal_agent_floorstep",
        "conformal_dtaci_floor",
    ],
)
def test_the_new_benchmark_methods_match_run_episode(suite_scenes, compare_batch, family):
    """The benchmark's per-pedestrian and floored methods, under the 0.5 s delay (the
    predictor called through the episode's own objects) on crossings-v2 scenarios."""
    from conformal_control.experiments.bench.methods import expand_methods

    kw = expand_methods([family])[0].run_kwargs()
    kw["predictor"] = "delayed"
    kw["predictor_params"] = {"delay_s": 0.5, "predictor": "constant_velocity"}
    frames = [sc.meta["max_frames"] for sc in suite_scenes]
    batched, singles = compare_batch(
        suite_scenes, max_frames=frames, batch_size=2, output="results", **kw
    )
    if kw["params"].get("lambda_per") == "agent":
        _same_agents(batched, singles)
    assert all(s.metrics.n_updates > 0 for s in singles)


def test_a_derived_lambda_safe_is_reported_and_its_premise_checked(crossings, compare_batch):
    """lambda_safe="auto": derived from the built run (the CBF gap bound), the same on both
    engines, every agent's loss re-evaluated at it at every interval."""
    from conformal_control.families.cbf.safe_lambda import barrier_slope_bound
    from conformal_control.runs.build import build_flagship
    from conformal_control.runs.results.measure import derived_lambda_safe

    params = {"lambda_per": "agent", "epsilon": -0.05}
    batched, singles = compare_batch(
        crossings[:2], seeds=[0, 1], output="results", params=params, lambda_safe="auto",
        max_frames=[160, 160], batch_size=2,
    )  # fmt: skip
    _same_agents(batched, singles)
    from conformal_control.core.spec import RunSpec

    fl = build_flagship(crossings[0], RunSpec(params=params, lambda_safe="auto"))
    safe = derived_lambda_safe(fl)
    si = fl.params.si
    m_h = barrier_slope_bound(fl.barrier)
    g = m_h * (2 * si["v_max"] + 2 * 3.0) + si["a"] * 1.0
    assert safe.gap_bound == pytest.approx(g)
    assert safe.value == pytest.approx(si["loss_scale"] * math.tan(math.pi * -0.05) - g)
    unit = crossings[0].units.factor("lambda_init")
    for s in singles:
        m = s.metrics
        assert m.lambda_safe == pytest.approx(safe.value / unit)
        assert m.lambda_safe_source.startswith("derived: CBF gap bound")
        assert m.n_premise_checks > 0 and m.n_premise_exceeded == 0
        assert m.n_agents_premise_tested == 0  # lambda never goes that low here
        assert m.theorem2_verdict != "not_applicable" and m.n_agents_bound_met is not None


def test_a_derived_lambda_safe_needs_the_gap_loss(crossings):
    from conformal_control.runs.episode import run_episode

    with pytest.raises(ValueError, match="derived for the CBF gap loss only"):
        run_episode(crossings[0], loss="collision", lambda_safe="auto", max_frames=20)


@pytest.mark.parametrize(
    "extra",
    [
        {"params": {"lambda_floor_row": 1.0}},  # each agent's own row floor
        {"loss": "cbf_shortfall"},  # the shortfall loss
        {"params": {"lambda_floor_row": 0.8}, "loss": "cbf_shortfall"},
    ],
)
def test_the_row_floor_and_the_shortfall_loss_match_run_episode(suite_scenes, compare_batch, extra):
    """Per-pedestrian DtACI under the 0.5 s delay with each agent's own row floor and/or
    the shortfall loss: every metric, every agent's lambda and loss, the floor counters."""
    from conformal_control.experiments.bench.methods import expand_methods

    kw = expand_methods(["conformal_agent_dtaci"])[0].run_kwargs()
    kw["params"].update(extra.get("params", {}))
    if "loss" in extra:
        kw["loss"] = extra["loss"]
    kw["predictor"] = "delayed"
    kw["predictor_params"] = {"delay_s": 0.5, "predictor": "constant_velocity"}
    frames = [sc.meta["max_frames"] for sc in suite_scenes]
    batched, singles = compare_batch(
        suite_scenes, max_frames=frames, batch_size=2, output="results", **kw
    )
    _same_agents(batched, singles)
    for b, s in zip(batched, singles, strict=True):
        mb, ms = b.loop.monitor, s.loop.monitor
        assert (mb.n_floor_lowered, mb.n_floor_bound) == (ms.n_floor_lowered, ms.n_floor_bound)
        assert (mb.n_floor_stepped, mb.agent_floors) == (ms.n_floor_stepped, ms.agent_floors)
    if "lambda_floor_row" in extra.get("params", {}):
        assert sum(s.loop.monitor.n_floor_lowered for s in singles) > 0
        lows = [float(np.min(iv.lams)) for s in singles for iv in s.loop.intervals if iv.lams.size]
        assert min(lows) < kw["params"]["lambda_min"]  # below the run's floor: its own row's
    if "loss" in extra:
        top = max(
            float(np.nanmax(iv.agent_losses))
            for s in singles
            for iv in s.loop.intervals
            if iv.agent_losses is not None and np.isfinite(iv.agent_losses).any()
        )
        assert top > 0.5  # a shortfall scored beyond the gap loss's 1/2


def test_the_floor_step_matches_run_episode(data_root, compare_batch):
    """``conformal_agent_floorstep`` under the 0.5 s delay on two dev scenarios where a
    pedestrian is still missed at the -30/s floor (its floor steps 10/s down, not below
    -60/s): every metric, every agent's lambda and loss, every agent's floor."""
    from conformal_control.experiments.bench.methods import expand_methods

    ids = ("ethucy-crowds_zara02-w017", "ethucy-crowds_zara02-w060")
    scenes = [load_scene(f"scenario:crossings-v2/{i}", str(data_root)) for i in ids]
    kw = expand_methods(["conformal_agent_floorstep"])[0].run_kwargs()
    kw["predictor"] = "delayed"
    kw["predictor_params"] = {"delay_s": 0.5, "predictor": "constant_velocity"}
    frames = [sc.meta["max_frames"] for sc in scenes]
    batched, singles = compare_batch(
        scenes, max_frames=frames, batch_size=2, output="results", **kw
    )
    _same_agents(batched, singles)
    for b, s in zip(batched, singles, strict=True):
        mb, ms = b.loop.monitor, s.loop.monitor
        assert (mb.n_floor_stepped, mb.agent_floors) == (ms.n_floor_stepped, ms.agent_floors)
        assert ms.n_floor_stepped > 0
        assert all(-60.0 <= f <= -40.0 for f in ms.agent_floors.values())
    lows = [float(np.min(iv.lams)) for s in singles for iv in s.loop.intervals if iv.lams.size]
    assert -60.0 <= min(lows) < kw["params"]["lambda_min"]  # below the run's floor
