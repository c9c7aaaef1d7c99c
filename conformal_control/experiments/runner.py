"""Run a sweep: validate, lock the folder, skip finished keys, record each run as it completes.

Order of a call to :func:`run_sweep`: every configuration is checked (nothing runs if one
is invalid); the folder's lock is taken (a second sweep on the same folder stops at once);
the journal is read and finished keys are skipped; the rest go to the executor and every
outcome is appended to the journal the moment it arrives; the tables and the summary plot
are written at the end. SIGTERM and Ctrl-C stop the sweep cleanly: the runs in flight are
abandoned, workers are terminated, every run whose directory was completed (``metrics.json``
written) but whose outcome had not reached the journal yet -- a pool worker's finished run, a
batched run between its files and its journal line -- is journaled from its run directory
(counted in :attr:`SweepReport.recovered`), the tables are rewritten and the lock released.
A resumed sweep adopts such run directories the same way instead of running them again.

The tables are rewritten at the end and, during the sweep, at most every
:data:`TABLE_INTERVAL_S` seconds and never more often than it takes to write them twenty
times over (``table_every=None``, the default): their cost stays a small fraction of the
sweep, whatever its size (rewriting them after every run made a sweep quadratic in its
number of runs).

Every journal line is written (handed to the operating system) before the next outcome is
taken, so a stopped or killed sweep loses nothing it finished. Its ``fsync`` -- durability
against a crash of the machine itself -- is a group commit: a line is synced when the last
sync is at least :data:`JOURNAL_SYNC_S` old, otherwise the next sync covers it, and the
journal is synced before every table rewrite, at the end and when the sweep is stopped. A
sweep whose runs take longer than that syncs every line, as before; a burst of results (the
batch engine delivers hundreds at once) pays one ``fsync`` per second instead of one per
run, whose latency is set by whatever else writes to the disk (0.1 ms on an idle disk, 3 to
5 ms with other writers on it, more on network file systems). A crash of the machine can
lose the lines written since the last sync (runs that finished within one second of it);
a resumed sweep does those runs again.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import threading
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

from ..core.exceptions import ConformalControlWarning
from .executors import Executor, make_executor
from .lock import SweepLock
from .plan import SweepRun, SweepSpec
from .results import ResultsStore, atomic_write
from .worker import execute_run

__all__ = ["JOURNAL_SYNC_S", "TABLE_INTERVAL_S", "SweepInterrupted", "SweepReport", "run_sweep"]

#: Least time (s) between two ``fsync`` of the journal during a sweep (group commit).
JOURNAL_SYNC_S = 1.0

#: Least time (s) between two rewrites of the tables during a sweep (``table_every=None``).
TABLE_INTERVAL_S = 30.0
#: The tables are rewritten at most once per this many times the last rewrite took.
TABLE_COST_RATIO = 20.0


class SweepInterrupted(KeyboardInterrupt):
    """The sweep was stopped by a signal (SIGTERM, SIGINT); what finished is recorded.

    Attributes
    ----------
    signum : int
    recorded : str or None
        What the sweep folder holds now, read back from its journal (set by
        :func:`run_sweep` once it has stopped; ``None`` if the signal came before the sweep
        started or the journal could not be read): what finished and how to resume.
    """

    def __init__(self, signum: int) -> None:
        self.signum = signum
        self.recorded: str | None = None
        super().__init__(f"interrupted by {signal.Signals(signum).name}")


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
        Flat result rows of every run of the spec (spec order; see ``results.csv``), with
        ``run_dir`` as an absolute path.
    wall_s : float
    executor : str
    journal_skipped : list of (int, str)
        Journal lines that could not be read (line number, reason); a
        :class:`~conformal_control.experiments.results.JournalWarning` names them too.
    summary_plot : Path or None
        The summary plot written (``summary.png``), if any.
    notes : list of str
        Other things the caller should be told (why there is no summary plot).
    recovered : list of str
        Keys journaled from their finished run directory instead of their outcome (an
        interrupted sweep's finished runs, or the run directories a resumed sweep found).
    interrupted : bool
        The sweep was stopped by a signal before every run finished.
    unfinished : list of str
        Keys whose run never came back because the machinery failed (a Dask scheduler or
        worker lost, a pool's worker killed): they are not failures of the run, are not
        journaled, and a rerun of the same command runs them.
    infrastructure : list of str
        What failed (one line per distinct reason), for :attr:`unfinished`.
    """

    out_dir: Path
    keys: list[str]
    skipped: list[str] = field(default_factory=list)
    ran: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    rows: list[dict[str, Any]] = field(default_factory=list)
    wall_s: float = 0.0
    executor: str = ""
    journal_skipped: list[tuple[int, str]] = field(default_factory=list)
    summary_plot: Path | None = None
    notes: list[str] = field(default_factory=list)
    recovered: list[str] = field(default_factory=list)
    interrupted: bool = False
    unfinished: list[str] = field(default_factory=list)
    infrastructure: list[str] = field(default_factory=list)

    def summary(self) -> str:
        recovered = (
            f"{len(self.recovered)} recovered from their run directories, "
            if self.recovered
            else ""
        )
        return (
            f"{len(self.keys)} runs: {len(self.skipped)} already done, {recovered}"
            f"{len(self.ran)} ran ({len(self.failed)} failed) in {self.wall_s:.1f} s on "
            f"{self.executor}; results in {self.out_dir}" + self.unfinished_note()
        )

    def unfinished_note(self) -> str:
        """``; N left unfinished ...`` when the machinery lost runs, else ``""``."""
        if not self.unfinished:
            return ""
        why = self.infrastructure[0] if self.infrastructure else "the executor failed"
        more = (
            f" (and {len(self.infrastructure) - 1} other reasons)"
            if len(self.infrastructure) > 1
            else ""
        )
        return (
            f"; {len(self.unfinished)} left unfinished, not failed: the infrastructure "
            f"failed ({why}{more}); run the same command again to finish them"
        )


class _SignalGuard:
    """Turn SIGTERM/SIGINT into :class:`SweepInterrupted`, deferred inside critical parts.

    Handlers are installed only in the main thread (Python allows no other). The first
    signal raises; later ones are ignored while the sweep cleans up.
    """

    SIGNALS = ("SIGTERM", "SIGINT")

    def __init__(self) -> None:
        self._old: dict[int, Any] = {}
        self._critical = 0
        self._pending: int | None = None
        self._fired = False

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        if self._fired:
            return
        if self._critical:
            self._pending = signum
            return
        self._fired = True
        raise SweepInterrupted(signum)

    def __enter__(self) -> _SignalGuard:
        if threading.current_thread() is threading.main_thread():
            for name in self.SIGNALS:
                sig = getattr(signal, name, None)
                if sig is not None:
                    self._old[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)

    @contextlib.contextmanager
    def critical(self) -> Iterator[None]:
        """Delay a signal until the block (a journal append) is done."""
        self._critical += 1
        try:
            yield
        finally:
            self._critical -= 1
            if not self._critical and self._pending is not None and not self._fired:
                signum, self._pending = self._pending, None
                self._fired = True
                raise SweepInterrupted(signum)


class _NoBar:
    """The progress bar when it is off: tqdm's first bar, even disabled, starts a monitor
    thread, and a process with a second thread cannot safely fork (figures are drawn on
    a forked child: :mod:`conformal_control.io.plotting.jobs`)."""

    def update(self, n: int = 1) -> None:
        pass

    def set_postfix(self, **kwargs: Any) -> None:
        pass

    def close(self) -> None:
        pass


class _Report:
    """The sweep's progress (:func:`conformal_control.core.progress.progress`): a bar on a
    terminal, and where the output is redirected (a log file, ``nohup``, CI) a line every
    10 s with the runs done, the time so far and the time left; no thread either way."""

    def __init__(self, total: int, initial: int) -> None:
        from ..core.progress import progress

        self._report = progress(total, "sweep", "runs", initial=initial)

    def update(self, n: int = 1) -> None:
        self._report.update(n)

    def set_postfix(self, failed: int = 0, refresh: bool = False) -> None:
        self._report.set_postfix(f"{failed} failed" if failed else "")

    def close(self) -> None:
        self._report.close()


def _progress(total: int, initial: int, enabled: bool | None) -> Any:
    """The sweep's report: off with ``enabled=False`` (or ``--quiet``), else a bar on a
    terminal and periodic lines elsewhere (:class:`_Report`)."""
    if enabled is False:
        return _NoBar()
    return _Report(total, initial)


def distinct_runs(configs: list[SweepRun]) -> tuple[list[SweepRun], list[tuple[str, str]]]:
    """The configurations with one run per key (the first of each), and ``(label left out,
    label kept)`` for every run whose configuration another run of the list already has
    (e.g. a method that a predictor shift turns into another one: ``oracle_mpc`` under a
    shift that replaces every predictor is ``mpc``).

    Parameters
    ----------
    configs : list of SweepRun
        The sweep's runs, in order.
    """
    first: dict[str, SweepRun] = {}
    kept: list[SweepRun] = []
    same: list[tuple[str, str]] = []
    for c in configs:
        k = c.key
        if k in first:
            same.append((c.label, first[k].label))
        else:
            first[k] = c
            kept.append(c)
    return kept, same


def run_sweep(
    spec: SweepSpec | list[SweepRun],
    out_dir: str | os.PathLike[str],
    executor: Executor | str = "process",
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = True,
    retry_failed: bool = True,
    plot: bool | str = False,
    summary_plot: bool = True,
    validate: bool = True,
    progress: bool | None = None,
    table_every: int | None = None,
    parquet: bool = True,
) -> SweepReport:
    """Run every configuration of ``spec`` into ``out_dir``.

    Parameters
    ----------
    spec : SweepSpec or list of SweepRun
    out_dir : path
        Folder of the sweep: ``runs/<name>-<key>/`` (one run directory each),
        ``results.jsonl`` (journal), ``results.csv`` / ``results.parquet``, ``sweep.json``,
        ``summary.png``, ``.lock``.
    executor : Executor or str
        ``"process"`` (default), ``"serial"``, ``"dask"``, ``"batch"``, or an executor
        instance (not closed here). ``"batch"`` runs every run the lockstep engine supports
        many at once in this process (same metrics; see :mod:`conformal_control.experiments.batch`)
        and the others on a process pool; ``"dask"`` (``scheduler``: a running cluster's
        address, else a local one) sends those runs in chunks, each batched on a worker
        (:func:`~conformal_control.experiments.batch.run_chunked`), and the others one per task.
        Either way this process journals every record as it arrives.
    workers, scheduler :
        For executors built by name.
    resume : bool
        Skip keys that already finished in ``out_dir`` (default). False reruns all.
    retry_failed : bool
        On resume, rerun keys whose last attempt failed (default).
    plot : bool or str
        Write ``plot.png`` and ``guarantee.png`` in every run directory (default off:
        plotting takes most of a short run's time); ``"metrics"`` writes only each run's
        ``config.json`` and ``metrics.json``, ``"none"`` no run directory (the journal
        holds the metrics): see :func:`~conformal_control.experiments.worker.execute_run`.
    summary_plot : bool
        Write ``summary.png``, the metrics against the swept parameter (default on).
    validate : bool
        Check every configuration before any run starts (default). False lets invalid
        runs start and be recorded as failed.
    progress : bool, optional
        False: no report. Otherwise (default) a bar on a terminal, and a line every 10 s
        where stderr is redirected (runs done / total, time so far and left).
    table_every : int or None
        Rewrite the CSV/Parquet tables after every N completed runs (always at the end);
        None (default): by time, see the module docstring.
    parquet : bool
        Write ``results.parquet`` beside ``results.csv`` (default, when pyarrow is
        installed). False writes the CSV only: building the Arrow table imports pandas
        (about 0.4 s), a tenth of a short report such as ``reproduce``.

    Returns
    -------
    SweepReport

    Raises
    ------
    SweepValidationError
        If a configuration is invalid (nothing was run; a ``ValueError``).
    SweepLockedError
        If another process is running a sweep in ``out_dir``.
    SweepInterrupted
        On SIGTERM or Ctrl-C, after recording what finished.
    """
    t0 = time.perf_counter()
    configs = spec.expand() if isinstance(spec, SweepSpec) else list(spec)
    configs, same = distinct_runs(configs)
    keys = [c.key for c in configs]
    if validate:
        from .validate import validate_runs

        validate_runs(configs)
    out = Path(out_dir)
    report = SweepReport(out, keys)
    if same:
        # two runs of one configuration are one result (the journal keeps one row per
        # key): said, counted and warned, never collapsed silently
        shown = "; ".join(f"{a} = {b}" for a, b in same[:5]) + ("; ..." if len(same) > 5 else "")
        note = (
            f"{len(same)} run(s) left out: the same configuration (and key) as another run "
            f"of this sweep, whose result stands for both ({shown})"
        )
        report.notes.append(note)
        warnings.warn(note, ConformalControlWarning, stacklevel=2)
    with SweepLock(out), _SignalGuard() as guard:
        store = ResultsStore(out)
        store.remove_stale_temp_files()
        store.records()  # reads the journal now: unreadable lines are reported up front
        report.journal_skipped = list(store.bad_lines_)  # also warned (JournalWarning)
        done = store.finished(include_failed=not retry_failed) if resume else set()
        if resume:  # finished run directories the journal does not know (a killed sweep)
            waiting = [(c, k) for c, k in zip(configs, keys, strict=True) if k not in done]
            adopted = _adopt_finished(store, waiting, guard)
            report.recovered.extend(adopted)
            done |= set(adopted)
        todo = [(c, k) for c, k in zip(configs, keys, strict=True) if k not in done]
        report.skipped = [k for k in keys if k in done and k not in report.recovered]
        runs = [dict(c.as_dict(), key=k) for c, k in zip(configs, keys, strict=True)]
        text = json.dumps({"runs": runs}, indent=1, default=str) + "\n"
        atomic_write(out / "sweep.json", lambda tmp: tmp.write_text(text))
        own = isinstance(executor, str)
        # the lockstep engine: here with the other runs on a process pool (batch), or in
        # chunks on a cluster's workers (dask)
        batch = executor in ("batch", "dask") or getattr(executor, "distributed", False)
        if isinstance(executor, str):
            name = "process" if executor == "batch" else executor
            ex = make_executor(name, workers=workers, scheduler=scheduler)
        else:
            ex = executor
        stopped = False
        signalled: SweepInterrupted | None = None
        try:
            _run(ex, todo, store, report, guard, plot, progress, table_every, batch, parquet)
        except BaseException as exc:
            stopped = True
            report.interrupted = isinstance(exc, KeyboardInterrupt)  # SweepInterrupted too
            if isinstance(exc, SweepInterrupted):
                signalled = exc
            raise
        finally:
            if own:
                ex.close()
            if stopped:  # after the workers stopped: their run directories are complete or not
                with contextlib.suppress(SweepInterrupted, Exception):
                    if report.interrupted:
                        ran = set(report.ran)
                        left = [(c, k) for c, k in todo if k not in ran]
                        report.recovered.extend(_adopt_finished(store, left, guard))
                with contextlib.suppress(SweepInterrupted, Exception):
                    store.sync()
                with contextlib.suppress(SweepInterrupted, Exception):
                    store.write_tables(parquet=parquet)
                if signalled is not None:  # the caller says what was kept, from the journal
                    with contextlib.suppress(SweepInterrupted, Exception):
                        signalled.recorded = store.interrupted_summary()
        report.rows = store.rows(keys, absolute=True)
        if summary_plot:
            from .summary import write_summary_plot

            try:
                report.summary_plot, note = write_summary_plot(report.rows, out / "summary.png")
            except Exception as exc:  # the results are written; a plot must not undo that
                note = f"no summary plot: {type(exc).__name__}: {exc}"
            if report.summary_plot is None:
                report.notes.append(note)
    report.wall_s = time.perf_counter() - t0
    return report


def _run(
    ex: Executor,
    todo: list[tuple[SweepRun, str]],
    store: ResultsStore,
    report: SweepReport,
    guard: _SignalGuard,
    plot: bool | str,
    progress: bool | None,
    table_every: int | None,
    batch: bool = False,
    parquet: bool = True,
) -> None:
    """Dispatch ``todo`` and journal every outcome as it arrives."""
    report.executor = ex.describe() if todo else ex.name
    out_str = str(store.out_dir.resolve())
    tasks = [(c, k, out_str, plot) for c, k in todo]
    bar = _progress(len(report.keys), len(report.keys) - len(todo), progress)
    n_since_table = 0
    last_table = time.perf_counter()
    table_cost = 0.0
    last_sync = -math.inf  # the first line is synced at once
    if batch and ex.distributed:
        from .batch import run_chunked

        report.executor = f"batch chunks on {report.executor}"
        outcomes = run_chunked(ex, tasks)
    elif batch:
        from .batch import run_batched

        report.executor = f"batch + {report.executor}"
        outcomes = run_batched(ex, tasks)
    else:
        outcomes = ex.run(execute_run, tasks)
    try:
        for i, outcome in outcomes:
            cfg, key = todo[i]
            rec: dict[str, Any]
            if isinstance(outcome, BaseException):
                # the machinery failed, not the run (a run's own error comes back as a
                # record): left unfinished, never journaled as a failure of the method,
                # and run again by a rerun of the same command
                reason = _one_line(outcome)
                if reason not in report.infrastructure:
                    report.infrastructure.append(reason)
                report.unfinished.append(key)
                bar.update(1)
                continue
            rec = dict(outcome)
            rec["run_dir"] = store.relative_run_dir(rec.get("run_dir"))
            rec["config"] = cfg.as_dict()
            rec["finished_at"] = time.time()
            now = time.perf_counter()
            sync = now - last_sync >= JOURNAL_SYNC_S
            with guard.critical():
                store.append(rec, sync=sync)
                report.ran.append(key)
                if rec["status"] != "ok":
                    report.failed.append(key)
            if sync:
                last_sync = now
            bar.update(1)
            bar.set_postfix(failed=len(report.failed), refresh=False)
            n_since_table += 1
            now = time.perf_counter()
            if (
                n_since_table >= max(1, table_every)
                if table_every is not None
                else now - last_table >= max(TABLE_INTERVAL_S, TABLE_COST_RATIO * table_cost)
            ):
                store.sync()  # the tables never run ahead of the durable journal
                last_sync = now
                store.write_tables(parquet=parquet)
                last_table = time.perf_counter()
                table_cost = last_table - now
                n_since_table = 0
    finally:
        close = getattr(outcomes, "close", None)
        if close is not None:  # stop the executor now, not when the generator is collected
            close()
        bar.close()
    store.sync()
    store.write_tables(parquet=parquet)


def _one_line(exc: BaseException) -> str:
    """``Type: message`` of an infrastructure error, on one line and short."""
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    return text if len(text) <= 200 else text[:200] + "..."


def _adopt_finished(
    store: ResultsStore, todo: list[tuple[SweepRun, str]], guard: _SignalGuard
) -> list[str]:
    """Journal the runs of ``todo`` whose run directory is complete; return their keys.

    A run directory is complete when its ``metrics.json`` exists (written atomically, after
    ``config.json``) and its ``config.json`` names the run's key: the run finished, but its
    outcome never reached the journal (the sweep was stopped in between). Its record is
    the one the run would have sent, rebuilt from those files, marked ``"recovered": true``.
    """
    from .worker import METRIC_COLUMNS, run_dir_name

    runs = store.out_dir / "runs"
    if not todo or not runs.is_dir():
        return []
    present = {p.name for p in runs.iterdir()}
    adopted: list[str] = []
    for cfg, key in todo:
        d = cfg.as_dict()
        name = run_dir_name(cfg, key)
        if name not in present:
            continue
        try:
            metrics = json.loads((runs / name / "metrics.json").read_text())
            saved = json.loads((runs / name / "config.json").read_text())
        except (OSError, ValueError, RecursionError):
            continue  # not finished (or not ours): the run is done again
        if not isinstance(metrics, dict) or not isinstance(saved, dict):
            continue
        if (saved.get("sweep") or {}).get("key") != key:
            continue
        rec = {
            "key": key,
            "status": "ok",
            "run_dir": f"runs/{name}",
            "metrics": {k: metrics.get(k) for k in METRIC_COLUMNS},
            "error": None,
            "traceback": None,
            "recovered": True,
            "config": d,
            "finished_at": time.time(),
        }
        with guard.critical():
            store.append(rec, sync=False)
        adopted.append(key)
    if adopted:
        store.sync()  # one fsync for them all
    return adopted
