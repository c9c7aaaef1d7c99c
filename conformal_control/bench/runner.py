"""Run the benchmark: every scenario of a suite split x every method, on the sweep runner.

Each (scenario, method) pair is one run of a sweep (:func:`conformal_control.sweep.run_sweep`):
resumable by key, failures isolated and recorded, a progress bar, any executor (local
processes, serial, Dask). The scene of a run is ``scenario:<suite>/<id>`` (its time limit
comes with it), the method's parameters are in SI (``units="si"``), and the row of every
episode carries the scenario's and the method's description (``meta``) so that reports
are built from the stored rows alone (:func:`conformal_control.bench.report.write_report`).
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..data.suites import Scenario, load_suite
from .methods import DEFAULT_METHODS, Method, available, expand_methods

__all__ = ["BenchRun", "bench_configs", "read_rows", "run_bench"]

#: What each run of the benchmark writes (config.json + metrics.json); the rows are in
#: the sweep's journal and tables.
RUN_FILES = "metrics"


def _meta(suite: str, sc: Scenario, method: Method, crowd: str) -> dict[str, Any]:
    return {
        "suite": suite,
        "scenario": sc.id,
        "split": sc.split,
        "source": sc.recording,
        "time_limit": sc.time_limit_s,
        "method": method.name,
        "family": method.family,
        "setting": method.setting,
        "crowd": crowd,
        "n_crossing": sc.stats.get("n_crossing"),
        # suite scenes count time in frames: lambda in 1/frame = fps / s
        "lambda_unit_si": sc.fps,
    }


def bench_configs(
    suite: str,
    split: str | None,
    methods: Sequence[Method],
    *,
    predictor: str = "constant_velocity",
    crowd: str = "replay",
    crowd_params: Mapping[str, Any] | None = None,
    data_root: str | None = None,
    seed: int = 0,
    scenarios: Iterable[str] | None = None,
    limit: int | None = None,
    base_params: Mapping[str, Any] | None = None,
) -> list[Any]:
    """The sweep's run configurations: one per (scenario, method), scenarios outermost.

    Parameters
    ----------
    suite : str
        A shipped suite (``conformal-control bench scenarios``).
    split : {"dev", "test"} or None
        None runs both.
    methods : sequence of Method
    predictor : str
        The predictor every method uses (a method may replace it, e.g. the oracle).
    crowd, crowd_params :
        Replayed pedestrians or a reactive crowd (see ``run --crowd``).
    scenarios : iterable of str, optional
        Only these scenario ids.
    limit : int, optional
        Only the first ``limit`` scenarios of the split (quick looks, tests).
    base_params : mapping, optional
        Run parameters (SI) applied to every method; a method's own parameters win.
    """
    from ..sweep.spec import RunConfig

    s = load_suite(suite)
    chosen = s.scenarios_for(split) if split else list(s.scenarios)
    if scenarios is not None:
        wanted = set(scenarios)
        unknown = sorted(wanted - {sc.id for sc in s.scenarios})
        if unknown:
            raise ValueError(f"unknown scenario(s) of {suite}: {', '.join(unknown[:5])}")
        chosen = [sc for sc in chosen if sc.id in wanted]
    if limit is not None:
        chosen = chosen[: int(limit)]
    if not chosen:
        raise ValueError(f"no scenario of suite {suite} matches (split={split!r})")
    name = s.name if hasattr(s, "name") else suite
    configs = []
    for sc in chosen:
        for m in methods:
            kw = m.run_kwargs(predictor)
            episode = {
                k: v
                for k, v in kw.items()
                if k not in ("predictor", "params", "learn", "predictor_params")
            }
            if crowd != "replay":
                episode["crowd"] = crowd
                if crowd_params:
                    episode["crowd_params"] = dict(crowd_params)
            episode["record_animation"] = False
            configs.append(
                RunConfig(
                    scene=f"scenario:{name}/{sc.id}",
                    predictor=kw["predictor"],
                    learn=kw["learn"],
                    seed=seed,
                    params={**dict(base_params or {}), **dict(kw["params"])},
                    data_root=data_root,
                    label=f"{sc.id}-{m.name}",
                    episode=episode,
                    meta=_meta(name, sc, m, crowd),
                )
            )
    return configs


@dataclass
class BenchRun:
    """What :func:`run_bench` did (the sweep's report and where the rows are)."""

    out_dir: Path
    n_runs: int
    skipped: int
    ran: int
    failed: int
    unavailable: dict[str, str]
    wall_s: float

    def summary(self) -> str:
        extra = ""
        if self.unavailable:
            extra = "; methods left out (plugin unavailable): " + ", ".join(self.unavailable)
        return (
            f"{self.n_runs} episodes: {self.skipped} already done, {self.ran} ran "
            f"({self.failed} failed) in {self.wall_s:.1f} s; results in {self.out_dir}{extra}"
        )


def run_bench(
    out: str | Path,
    *,
    suite: str = "crossings-v1",
    split: str | None = "test",
    methods: Sequence[str] = DEFAULT_METHODS,
    grids: Mapping[str, Sequence[Any]] | None = None,
    predictor: str = "constant_velocity",
    crowd: str = "replay",
    crowd_params: Mapping[str, Any] | None = None,
    data_root: str | None = None,
    executor: str = "batch",
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool | None = None,
    limit: int | None = None,
    seed: int = 0,
    base_params: Mapping[str, Any] | None = None,
) -> BenchRun:
    """Run the benchmark into ``out`` (resumable: finished episodes are skipped).

    Methods whose plugins are not installed are left out and reported (never silently).
    ``executor="batch"`` (default) runs the (scenario, method) pairs the lockstep engine
    supports many at once in this process, with the metrics of the per-episode loop, and
    the others on a process pool of ``workers`` (see :mod:`conformal_control.sweep.batch`);
    ``"process"``, ``"serial"`` and ``"dask"`` run one episode per task.
    ``bench.json`` in ``out`` records the benchmark's configuration.
    """
    from ..sweep.runner import run_sweep

    out = Path(out)
    all_methods = expand_methods(methods, grids)
    unavailable = {m.name: why for m in all_methods if (why := available(m)) is not None}
    chosen = [m for m in all_methods if m.name not in unavailable]
    if not chosen:
        raise ValueError("no method can run: " + "; ".join(unavailable.values()))
    configs = bench_configs(
        suite,
        split,
        chosen,
        predictor=predictor,
        crowd=crowd,
        crowd_params=crowd_params,
        data_root=data_root,
        seed=seed,
        limit=limit,
        base_params=base_params,
    )
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.json").write_text(
        json.dumps(
            {
                "suite": suite,
                "split": split,
                "predictor": predictor,
                "crowd": crowd,
                "crowd_params": dict(crowd_params or {}),
                "methods": [m.as_dict() for m in chosen],
                "unavailable": unavailable,
                "limit": limit,
                "seed": seed,
                "base_params": dict(base_params or {}),
            },
            indent=2,
            default=str,
        )
        + "\n"
    )
    t0 = time.perf_counter()
    rep = run_sweep(
        configs,
        out,
        executor,
        workers=workers,
        scheduler=scheduler,
        plot=RUN_FILES,
        summary_plot=False,
        progress=progress,
        # the journal has every episode as it finishes; the tables (rewritten whole) about
        # ten times over the run: after every 50 episodes made a suite of thousands
        # quadratic in its size
        table_every=max(50, len(configs) // 10),
    )
    return BenchRun(
        out_dir=out,
        n_runs=len(configs),
        skipped=len(rep.skipped),
        ran=len(rep.ran),
        failed=len(rep.failed),
        unavailable=unavailable,
        wall_s=time.perf_counter() - t0,
    )


def read_rows(out: str | Path) -> list[dict[str, Any]]:
    """The stored per-episode rows of a benchmark folder (the latest record of each run)."""
    from ..sweep.results import ResultsStore

    out = Path(out)
    if not (out / "results.jsonl").exists():
        raise FileNotFoundError(f"{out} holds no benchmark results (no results.jsonl)")
    return ResultsStore(out).rows()
