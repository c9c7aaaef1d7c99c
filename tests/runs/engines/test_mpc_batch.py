"""Sampling-MPC episodes run in this process (one after another or in lockstep) give the
one-at-a-time results, field by field."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from conformal_control.core.spec import RunSpec
from conformal_control.data import load_scene
from conformal_control.experiments.batch import mpc_batch_reason
from conformal_control.experiments.bench.methods import expand_methods
from conformal_control.experiments.plan import SweepRun
from conformal_control.runs.engines.batch import as_run_spec
from conformal_control.runs.engines.mpc_batch import iter_mpc_batch
from conformal_control.runs.engines.mpc_batch import mpc_batch_reason as run_reason
from conformal_control.runs.episode import run_episode

from .conftest import WALL, same

#: The benchmark's MPC methods (one setting each), as bench run builds them.
METHODS = ["mpc", "cc_mpc", "acp_mpc", "ecp_mpc", "fcp_mpc"]


def _runs() -> list[tuple[str, RunSpec]]:
    out = []
    for name in METHODS:
        method = expand_methods([name])[0]
        kw = method.run_kwargs()
        kw["family_params"] = {**kw["family_params"], "sampling__n_samples": 60}
        out.append((method.name, as_run_spec(**kw)))
    return out


def _same_result(a, b) -> list[str]:
    da, db = dataclasses.asdict(a.metrics), dataclasses.asdict(b.metrics)
    diff = [k for k in da if k not in WALL and not same(da[k], db[k])]
    if not same(a.intervals, b.intervals):
        diff.append("intervals")
    for k in ("t", "x", "cmd"):
        if a.steps[k].tobytes() != b.steps[k].tobytes():
            diff.append(f"steps[{k}]")
    assert a.trajectory.keys() == b.trajectory.keys()
    for k in a.trajectory:
        if np.asarray(a.trajectory[k]).tobytes() != np.asarray(b.trajectory[k]).tobytes():
            diff.append(f"trajectory[{k}]")
    ca = {k: v for k, v in a.config.items() if k != "engine"}
    cb = {k: v for k, v in b.config.items() if k != "engine"}
    if ca != cb:
        diff.append("config")
    return diff


def test_lockstep_episodes_equal_one_at_a_time():
    """Five MPC families on three crossing seeds, several frame limits, batches of 4 (a
    freed slot refilled mid-run, families with different plans planning together)."""
    scenes = [load_scene("crossing", seed=s) for s in range(3)]
    episodes = []
    for k, (_, run) in enumerate(_runs()):
        for j, scene in enumerate(scenes):
            r = dataclasses.replace(run, seed=k + j, max_frames=240 + 60 * ((k + j) % 3))
            r = dataclasses.replace(r, record_animation=False)
            episodes.append((scene, r, {"tag": k * 10 + j}))
    got = dict(iter_mpc_batch(iter(episodes), lockstep=True, batch_size=4))
    assert sorted(got) == list(range(len(episodes)))
    problems = {}
    for i, (scene, run, extra) in enumerate(episodes):
        alone = run_episode(scene, run, extra_config=extra)  # auto: the loop for an MPC
        res = got[i]
        assert res.config["engine"] == "mpc_batch" and alone.config["engine"] == "loop"
        assert res.config["tag"] == extra["tag"]
        assert res.metrics.wall_s > 0
        diff = _same_result(res, alone)
        if diff:
            problems[i] = diff
    assert not problems, problems
    # the episodes differ (the comparison is not one of equal runs) and they did plan
    assert len({r.metrics.path_length for r in got.values()}) > len(episodes) // 2
    assert all(got[i].metrics.n_updates > 0 for i, e in enumerate(episodes) if e[1].learn)
    assert sum(r.metrics.n_infeasible for r in got.values()) > 0


@pytest.mark.parametrize("lockstep", [False, True])
def test_each_result_is_yielded_before_the_next_episode_starts(lockstep: bool) -> None:
    """A sweep journals each result as it is yielded: an interrupted benchmark keeps the
    episodes that ended (the first version ran the whole feed before yielding any)."""
    scene = load_scene("crossing", seed=0)
    run = dataclasses.replace(as_run_spec(family="mpc"), max_frames=30, record_animation=False)
    taken: list[int] = []

    def feed():
        for i in range(3):
            taken.append(i)
            yield scene, dataclasses.replace(run, seed=i), None

    size = 2 if lockstep else 1
    for n, (i, _) in enumerate(iter_mpc_batch(feed(), lockstep=lockstep, batch_size=size)):
        # without lockstep the episode yielded is the last one taken; in lockstep at
        # most one batch is alive beyond the results yielded
        assert len(taken) <= n + size, (n, i, taken)


def test_mpc_batch_reasons():
    run = as_run_spec(family="mpc")
    assert run_reason(run) is None
    assert "not a sampling MPC" in run_reason(as_run_spec(family="cbf"))
    sweep = SweepRun.from_settings
    assert mpc_batch_reason(sweep("crossing", family="acp_mpc"), "none") is None
    assert "plots" in mpc_batch_reason(sweep("crossing", family="mpc"), True)
    assert "sampling MPC" in mpc_batch_reason(sweep("crossing"), "none")
    with pytest.raises(ValueError, match="batch_size"):
        list(iter_mpc_batch([], batch_size=0))
    bad = (load_scene("crossing", seed=0), as_run_spec(family="cbf"), None)
    with pytest.raises(ValueError, match="does not run here"):
        list(iter_mpc_batch([bad]))


def test_a_sweep_runs_mpc_families_in_process_with_the_serial_records(tmp_path):
    """``run_sweep(executor="batch")`` (``bench run``'s) runs MPC runs in this process; their
    rows and config.json are the serial sweep's (the engine aside)."""
    from conformal_control.experiments import run_sweep

    from .test_batch_sweep import _by_key, _same_rows

    small = {"sampling__n_samples": 40, "sampling__replan_every": 2}
    runs = [
        SweepRun.from_settings(
            "crossing",
            seed=s,
            max_frames=160,
            record_animation=False,
            family=fam,
            family_params=small,
        )
        for s, fam in ((0, "mpc"), (1, "acp_mpc"), (2, "mpc"))
    ]
    rep = run_sweep(runs, tmp_path / "a", "batch", workers=1, summary_plot=False)
    ref = run_sweep(runs, tmp_path / "b", "serial", summary_plot=False)
    assert not rep.failed and len(rep.ran) == 3
    _same_rows(_by_key(rep.rows), _by_key(ref.rows))
    assert all(r["worker"].endswith("(batch)") for r in rep.rows)
    dirs = {r["key"]: r["run_dir"] for r in ref.rows}
    for r in rep.rows:
        assert r["run_dir"] != dirs[r["key"]]
        ca = json.loads((tmp_path / "a" / r["run_dir"] / "config.json").read_text())
        cb = json.loads((tmp_path / "b" / dirs[r["key"]] / "config.json").read_text())
        assert ca.pop("engine") == "mpc_batch" and cb.pop("engine") == "loop"
        assert ca == cb


def test_with_several_workers_the_mpc_runs_go_to_the_pool(monkeypatch, tmp_path):
    """In process only with one worker: more workers run the MPC episodes in parallel."""
    import conformal_control.experiments.batch as sweep_batch

    class FakePool:
        n_workers = 2

        def run(self, fn, tasks):
            for k, _ in enumerate(tasks):
                yield k, {"key": f"pool{k}", "status": "ok"}

    def no_mpc_here(*a, **k):
        raise AssertionError("an MPC run ran in this process")

    monkeypatch.setattr("conformal_control.runs.engines.mpc_batch.iter_mpc_batch", no_mpc_here)
    run = SweepRun.from_settings("crossing", seed=1, family="mpc", record_animation=False)
    assert mpc_batch_reason(run, "none") is None
    records = dict(sweep_batch.run_batched(FakePool(), [(run, "m0", str(tmp_path), "none")]))
    assert records == {0: {"key": "pool0", "status": "ok"}}
