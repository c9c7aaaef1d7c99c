"""``conformal-control sweep``: run the controller over a parameter grid."""

from __future__ import annotations

import argparse
import sys
import warnings

from . import add_data_root, command, key_values, positive_int


def add_executor_args(p: argparse.ArgumentParser, auto: str | None = None) -> None:
    """``--executor``, ``--workers``, ``--scheduler`` (shared with ``reproduce``).

    ``auto``: the help of an ``auto`` choice, which is then the default.
    """
    help = (
        "process pool on this machine, serial (in this process), dask, or batch (the "
        "runs the lockstep engine supports many at once in this process, same metrics; "
        "the others on a process pool)"
    )
    p.add_argument(
        "--executor",
        choices=("process", "serial", "dask", "batch", *(("auto",) if auto else ())),
        default="auto" if auto else "process",
        help=help + (f"; auto (default): {auto}" if auto else "; default: process"),
    )
    p.add_argument(
        "-j",
        "--workers",
        type=positive_int,
        default=None,
        help="worker processes (process pool / Dask LocalCluster); default: CPUs available",
    )
    p.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="Dask scheduler address (tcp://host:8786); without it a LocalCluster is started",
    )


@command("sweep", "run the controller over a parameter grid (local processes or Dask)")
def _sweep_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("spec", nargs="?", default=None, help="sweep spec file (.yaml, .json or .toml)")
    p.add_argument(
        "--grid",
        action="append",
        metavar="KEY=V1,V2,...",
        help="grid axis (repeatable), e.g. --grid epsilon=-0.25,0 --grid seed=0,1,2",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="value shared by every run (repeatable), e.g. --set scene=nexus_4",
    )
    p.add_argument("--scene", default=None, help="shorthand for --set scene=NAME")
    p.add_argument("--predictor", default=None, help="shorthand for --set predictor=NAME")
    add_data_root(p)
    p.add_argument("--out", required=True, help="sweep folder (created; reused to resume)")
    add_executor_args(p)
    p.add_argument("--no-resume", action="store_true", help="rerun runs already finished")
    p.add_argument(
        "--no-retry-failed", action="store_true", help="on resume, keep failed runs as failed"
    )
    p.add_argument(
        "--plots",
        action="store_true",
        help="write plot.png and guarantee.png in every run directory (slow; off by default)",
    )
    p.add_argument(
        "--no-plot",
        action="store_true",
        help="no per-run plots (the default; kept for old scripts)",
    )
    p.add_argument(
        "--no-summary-plot", action="store_true", help="do not write the sweep's summary.png"
    )
    p.add_argument(
        "--dry-run", action="store_true", help="check the runs and list them with their keys only"
    )
    p.add_argument(
        "--progress",
        choices=("auto", "on", "off"),
        default="auto",
        help="progress on stderr (auto, on: a bar on a terminal, a line every 10 s with the "
        "time left when redirected)",
    )


@_sweep_args.handler
def _sweep(args: argparse.Namespace) -> int:
    from ...experiments import (
        JournalWarning,
        ResultsStore,
        SweepInterrupted,
        SweepLockedError,
        SweepSpec,
        load_spec,
        parse_grid_option,
        run_sweep,
        validate_runs,
    )

    if args.plots and args.no_plot:
        raise ValueError("--plots and --no-plot contradict each other; give one")
    spec = load_spec(args.spec) if args.spec else SweepSpec()
    base = key_values(args.set, "--set")
    for name in ("scene", "predictor", "data_root"):
        if getattr(args, name) is not None:
            base[name] = getattr(args, name)
    spec = spec.merged(SweepSpec(base=base, grid=parse_grid_option(args.grid)))
    configs = spec.expand()
    if not configs:
        raise ValueError("the sweep has no runs")
    if args.dry_run:
        validate_runs(configs)  # the same check a real sweep makes before it starts
        for c in configs:
            print(c.key, c.as_dict())
        print(f"{len(configs)} runs")
        return 0
    with warnings.catch_warnings():  # unreadable journal lines: one plain line on stderr
        warnings.simplefilter("always", JournalWarning)
        warnings.showwarning = _show_warning
        try:
            report = run_sweep(
                configs,
                args.out,
                args.executor,
                workers=args.workers,
                scheduler=args.scheduler,
                resume=not args.no_resume,
                retry_failed=not args.no_retry_failed,
                plot=args.plots,
                summary_plot=not args.no_summary_plot,
                progress={"auto": None, "on": True, "off": False}[args.progress],
            )
        except SweepLockedError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except SweepInterrupted as exc:
            recorded = exc.recorded or ResultsStore(args.out).interrupted_summary()
            print(f"sweep {exc}: {recorded}", file=sys.stderr)
            return 128 + exc.signum
    print(report.summary())
    if report.summary_plot is not None:
        print(f"summary plot: {report.summary_plot}")
    for note in report.notes:
        print(f"note: {note}", file=sys.stderr)
    for row in report.rows:
        if row["status"] != "ok":
            print(
                f"failed {row['key']} ({row['label'] or row['scene']}): {row['error']}",
                file=sys.stderr,
            )
    return 1 if report.failed or report.unfinished else 0


def _show_warning(
    message: Warning | str, category: type[Warning], *args: object, **kw: object
) -> None:
    print(f"warning: {message}", file=sys.stderr)
