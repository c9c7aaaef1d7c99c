"""lambda per pedestrian: a lockstep batch of benchmark episodes (``plan_all`` plans each
pedestrian with its own safe distance) equals the per-episode loop (``SamplingMPC.decide``
planning itself) in every metric field and every pedestrian's lambda, on real
``crossings-v2`` dev scenarios, nominal and under the 0.5 s delay."""

from __future__ import annotations

import numpy as np

from conformal_control.experiments.bench.methods import expand_methods
from conformal_control.experiments.bench.suite import bench_configs
from conformal_control.experiments.worker import load_run_scene
from conformal_control.runs.engines.mpc_batch import iter_mpc_batch
from conformal_control.runs.episode import run_episode

from .test_mpc_batch import _same_result

#: The benchmark's MPC methods with a lambda per pedestrian.
METHODS = ["cc_mpc_margin_agent", "cc_mpc_margin_agent_floor", "cc_mpc_margin_agent_interval"]


def _lams(result) -> list[bytes]:
    return [
        np.asarray(iv.lams, dtype=float).tobytes()
        for iv in result.loop.intervals
        if iv.lams is not None
    ]


def test_per_pedestrian_lockstep_equals_the_loop_on_crossings(data_root) -> None:
    cfgs = bench_configs(
        "crossings-v2",
        "dev",
        expand_methods(METHODS),
        limit=2,
        shifts=["nominal", "delay-0.5s"],
        data_root=str(data_root),
    )
    episodes = []
    for run in cfgs:
        scene = load_run_scene(run)
        spec = run.spec_on(120).set_params(family__sampling__n_samples=60)
        episodes.append((scene, spec, None))
    assert len(episodes) == 2 * 2 * len(METHODS)
    together = dict(iter_mpc_batch(iter(episodes), lockstep=True, batch_size=len(episodes)))
    problems, spread = {}, 0
    for i, (scene, spec, _) in enumerate(episodes):
        alone = run_episode(scene, spec)  # auto: the loop for an MPC
        assert alone.config["engine"] == "loop"
        got = together[i]
        diff = _same_result(got, alone)
        if _lams(got) != _lams(alone):
            diff.append("lams")
        if diff:
            problems[cfgs[i].label] = diff
        spread += sum(
            np.unique(iv.lams).size > 1 for iv in alone.loop.intervals if iv.lams is not None
        )
    assert not problems, problems
    # pedestrians carried different lambdas in one interval: the offsets were exercised
    assert spread > 0
