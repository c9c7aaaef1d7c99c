"""Run a sweep: skip finished keys, dispatch the rest, record each run as it completes."""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .executors import Executor, make_executor
from .results import ResultsStore
from .spec import RunConfig, SweepSpec
from .worker import execute_run

__all__ = ["SweepReport", "run_sweep"]


@dataclass
class SweepReport:
    """What a call to :func:`run_sweep` did.

    Attributes
    ----------
    out_dir : Path
    keys : list of str
        Keys of every run of the spec, in spec order.
    skipped, ran, failed : list of str
        Keys already finished before this call, run now, and failed now.
    rows : list of dict
        Flat result rows of every run of the spec (spec order; see ``results.csv``).
    wall_s : float
    executor : str
    """

    out_dir: Path
    keys: list[str]
    skipped: list[str] = field(default_factory=list)
    ran: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    rows: list[dict[str, Any]] = field(default_factory=list)
    wall_s: float = 0.0
    executor: str = ""

    def summary(self) -> str:
        return (
            f"{len(self.keys)} runs: {len(self.skipped)} already done, {len(self.ran)} ran "
            f"({len(self.failed)} failed) in {self.wall_s:.1f} s on {self.executor}; "
            f"results in {self.out_dir}"
        )


def _progress(total: int, initial: int, enabled: bool | None) -> Any:
    from tqdm.auto import tqdm

    return tqdm(
        total=total,
        initial=initial,
        unit="run",
        desc="sweep",
        disable=(not sys.stderr.isatty()) if enabled is None else not enabled,
        dynamic_ncols=True,
    )


def run_sweep(
    spec: SweepSpec | list[RunConfig],
    out_dir: str | os.PathLike[str],
    executor: Executor | str = "process",
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = True,
    retry_failed: bool = True,
    plot: bool = True,
    progress: bool | None = None,
    table_every: int = 1,
) -> SweepReport:
    """Run every configuration of ``spec`` into ``out_dir``.

    Parameters
    ----------
    spec : SweepSpec or list of RunConfig
    out_dir : path
        Folder of the sweep: ``runs/<name>-<key>/`` (one run directory each),
        ``results.jsonl`` (journal), ``results.csv`` / ``results.parquet``, ``sweep.json``.
    executor : Executor or str
        ``"process"`` (default), ``"serial"``, ``"dask"``, or an executor instance (not
        closed here).
    workers, scheduler :
        For executors built by name.
    resume : bool
        Skip keys that already finished in ``out_dir`` (default). False reruns all.
    retry_failed : bool
        On resume, rerun keys whose last attempt failed (default).
    plot : bool
        Write ``plot.png`` in every run directory.
    progress : bool, optional
        Show a tqdm bar (runs done / total, ETA); default: when stderr is a terminal.
    table_every : int
        Rewrite the CSV/Parquet tables after every N completed runs (always at the end).

    Returns
    -------
    SweepReport
    """
    t0 = time.perf_counter()
    configs = spec.expand() if isinstance(spec, SweepSpec) else list(spec)
    keys = [c.key for c in configs]
    store = ResultsStore(out_dir)
    done = store.finished(include_failed=not retry_failed) if resume else set()
    todo = [(c, k) for c, k in zip(configs, keys, strict=True) if k not in done]
    report = SweepReport(Path(out_dir), keys, skipped=[k for k in keys if k in done])
    (Path(out_dir) / "sweep.json").write_text(
        json.dumps(
            {"runs": [dict(c.as_dict(), key=k) for c, k in zip(configs, keys, strict=True)]},
            indent=1,
            default=str,
        )
        + "\n"
    )
    own = isinstance(executor, str)
    ex = make_executor(executor, workers=workers, scheduler=scheduler) if own else executor
    report.executor = ex.describe() if todo else ex.name
    out_str = str(Path(out_dir).resolve())
    tasks = [(c.as_dict(), k, out_str, plot) for c, k in todo]
    bar = _progress(len(keys), len(report.skipped), progress)
    n_since_table = 0
    try:
        for i, outcome in ex.run(execute_run, tasks):
            cfg, key = todo[i]
            if isinstance(outcome, BaseException):  # the machinery failed, not the run
                import traceback

                rec = {
                    "key": key,
                    "status": "failed",
                    "run_dir": None,
                    "metrics": {},
                    "error": f"{type(outcome).__name__}: {outcome}",
                    "traceback": "".join(traceback.format_exception(outcome)),
                }
            else:
                rec = dict(outcome)
            rec["config"] = cfg.as_dict()
            rec["finished_at"] = time.time()
            store.append(rec)
            report.ran.append(key)
            if rec["status"] != "ok":
                report.failed.append(key)
            bar.update(1)
            bar.set_postfix(failed=len(report.failed), refresh=False)
            n_since_table += 1
            if n_since_table >= max(1, table_every):
                store.write_tables()
                n_since_table = 0
    finally:
        bar.close()
        if own:
            ex.close()
        store.write_tables()
    report.rows = store.rows(keys)
    report.wall_s = time.perf_counter() - t0
    return report
